#!/bin/sh
# The project's test command: installs the Debian packages, builds three
# times with warnings as errors (-O2 with debug info, -O3 Release as users
# and packagers build it, and AddressSanitizer + UndefinedBehaviorSanitizer)
# and runs the whole CTest suite on the -O2 and the sanitizer builds. Run from the repository root
# as root on Debian 12; .ci/run calls exactly this.
set -eu
cd "$(dirname "$0")/.."
if [ "$(id -u)" = 0 ]; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    xargs -a configs/debian-packages.txt apt-get install -y -qq --no-install-recommends >/dev/null
fi
jobs=$(nproc)
# One OpenBLAS thread: the suite runs tests in parallel, and threaded BLAS
# inside parallel tests only adds contention.
export OPENBLAS_NUM_THREADS=1
# Likewise CHOLMOD's OpenMP, whose factorizations open teams of a fixed
# four threads that only OMP_THREAD_LIMIT caps (not OMP_NUM_THREADS).
export OMP_THREAD_LIMIT=1
cmake -S . -B build -DCMAKE_BUILD_TYPE=RelWithDebInfo -DBIOTGRID_WERROR=ON
cmake --build build -j "$jobs"
ctest --test-dir build --output-on-failure -j "$jobs"
cmake -S . -B build-release -DCMAKE_BUILD_TYPE=Release -DBIOTGRID_WERROR=ON
cmake --build build-release -j "$jobs"
# The sanitizer build at -O1, as AddressSanitizer's authors advise: every
# check stays on (no NDEBUG, debug info kept), and the suite's numerical
# tests run 1.5-2x faster than at -O0.
cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=Debug "-DCMAKE_C_FLAGS_DEBUG=-g -O1" \
    -DBIOTGRID_SANITIZE=ON -DBIOTGRID_WERROR=ON
cmake --build build-asan -j "$jobs"
ctest --test-dir build-asan --output-on-failure -j "$jobs"

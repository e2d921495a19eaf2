#!/bin/sh
# expect.sh CODE PATTERN FILE|- COMMAND...: runs COMMAND, requires exit
# status CODE, output (stdout + stderr) matching the extended regular
# expression PATTERN, and FILE (unless -) to exist afterwards.
code=$1 pattern=$2 file=$3
shift 3
out=$("$@" 2>&1)
status=$?
printf '%s\n' "$out"
if [ "$status" -ne "$code" ]; then
    echo "expect.sh: exit status $status, expected $code" >&2
    exit 1
fi
if ! printf '%s\n' "$out" | grep -Eq -- "$pattern"; then
    echo "expect.sh: output does not match /$pattern/" >&2
    exit 1
fi
if [ "$file" != "-" ] && [ ! -s "$file" ]; then
    echo "expect.sh: $file was not written" >&2
    exit 1
fi
exit 0

// arap_bench — the cost of one local/global iteration of libigl's
// arap_solve on a biotgrid scene's mesh and handles, for the comparison row
// of tests/bench/bench_table.sh (--libigl DIR). Not part of the build:
// libigl is not a dependency of biotgrid; bench_table.sh compiles this file
// against a libigl source tree the user names (header-only use) and
// Debian's Eigen (libeigen3-dev), with the flags a release build of a user's
// program gets (-O3 -DNDEBUG, no -march).
//
//   arap_bench MESH ITERATIONS HANDLE...
//     MESH    a Medit .mesh file of tetrahedra, or box:NX,NY,NZ:SX,SY,SZ for
//             the box biotgrid generates ("generate": "box"): the same
//             vertices, numbering and Kuhn split into six tetrahedra a cell
//     HANDLE  x0,y0,z0,x1,y1,z1,tx,ty,tz: the vertices inside the box given
//             as fractions of the mesh's bounding box (inclusive, 1e-9 of
//             the extent, as biotgrid's box_fraction selects), moved by t;
//             a vertex takes the first handle that selects it
//
// Prints the counts (to check against biotgrid's report) and
// "figure libigl.ms_per_iteration=V": the wall time of ITERATIONS
// iterations after one untimed iteration, divided by ITERATIONS. One
// thread: run it with IGL_NUM_THREADS=1.
#include <igl/arap.h>

#include <array>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

namespace {

double now()
{
    using clock = std::chrono::steady_clock;
    return std::chrono::duration<double>(clock::now().time_since_epoch()).count();
}

bool read_medit(const char *path, Eigen::MatrixXd &V, Eigen::MatrixXi &T)
{
    std::ifstream in(path);
    std::string word;
    while (in >> word) {
        int count = 0, ref = 0;
        if (word == "Vertices") {
            in >> count;
            V.resize(count, 3);
            for (int i = 0; i < count; i++)
                in >> V(i, 0) >> V(i, 1) >> V(i, 2) >> ref;
        } else if (word == "Tetrahedra") {
            in >> count;
            T.resize(count, 4);
            for (int i = 0; i < count; i++) {
                in >> T(i, 0) >> T(i, 1) >> T(i, 2) >> T(i, 3) >> ref;
                T.row(i).array() -= 1; // Medit numbers from 1
            }
        }
    }
    return in.eof() && V.rows() > 0 && T.rows() > 0;
}

// bg_mesh_generate_box's mesh: vertex (i, j, k) at index (k·(ny+1) + j)·(nx+1) + i;
// a cell's six tetrahedra follow the monotone paths from its corner
// (0,0,0) to (1,1,1), the odd permutations with two vertices swapped.
void box(const int cells[3], const double size[3], Eigen::MatrixXd &V, Eigen::MatrixXi &T)
{
    const int nx = cells[0], ny = cells[1], nz = cells[2];
    auto id = [&](int i, int j, int k) { return (k * (ny + 1) + j) * (nx + 1) + i; };
    V.resize((nx + 1) * (ny + 1) * (nz + 1), 3);
    for (int k = 0; k <= nz; k++)
        for (int j = 0; j <= ny; j++)
            for (int i = 0; i <= nx; i++)
                V.row(id(i, j, k)) << size[0] * i / nx, size[1] * j / ny, size[2] * k / nz;
    static const int order[6][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1},
                                    {0, 2, 1}, {2, 1, 0}, {1, 0, 2}};
    T.resize(6 * nx * ny * nz, 4);
    int e = 0;
    for (int k = 0; k < nz; k++)
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++)
                for (int p = 0; p < 6; p++) {
                    int c[3] = {i, j, k}, path[4];
                    path[0] = id(c[0], c[1], c[2]);
                    for (int s = 0; s < 3; s++) {
                        c[order[p][s]]++;
                        path[s + 1] = id(c[0], c[1], c[2]);
                    }
                    if (p >= 3)
                        std::swap(path[2], path[3]);
                    T.row(e++) << path[0], path[1], path[2], path[3];
                }
}

} // namespace

int main(int argc, char **argv)
{
    if (argc < 4) {
        std::fprintf(stderr, "usage: arap_bench MESH ITERATIONS HANDLE...\n");
        return 2;
    }
    Eigen::MatrixXd V;
    Eigen::MatrixXi T;
    int cells[3];
    double size[3];
    if (std::sscanf(argv[1], "box:%d,%d,%d:%lf,%lf,%lf", &cells[0], &cells[1], &cells[2],
                    &size[0], &size[1], &size[2]) == 6) {
        box(cells, size, V, T);
    } else if (!read_medit(argv[1], V, T)) {
        std::fprintf(stderr, "arap_bench: %s: not a Medit mesh of tetrahedra\n", argv[1]);
        return 2;
    }
    const int iterations = std::atoi(argv[2]);
    if (iterations < 1) {
        std::fprintf(stderr, "arap_bench: ITERATIONS must be a positive integer\n");
        return 2;
    }
    std::vector<std::array<double, 9>> handles;
    for (int a = 3; a < argc; a++) {
        std::array<double, 9> h;
        if (std::sscanf(argv[a], "%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf", &h[0], &h[1], &h[2],
                        &h[3], &h[4], &h[5], &h[6], &h[7], &h[8]) != 9) {
            std::fprintf(stderr, "arap_bench: handle '%s': expected nine numbers\n", argv[a]);
            return 2;
        }
        handles.push_back(h);
    }
    const Eigen::RowVector3d lo = V.colwise().minCoeff(), hi = V.colwise().maxCoeff();
    std::vector<int> fixed;
    std::vector<Eigen::RowVector3d> target;
    for (int v = 0; v < V.rows(); v++)
        for (const auto &h : handles) {
            bool inside = true;
            for (int c = 0; c < 3; c++) {
                const double span = hi(c) - lo(c), tol = 1e-9 * span;
                inside = inside && V(v, c) >= lo(c) + h[c] * span - tol &&
                         V(v, c) <= lo(c) + h[3 + c] * span + tol;
            }
            if (inside) {
                fixed.push_back(v);
                target.push_back(V.row(v) + Eigen::RowVector3d(h[6], h[7], h[8]));
                break;
            }
        }
    Eigen::VectorXi b(fixed.size());
    Eigen::MatrixXd bc(fixed.size(), 3);
    for (size_t i = 0; i < fixed.size(); i++) {
        b(i) = fixed[i];
        bc.row(i) = target[i];
    }
    igl::ARAPData data;
    const double t0 = now();
    if (!igl::arap_precomputation(V, T, 3, b, data)) {
        std::fprintf(stderr, "arap_bench: arap_precomputation failed\n");
        return 1;
    }
    const double t1 = now();
    Eigen::MatrixXd U = V;
    data.max_iter = 1;
    igl::arap_solve(bc, data, U);
    data.max_iter = iterations;
    const double t2 = now();
    igl::arap_solve(bc, data, U);
    const double t3 = now();
    std::printf("libigl arap: %ld vertices, %ld tetrahedra, %zu handle vertices; "
                "precomputation %.3f s, %d iterations %.3f s\n",
                (long)V.rows(), (long)T.rows(), fixed.size(), t1 - t0, iterations, t3 - t2);
    std::printf("figure libigl.ms_per_iteration=%.4f ms\n", (t3 - t2) / iterations * 1e3);
    return 0;
}

// A timed harness for the sphere's surface cells (omt/surface_cells.hpp): a random density on
// the flat triangles of a subdivided icosahedron, sites on the unit sphere (the vertices of a
// coarser one, jittered), one set of cells at equal heights and the transport to equal masses.
//
// Usage: bench_surface [density_level=5] [site_level=4] [repeats=5]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <vector>

#include "common/parallel.hpp"
#include "process.hpp"
#include "mesh/shapes.hpp"
#include "omt/surface_cells.hpp"

using namespace brenier;

int main(int argc, char** argv) {
  process::reexec_with_runtime_settings(argv);
  process::tune_allocator(process::Lifetime::kOneShot);
  const int density_level = argc > 1 ? std::atoi(argv[1]) : 5;
  const int site_level = argc > 2 ? std::atoi(argv[2]) : 4;
  const int repeats = argc > 3 ? std::atoi(argv[3]) : 5;
  const mesh::TriMesh surface = mesh::make_icosphere(density_level);
  omt::SurfaceDensity S;
  S.vertices = surface.V;
  S.faces = surface.F;
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> U(0.5, 2.0), J(-1.0, 1.0);
  S.density.resize(surface.num_faces());
  for (int f = 0; f < surface.num_faces(); ++f) S.density[f] = U(rng);
  const mesh::TriMesh site_mesh = mesh::make_icosphere(site_level);
  omt::Points3 sites = site_mesh.V;
  const double jitter = 0.2 * std::sqrt(4 * 3.14159 / site_mesh.num_vertices());
  for (int i = 0; i < sites.rows(); ++i) {
    // Drawn in sequence: the order of a call's arguments differs between gcc and clang.
    const double a = J(rng), b = J(rng), c = J(rng);
    const Eigen::Vector3d v = Eigen::Vector3d(sites.row(i)) + jitter * Eigen::Vector3d(a, b, c);
    sites.row(i) = v.normalized().transpose();
  }
  const Eigen::VectorXd h = Eigen::VectorXd::Zero(sites.rows()), nu = Eigen::VectorXd::Ones(sites.rows());
  std::vector<double> cells_s, solve_s;
  omt::SurfaceOmtResult r;
  for (int k = 0; k < repeats; ++k) {
    const auto t0 = std::chrono::steady_clock::now();
    const omt::SurfaceCells c = omt::surface_power_cells(S, sites, h);
    const auto t1 = std::chrono::steady_clock::now();
    r = omt::solve_surface_omt(S, sites, nu);
    const auto t2 = std::chrono::steady_clock::now();
    cells_s.push_back(std::chrono::duration<double>(t1 - t0).count());
    solve_s.push_back(std::chrono::duration<double>(t2 - t1).count());
  }
  std::sort(cells_s.begin(), cells_s.end());
  std::sort(solve_s.begin(), solve_s.end());
  std::printf("%ld sites, %ld triangles: cells median %.1f ms; transport to 1e-8 median %.1f ms, %d Newton steps, "
              "error %.1e%s\n",
              static_cast<long>(sites.rows()), static_cast<long>(S.faces.rows()), 1e3 * cells_s[cells_s.size() / 2],
              1e3 * solve_s[solve_s.size() / 2], r.iterations, r.max_relative_error, r.converged ? "" : " (not converged)");
  return 0;
}

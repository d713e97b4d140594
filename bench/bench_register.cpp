// Registration (Alg. 7) against ground truth and on the clock.
//
//   bench_register eval [--samples N] [--landmarks K] MESH...
//     For each real mesh: ground-truth pairs (make_truth_pair: the mesh, and a remeshed copy
//     bent, twisted or stretched), registered by the OMT route (area-preserving maps) and the
//     conformal route; prints per pair and route the median / mean / 90th percentile of the
//     normalized geodesic error, the domain folds and flipped morph faces, and the cumulative
//     error curves (share of points within 0, 0.01, ..., 0.25), Kim et al. 2011 style.
//   bench_register time MESH [--subdivide S]
//     End-to-end time of registering the mesh (subdivided S times) onto its remeshed, bent copy.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "jobs/jobs.hpp"
#include "mesh/geometry.hpp"
#include "mesh/shapes.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"
#include "register/evaluation.hpp"

using namespace brenier;
using registration::Deformation;

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

double quantile(std::vector<double> x, double q) {
  std::sort(x.begin(), x.end());
  return x.empty() ? 0 : x[static_cast<size_t>(q * static_cast<double>(x.size() - 1) + 0.5)];
}

struct Route {
  jobs::MapMethod method;
  std::vector<double> all_errors;
};

jobs::RegisterRequest request_for(const registration::TruthPair& p, jobs::Domain domain, bool cut, jobs::MapMethod m) {
  jobs::RegisterRequest r;
  r.domain = domain;
  r.cut_hole = cut;
  r.method = m;
  r.source_landmarks = p.source_landmarks;
  r.target_landmarks = p.target_landmarks;
  return r;
}

int eval(const std::vector<std::string>& meshes, int samples, int landmarks) {
  const std::vector<std::pair<Deformation, double>> deformations = {
      {Deformation::kNone, 0}, {Deformation::kBend, 0.5}, {Deformation::kTwist, 0.3}, {Deformation::kStretch, 0.2}};
  std::vector<Route> routes = {{jobs::MapMethod::kAreaPreserving, {}}, {jobs::MapMethod::kConformal, {}}};
  std::vector<double> thresholds;
  for (int i = 0; i <= 25; ++i) thresholds.push_back(0.01 * i);
  std::printf("%-28s %-8s %-16s %7s %8s %8s %8s %6s %6s %7s\n", "mesh", "deform", "route", "V", "median", "mean", "p90",
              "folds", "flips", "sec");
  for (const std::string& path : meshes) {
    mesh::CleanMesh cm = mesh::load_mesh(path);
    mesh::require_valid(cm, path);
    const mesh::Topology t = mesh::compute_topology(cm.mesh);
    const bool sphere = t.mesh_class == mesh::MeshClass::kSphere;
    for (const auto& [d, amount] : deformations) {
      const registration::TruthPair p = registration::make_truth_pair(cm.mesh, d, amount, 1.0, landmarks);
      const mesh::CleanMesh a = mesh::clean(p.source), b = mesh::clean(p.target);
      for (Route& route : routes) {
        const auto t0 = std::chrono::steady_clock::now();
        try {
          const jobs::RegisterOutcome out = jobs::run_register(
              a, b, "source", "target", request_for(p, sphere ? jobs::Domain::kSphere : jobs::Domain::kDisk, false, route.method), 2);
          const double sec = seconds_since(t0);
          std::vector<registration::SurfacePoint> found;
          for (const auto& [f, w] : out.target_points) found.push_back({f, w});
          const std::vector<double> e = registration::registration_errors(p, found, samples);
          route.all_errors.insert(route.all_errors.end(), e.begin(), e.end());
          double mean = 0;
          for (double x : e) mean += x / static_cast<double>(e.size());
          std::printf("%-28s %-8s %-16s %7d %8.4f %8.4f %8.4f %6d %6d %7.2f\n", path.substr(path.rfind('/') + 1).c_str(),
                      registration::deformation_name(d), jobs::map_method_name(route.method), a.mesh.num_vertices(),
                      quantile(e, 0.5), mean, quantile(e, 0.9), out.report["domain_folded_faces"].get<int>(),
                      out.report["morph_flipped_faces"].get<int>(), sec);
        } catch (const std::exception& e) {
          std::printf("%-28s %-8s %-16s failed: %s\n", path.c_str(), registration::deformation_name(d),
                      jobs::map_method_name(route.method), e.what());
        }
        std::fflush(stdout);
      }
    }
  }
  for (const Route& route : routes) {
    const std::vector<double> c = registration::cumulative_curve(route.all_errors, thresholds);
    std::printf("cumulative %s (%zu points, median %.4f):", jobs::map_method_name(route.method), route.all_errors.size(),
                quantile(route.all_errors, 0.5));
    for (size_t i = 0; i < c.size(); ++i) std::printf(" %.2f:%.3f", thresholds[i], c[i]);
    std::printf("\n");
  }
  return 0;
}

int time_one(const std::string& path, int subdivide) {
  mesh::CleanMesh cm = mesh::load_mesh(path);
  mesh::require_valid(cm, path);
  mesh::TriMesh m = cm.mesh;
  for (int i = 0; i < subdivide; ++i) m = mesh::subdivide_midpoint(m);
  const bool sphere = mesh::compute_topology(m).mesh_class == mesh::MeshClass::kSphere;
  const auto tp = std::chrono::steady_clock::now();
  const registration::TruthPair p = registration::make_truth_pair(m, Deformation::kBend, 0.5, 1.0, 6);
  const double t_pair = seconds_since(tp);
  const mesh::CleanMesh a = mesh::clean(p.source), b = mesh::clean(p.target);
  for (jobs::MapMethod method : {jobs::MapMethod::kAreaPreserving, jobs::MapMethod::kConformal}) try {
    const auto t0 = std::chrono::steady_clock::now();
    const jobs::RegisterOutcome out = jobs::run_register(
        a, b, "source", "target", request_for(p, sphere ? jobs::Domain::kSphere : jobs::Domain::kDisk, false, method), 2);
    const double sec = seconds_since(t0);
    std::printf("%s x%d (%s): %d -> %d vertices, registration %.2f s (maps %.2f s, match %.3f s), %d folds, %d flips; "
                "pair made in %.1f s\n",
                path.c_str(), subdivide, jobs::map_method_name(method), a.mesh.num_vertices(), b.mesh.num_vertices(), sec,
                out.report["seconds"]["maps"].get<double>(), out.report["seconds"]["match"].get<double>(),
                out.report["domain_folded_faces"].get<int>(), out.report["morph_flipped_faces"].get<int>(), t_pair);
    std::fflush(stdout);
  } catch (const std::exception& e) {
    std::printf("%s (%s): failed: %s\n", path.c_str(), jobs::map_method_name(method), e.what());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: bench_register eval [--samples N] [--landmarks K] MESH... | time MESH [--subdivide S]\n");
    return 2;
  }
  const std::string mode = argv[1];
  int samples = 300, landmarks = 6, subdivide = 0;
  std::vector<std::string> meshes;
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--samples" && i + 1 < argc) samples = std::atoi(argv[++i]);
    else if (a == "--landmarks" && i + 1 < argc) landmarks = std::atoi(argv[++i]);
    else if (a == "--subdivide" && i + 1 < argc) subdivide = std::atoi(argv[++i]);
    else meshes.push_back(a);
  }
  try {
    if (mode == "eval") return eval(meshes, samples, landmarks);
    if (mode == "time" && meshes.size() == 1) return time_one(meshes[0], subdivide);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_register: %s\n", e.what());
    return 1;
  }
  std::fprintf(stderr, "bench_register: unknown mode %s\n", mode.c_str());
  return 2;
}

// brenier-compute map MESH --domain disk|sphere --method conformal [...]: a map of a surface
// onto the unit disk or sphere, written as a mesh and reported as JSON (DESIGN.md contract).
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <cstdio>
#include <iostream>
#include <memory>

#include "commands.hpp"
#include "common/error.hpp"
#include "jobs/jobs.hpp"

namespace brenier::tools {
namespace {

struct MapOptions {
  MeshInputOptions input;
  std::string domain = "disk";
  std::string method = "conformal";
  int center = -1, boundary_marker = -1;
  std::vector<int> markers;
  bool cut = false;
  int hole_vertex = -1;
  std::string output;
  bool json = false;
  bool allow_flips = false;
  double tolerance = 0;  // 0: the method's default (curvature 1e-7 rad; cell mass 1e-8)
  std::string weights;
  double t = 0;
  int max_iterations = 200;
};

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

int run_map(const MapOptions& o) {
  auto t0 = std::chrono::steady_clock::now();
  mesh::CleanMesh cm = o.input.load();
  mesh::require_valid(cm, o.input.path);
  const double t_read = seconds_since(t0);

  jobs::MapRequest r;
  r.domain = o.domain;
  r.method = o.method;
  r.center = o.center;
  r.boundary_marker = o.boundary_marker;
  r.markers = o.markers;
  r.cut_hole = o.cut;
  r.hole_vertex = o.hole_vertex;
  r.tolerance = o.tolerance;
  r.max_iterations = o.max_iterations;
  r.t = o.t;
  r.allow_flips = o.allow_flips;
  if (!o.weights.empty()) r.weights = jobs::read_weights_file(o.weights, cm.input_vertices);
  jobs::MapOutcome m = jobs::run_map(cm, o.input.path, r);
  if (!o.output.empty()) jobs::write_map_file(m, o.output);

  nlohmann::json& j = m.report;
  j["seconds"]["read"] = t_read;
  j["seconds"]["total"] = seconds_since(t0);
  if (!o.output.empty()) j["output"] = o.output;
  if (o.json) {
    std::cout << j.dump(2) << std::endl;
    return kExitOk;
  }
  const nlohmann::json& q = j["quality"];
  std::printf("%s -> %s (%s): %d vertices, %d Newton iterations, max |K-Kbar| %.2e, %.3f s\n", o.input.path.c_str(),
              o.domain.c_str(), o.method.c_str(), j["mesh"]["vertices"].get<int>(),
              j["conformal"]["newton_iterations"].get<int>(), j["conformal"]["max_curvature_error"].get<double>(),
              j["seconds"]["total"].get<double>());
  if (j.contains("omt"))
    std::printf("optimal transport: %d Newton iterations, max relative cell-mass error %.2e\n",
                j["omt"]["newton_iterations"].get<int>(), j["omt"]["max_relative_area_error"].get<double>());
  std::printf("flipped faces %d; angle distortion mean %.3f deg, p95 %.3f, max %.3f; "
              "|log area ratio| mean %.3f, max %.3f\n",
              q["flipped_faces"].get<int>(), q["angle_distortion_deg"]["mean"].get<double>(),
              q["angle_distortion_deg"]["p95"].get<double>(), q["angle_distortion_deg"]["max"].get<double>(),
              q["area_distortion_log"]["mean_abs"].get<double>(), q["area_distortion_log"]["max_abs"].get<double>());
  if (!o.output.empty()) std::printf("wrote %s\n", o.output.c_str());
  return kExitOk;
}

}  // namespace

void add_map(CLI::App& app, Action& action) {
  auto o = std::make_shared<MapOptions>();
  CLI::App* cmd = app.add_subcommand("map", "map a surface onto the unit disk or sphere");
  o->input.add_to(cmd);
  cmd->add_option("--domain", o->domain, "disk or sphere")->check(CLI::IsMember({"disk", "sphere"}));
  cmd->add_option("--method", o->method, "conformal or area-preserving")
      ->check(CLI::IsMember({"conformal", "area-preserving"}));
  cmd->add_option("--t", o->t, "area-preserving: the polar-factorization map phi_t, 0 area-preserving .. 1 conformal")
      ->check(CLI::Range(0.0, 1.0));
  cmd->add_option("--weights", o->weights,
                  "area-preserving: file of one positive weight per input vertex (region of interest)");
  cmd->add_option("--center", o->center, "disk: interior vertex sent to 0");
  cmd->add_option("--boundary-marker", o->boundary_marker, "disk: boundary vertex sent to 1");
  cmd->add_option("--markers", o->markers, "sphere: three vertices sent to 0, 1, infinity")->delimiter(',');
  cmd->add_flag("--cut-hole", o->cut, "open a closed genus-0 mesh into a disk by removing one vertex's star");
  cmd->add_option("--hole-vertex", o->hole_vertex, "vertex whose star --cut-hole removes");
  cmd->add_option("-o,--output", o->output, "write the mapped mesh (.obj with vt, .ply, .off)");
  cmd->add_flag("--json", o->json, "print one JSON object");
  cmd->add_flag("--allow-flips", o->allow_flips, "write a map even if it folds faces");
  cmd->add_option("--tolerance", o->tolerance,
                  "conformal: max |K - Kbar| (radians, default 1e-7); area-preserving: max relative "
                  "cell-mass error (default 1e-8)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--max-iterations", o->max_iterations, "Newton iterations")->check(CLI::PositiveNumber);
  cmd->callback([o, &action] { action = [o] { return run_map(*o); }; });
}

}  // namespace brenier::tools

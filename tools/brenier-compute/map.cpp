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
#include "conformal/conformal_map.hpp"
#include "omt/area_preserving.hpp"
#include "mesh/geometry.hpp"
#include "quality/quality.hpp"

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

nlohmann::json stats_json(const quality::Stats& s, const char* suffix = "") {
  std::string sfx = suffix;
  return {{"mean" + sfx, s.mean}, {"p95" + sfx, s.p95}, {"max" + sfx, s.max}};
}

// One positive number per input vertex (whitespace separated), carried to the vertices of
// the mesh being mapped through `origin` (mapped vertex -> input vertex).
Eigen::VectorXd read_weights(const std::string& path, const std::vector<int>& origin, int input_vertices) {
  std::ifstream in(path);
  if (!in) invalid("cannot read the weights file " + path);
  std::vector<double> w;
  std::string tok;
  while (in >> tok) {
    char* end = nullptr;
    double x = std::strtod(tok.c_str(), &end);
    if (end == tok.c_str() || *end != '\0' || !(x > 0) || !std::isfinite(x))
      invalid(path + ": weight " + std::to_string(w.size()) + " is '" + tok + "'; weights must be positive numbers");
    w.push_back(x);
  }
  if (static_cast<int>(w.size()) != input_vertices)
    invalid(path + ": " + std::to_string(w.size()) + " weights for " + std::to_string(input_vertices) + " vertices");
  Eigen::VectorXd out(static_cast<int>(origin.size()));
  for (size_t i = 0; i < origin.size(); ++i) out[static_cast<int>(i)] = w[origin[i]];
  return out;
}

int run_map(const MapOptions& o) {
  auto t0 = std::chrono::steady_clock::now();
  mesh::CleanMesh cm = o.input.load();
  mesh::require_valid(cm, o.input.path);
  double t_read = seconds_since(t0);

  // Vertex numbers given by the user are those of the input file.
  std::vector<int> to_clean(static_cast<size_t>(cm.input_vertices), -1);
  for (size_t i = 0; i < cm.vertex_origin.size(); ++i) to_clean[cm.vertex_origin[i]] = static_cast<int>(i);
  auto clean_index = [&](int v, const char* what) {
    if (v < 0 || v >= cm.input_vertices || to_clean[v] < 0)
      invalid(std::string(what) + " " + std::to_string(v) + " is not a vertex of the mesh");
    return to_clean[v];
  };

  mesh::TriMesh surface = cm.mesh;
  std::vector<int> origin = cm.vertex_origin;
  int cut_vertex = -1;
  if (o.cut) {
    if (o.domain != "disk") invalid("--cut-hole applies to the disk domain");
    auto cut = mesh::cut_hole(surface, o.hole_vertex >= 0 ? std::optional<int>(clean_index(o.hole_vertex, "hole vertex"))
                                                          : std::nullopt);
    cut_vertex = origin[cut.vertex];
    std::vector<int> o2;
    for (int v : cut.vertex_origin) o2.push_back(origin[v]);
    origin = std::move(o2);
    surface = std::move(cut.mesh);
    std::fill(to_clean.begin(), to_clean.end(), -1);
    for (size_t i = 0; i < origin.size(); ++i) to_clean[origin[i]] = static_cast<int>(i);
  }

  conformal::ConformalOptions co;
  co.tolerance = o.tolerance > 0 ? o.tolerance : 1e-7;
  co.max_iterations = o.max_iterations;
  if (o.center >= 0) co.center_vertex = clean_index(o.center, "center vertex");
  if (o.boundary_marker >= 0) co.boundary_vertex = clean_index(o.boundary_marker, "boundary marker");
  if (!o.markers.empty()) {
    if (o.markers.size() != 3) invalid("--markers takes three vertices (sent to 0, 1, infinity)");
    co.sphere_markers = std::array<int, 3>{clean_index(o.markers[0], "marker"),
                                           clean_index(o.markers[1], "marker"),
                                           clean_index(o.markers[2], "marker")};
  }
  auto t1 = std::chrono::steady_clock::now();
  conformal::ConformalMap map;
  std::optional<omt::AreaPreservingMap> ap;
  if (o.method == "conformal" && (o.t > 0 || !o.weights.empty()))
    invalid("--t and --weights apply to --method area-preserving");
  if (o.method == "conformal") {
    map = o.domain == "disk" ? conformal::map_to_disk(surface, co) : conformal::map_to_sphere(surface, co);
  } else {
    omt::AreaPreservingOptions apo;
    apo.conformal = co;
    apo.conformal.tolerance = 1e-7;
    if (o.tolerance > 0) apo.omt.tolerance = o.tolerance;
    apo.omt.max_iterations = o.max_iterations;
    apo.t = o.t;
    if (!o.weights.empty()) apo.weights = read_weights(o.weights, origin, cm.input_vertices);
    ap = o.domain == "disk" ? omt::area_preserving_disk(surface, apo) : omt::area_preserving_sphere(surface, apo);
    map = ap->conformal;
  }
  const mesh::Vertices& positions = ap ? ap->positions : map.positions;
  double t_map = seconds_since(t1);
  if (!map.converged)
    fail(ErrorCode::kNotConverged,
         o.input.path + ": the conformal map did not converge: max |K - Kbar| = " +
             std::to_string(map.max_curvature_error) + " after " +
             std::to_string(map.newton_iterations) + " Newton iterations");

  auto target = o.domain == "disk" ? quality::Target::kPlane : quality::Target::kSphere;
  quality::MapQuality q = quality::measure(surface, positions, target);
  if (q.flipped_faces > 0 && !o.allow_flips) {
    std::string list;
    for (size_t i = 0; i < q.flipped.size() && i < 8; ++i) list += (i ? ", " : "") + std::to_string(q.flipped[i]);
    // Say why when the first folded face is too small for doubles: a region the conformal
    // map compresses below ~1e-8 has cross products at round-off level (long protrusions).
    const int f = q.flipped.front();
    double size = 0;
    for (int k = 0; k < 3; ++k)
      size = std::max(size, (positions.row(surface.F(f, k)) - positions.row(surface.F(f, (k + 1) % 3))).norm());
    std::string why;
    if (size < 1e-8) {
      char buf[160];
      std::snprintf(buf, sizeof buf, "; face %d is %.1e across in the image: the map compresses it below double precision", f, size);
      why = buf;
    }
    fail(ErrorCode::kNotConverged, o.input.path + ": the map folds " + std::to_string(q.flipped_faces) +
                                       " faces (first: " + list + ")" + why + "; pass --allow-flips to write it anyway");
  }

  if (!o.output.empty()) {
    if (o.domain == "disk") {
      mesh::UV uv = positions.leftCols(2);
      mesh::write_mesh_file(o.output, surface, &uv);
    } else {
      mesh::TriMesh sphere{positions, surface.F};
      mesh::write_mesh_file(o.output, sphere);
    }
  }

  mesh::Topology topo = mesh::compute_topology(cm.mesh);
  nlohmann::json j;
  j["mesh"] = {{"vertices", topo.vertices}, {"faces", topo.faces}, {"boundary_loops", topo.boundary_loops},
               {"genus", topo.genus}, {"class", mesh::class_name(topo.mesh_class)}};
  if (cut_vertex >= 0) j["cut_hole_vertex"] = cut_vertex;
  j["domain"] = o.domain;
  j["method"] = o.method;
  j["seconds"] = {{"total", seconds_since(t0)}, {"read", t_read}, {"map", t_map}};
  j["conformal"] = {{"newton_iterations", map.newton_iterations},
                    {"max_curvature_error", map.max_curvature_error},
                    {"converged", map.converged},
                    {"intrinsic_flips", map.flips},
                    {"normalization", map.normalization},
                    {"relaxed_vertices", map.relaxed_vertices},
                    {"lambda_min", map.lambda.minCoeff()},
                    {"lambda_max", map.lambda.maxCoeff()}};
  if (ap)
    j["omt"] = {{"newton_iterations", ap->omt.iterations},
                {"t", o.t},
                {"max_relative_area_error", ap->omt.max_relative_error},
                {"converged", ap->omt.converged},
                {"factorizations", ap->omt.factorizations},
                {"relaxed_vertices", ap->relaxed_vertices}};
  j["quality"] = {{"flipped_faces", q.flipped_faces},
                  {"angle_distortion_deg", stats_json(q.angle_distortion_deg)},
                  {"area_distortion_log", stats_json(q.area_distortion_log_abs, "_abs")},
                  {"quasi_conformal", stats_json(q.quasi_conformal)}};
  j["problems"] = problems_json(cm.report);
  if (!o.output.empty()) j["output"] = o.output;
  if (o.json) {
    std::cout << j.dump(2) << std::endl;
  } else {
    std::printf("%s -> %s (%s): %d vertices, %d Newton iterations, max |K-Kbar| %.2e, %.3f s\n",
                o.input.path.c_str(), o.domain.c_str(), o.method.c_str(), topo.vertices,
                map.newton_iterations, map.max_curvature_error, seconds_since(t0));
    if (ap)
      std::printf("optimal transport: %d Newton iterations, max relative cell-mass error %.2e\n",
                  ap->omt.iterations, ap->omt.max_relative_error);
    std::printf("flipped faces %d; angle distortion mean %.3f deg, p95 %.3f, max %.3f; "
                "|log area ratio| mean %.3f, max %.3f\n",
                q.flipped_faces, q.angle_distortion_deg.mean, q.angle_distortion_deg.p95,
                q.angle_distortion_deg.max, q.area_distortion_log_abs.mean,
                q.area_distortion_log_abs.max);
    if (!o.output.empty()) std::printf("wrote %s\n", o.output.c_str());
  }
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

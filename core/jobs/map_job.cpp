// The map job: conformal (Alg. 1, sec. 3.2.5) or area-preserving (Alg. 3, sec. 3.2.5) maps
// of a cleaned mesh, with the quality report of DESIGN.md's contract.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <optional>

#include "common/error.hpp"
#include "conformal/conformal_map.hpp"
#include "jobs/jobs.hpp"
#include "mesh/geometry.hpp"
#include "mesh/topology.hpp"
#include "omt/area_preserving.hpp"
#include "quality/quality.hpp"

namespace brenier::jobs {
namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

nlohmann::json stats_json(const quality::Stats& s, const char* suffix = "") {
  std::string sfx = suffix;
  return {{"mean" + sfx, s.mean}, {"p95" + sfx, s.p95}, {"max" + sfx, s.max}};
}

}  // namespace

nlohmann::json problems_json(const mesh::Report& report) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& p : report.problems)
    out.push_back({{"severity", p.severity == mesh::Problem::Severity::kError ? "error" : "warning"},
                   {"code", p.code},
                   {"message", name_options(p.message, OptionStyle::kField)},
                   {"count", p.count}});
  return out;
}

nlohmann::json topology_json(const mesh::Topology& t) {
  return {{"vertices", t.vertices},
          {"edges", t.edges},
          {"faces", t.faces},
          {"components", t.components},
          {"boundary_loops", t.boundary_loops},
          {"euler", t.euler},
          {"genus", t.genus},
          {"manifold", t.manifold},
          {"class", mesh::class_name(t.mesh_class)}};
}

omt::Progress solver_progress(const ProgressSink& sink, const std::string& stage, double tolerance, double from,
                              double to) {
  if (!sink) return {};
  // The residual falls from its first value r0 towards the tolerance, roughly geometrically
  // once Newton's method is in its quadratic phase: log(r0 / r) / log(r0 / tol) estimates
  // the share done (never backwards).
  auto first = std::make_shared<double>(-1.0);
  auto best = std::make_shared<double>(0.0);
  return [=](int iteration, double residual) {
    if (*first < 0 && residual > 0 && std::isfinite(residual)) *first = residual;
    double share = 0;
    if (*first > tolerance && residual > 0 && std::isfinite(residual))
      share = std::clamp(std::log(*first / residual) / std::log(*first / tolerance), 0.0, 1.0);
    *best = std::max(*best, share);
    return sink(Progress{stage, from + (to - from) * *best, iteration, residual});
  };
}

std::vector<double> read_weights_file(const std::string& path, int64_t count) {
  std::ifstream in(path);
  if (!in) invalid("cannot read the weights file " + path);
  std::vector<double> w;
  std::string tok;
  while (in >> tok) {
    char* end = nullptr;
    const double x = std::strtod(tok.c_str(), &end);
    if (end == tok.c_str() || *end != '\0' || !(x > 0) || !std::isfinite(x))
      invalid(path + ": weight " + std::to_string(w.size()) + " is '" + tok + "'; weights must be positive numbers");
    w.push_back(x);
  }
  if (static_cast<int64_t>(w.size()) != count)
    invalid(path + ": " + std::to_string(w.size()) + " weights for " + std::to_string(count) + " vertices");
  return w;
}

MapOutcome run_map(const mesh::CleanMesh& cm, const std::string& what, const MapRequest& o,
                   const ProgressSink& progress) {
  mesh::require_valid(cm, what);
  if (o.domain != "disk" && o.domain != "sphere") invalid("unknown domain '" + o.domain + "' (disk or sphere)");
  if (o.method != "conformal" && o.method != "area-preserving")
    invalid("unknown method '" + o.method + "' (conformal or area-preserving)");
  if (!(o.t >= 0 && o.t <= 1)) invalid("t must lie in [0, 1]");
  if (!(o.tolerance >= 0) || !std::isfinite(o.tolerance)) invalid("the tolerance must be a positive number");
  if (o.max_iterations < 1) invalid("max_iterations must be positive");
  // Vertex numbers given by the user are those of the input file.
  std::vector<int> to_clean(static_cast<size_t>(cm.input_vertices), -1);
  for (size_t i = 0; i < cm.vertex_origin.size(); ++i) to_clean[cm.vertex_origin[i]] = static_cast<int>(i);
  auto clean_index = [&](int v, const char* kind) {
    if (v < 0 || v >= cm.input_vertices || to_clean[v] < 0)
      invalid(std::string(kind) + " " + std::to_string(v) + " is not a vertex of the mesh");
    return to_clean[v];
  };

  MapOutcome out;
  out.disk = o.domain == "disk";
  mesh::TriMesh surface = cm.mesh;
  std::vector<int> origin = cm.vertex_origin;
  int cut_vertex = -1;
  if (o.cut_hole) {
    if (!out.disk) invalid("cut_hole applies to the disk domain");
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
    if (o.markers.size() != 3) invalid("sphere markers are three vertices (sent to 0, 1, infinity)");
    co.sphere_markers = std::array<int, 3>{clean_index(o.markers[0], "marker"), clean_index(o.markers[1], "marker"),
                                           clean_index(o.markers[2], "marker")};
  }
  const bool area_preserving = o.method == "area-preserving";
  if (!area_preserving && (o.t > 0 || !o.weights.empty()))
    invalid("t and weights apply to the area-preserving method");
  const auto t1 = std::chrono::steady_clock::now();
  conformal::ConformalMap map;
  std::optional<omt::AreaPreservingMap> ap;
  if (!area_preserving) {
    co.progress = solver_progress(progress, "conformal", co.tolerance, 0.0, 0.95);
    map = out.disk ? conformal::map_to_disk(surface, co) : conformal::map_to_sphere(surface, co);
  } else {
    omt::AreaPreservingOptions apo;
    apo.conformal = co;
    apo.conformal.tolerance = 1e-7;
    apo.conformal.progress = solver_progress(progress, "conformal", 1e-7, 0.0, 0.3);
    if (o.tolerance > 0) apo.omt.tolerance = o.tolerance;
    apo.omt.max_iterations = o.max_iterations;
    apo.omt.progress = solver_progress(progress, "omt", apo.omt.tolerance, 0.3, 0.95);
    apo.t = o.t;
    if (progress)
      apo.repair_progress = [progress](int round, int folds) {
        return progress(Progress{"fold repair", 0.95, round + 1, static_cast<double>(folds)});
      };
    if (!o.weights.empty()) {
      if (static_cast<int64_t>(o.weights.size()) != cm.input_vertices)
        invalid(std::to_string(o.weights.size()) + " weights for " + std::to_string(cm.input_vertices) + " vertices");
      apo.weights.resize(static_cast<int>(origin.size()));
      for (size_t i = 0; i < origin.size(); ++i) {
        const double w = o.weights[origin[i]];
        if (!(w > 0) || !std::isfinite(w))
          invalid("weight " + std::to_string(origin[i]) + " is " + std::to_string(w) + "; weights must be positive");
        apo.weights[static_cast<int>(i)] = w;
      }
    }
    ap = out.disk ? omt::area_preserving_disk(surface, apo) : omt::area_preserving_sphere(surface, apo);
    map = ap->conformal;
  }
  out.positions = ap ? ap->positions : map.positions;
  const double t_map = seconds_since(t1);
  if (!map.converged) {
    char buf[200];
    std::snprintf(buf, sizeof buf, ": the conformal map did not converge: max |K - Kbar| = %.3e rad after %d Newton iterations",
                  map.max_curvature_error, map.newton_iterations);
    fail(ErrorCode::kNotConverged, what + buf);
  }
  if (progress && !progress(Progress{"quality", 0.96, 0, 0})) fail(ErrorCode::kCancelled, "cancelled");

  const quality::MapQuality q =
      quality::measure(surface, out.positions, out.disk ? quality::Target::kPlane : quality::Target::kSphere);
  if (q.flipped_faces > 0 && !o.allow_flips) {
    std::string list;
    for (size_t i = 0; i < q.flipped.size() && i < 8; ++i) list += (i ? ", " : "") + std::to_string(q.flipped[i]);
    // Say why when the first folded face is too small for doubles: a region the conformal
    // map compresses below ~1e-8 has cross products at round-off level (long protrusions).
    const int f = q.flipped.front();
    double size = 0;
    for (int k = 0; k < 3; ++k)
      size = std::max(size, (out.positions.row(surface.F(f, k)) - out.positions.row(surface.F(f, (k + 1) % 3))).norm());
    std::string why;
    if (size < 1e-8) {
      char buf[160];
      std::snprintf(buf, sizeof buf, "; face %d is %.1e across in the image: the map compresses it below double precision",
                    f, size);
      why = buf;
    }
    fail(ErrorCode::kNotConverged, what + ": the map folds " + std::to_string(q.flipped_faces) + " faces (first: " + list +
                                       ")" + why + "; set {allow_flips} to write it anyway");
  }

  if (!quality::covers_once(q.degree) && !o.allow_flips) {
    char buf[160];
    std::snprintf(buf, sizeof buf, ": the map covers the sphere %.0f times, so it is no bijection; set {allow_flips} to write it anyway",
                  q.degree);
    fail(ErrorCode::kNotConverged, what + buf);
  }

  const mesh::Topology topo = mesh::compute_topology(cm.mesh);
  nlohmann::json& j = out.report;
  j["mesh"] = {{"vertices", topo.vertices}, {"faces", topo.faces}, {"boundary_loops", topo.boundary_loops},
               {"genus", topo.genus}, {"class", mesh::class_name(topo.mesh_class)}};
  if (cut_vertex >= 0) j["cut_hole_vertex"] = cut_vertex;
  j["domain"] = o.domain;
  j["method"] = o.method;
  j["seconds"] = {{"map", t_map}};
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
                {"relaxed_vertices", ap->relaxed_vertices},
                {"start", ap->spreading_stages ? "spread" : "conformal"},
                {"spreading_stages", ap->spreading_stages},
                {"spreading_newton_iterations", ap->spreading_newton_iterations}};
  j["quality"] = {{"flipped_faces", q.flipped_faces},
                  {"degree", q.degree},
                  {"angle_distortion_deg", stats_json(q.angle_distortion_deg)},
                  {"area_distortion_log", stats_json(q.area_distortion_log_abs, "_abs")},
                  {"quasi_conformal", stats_json(q.quasi_conformal)}};
  j["problems"] = problems_json(cm.report);
  out.surface = std::move(surface);
  return out;
}

std::string map_mesh_bytes(const MapOutcome& map, mesh::Format format) {
  if (map.disk) {
    const mesh::UV uv = map.positions.leftCols(2);
    return mesh::write_mesh_string(map.surface, format, &uv);
  }
  const mesh::TriMesh sphere{map.positions, map.surface.F};
  return mesh::write_mesh_string(sphere, format);
}

void write_map_file(const MapOutcome& map, const std::string& path) {
  if (map.disk) {
    const mesh::UV uv = map.positions.leftCols(2);
    mesh::write_mesh_file(path, map.surface, &uv);
  } else {
    const mesh::TriMesh sphere{map.positions, map.surface.F};
    mesh::write_mesh_file(path, sphere);
  }
}

}  // namespace brenier::jobs

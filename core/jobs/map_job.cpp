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

// The face-by-face refinement's report: whether it ran and met its tolerances, and the
// per-face |log area ratio| before and after.
nlohmann::json refinement_json(const omt::AreaRefinement& r) {
  nlohmann::json j = {{"ran", r.ran}};
  if (!r.ran) return j;
  j.update({{"converged", r.converged},
            {"kept_start", r.kept_start},
            {"iterations", r.iterations},
            {"stages", r.stages},
            {"tolerance", {{"mean_abs", r.mean_tolerance}, {"p95_abs", r.p95_tolerance}}},
            {"seconds", r.seconds},
            {"area_distortion_log_before", stats_json(r.before, "_abs")},
            {"area_distortion_log_after", stats_json(r.after, "_abs")}});
  return j;
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

namespace {

// The surface a map is computed on: the cleaned mesh, opened by a cut hole when asked, with
// the way back from its vertices to the input file's numbers, which users give.
struct Surface {
  mesh::TriMesh mesh;
  std::vector<int> origin;   // input vertex of each vertex
  std::vector<int> to_mesh;  // vertex of each input vertex (-1: removed or merged away)
  std::vector<int> faces;    // the cleaned mesh's face of each face
  int cut_vertex = -1;       // input number of the vertex a cut hole removed

  Surface(const mesh::CleanMesh& cm) : mesh(cm.mesh), origin(cm.vertex_origin) {
    to_mesh.assign(static_cast<size_t>(cm.input_vertices), -1);
    faces.resize(static_cast<size_t>(mesh.num_faces()));
    for (size_t f = 0; f < faces.size(); ++f) faces[f] = static_cast<int>(f);
    renumber();
  }
  void renumber() {
    std::fill(to_mesh.begin(), to_mesh.end(), -1);
    for (size_t i = 0; i < origin.size(); ++i) to_mesh[origin[i]] = static_cast<int>(i);
  }
  int vertex(int input, const char* kind) const {
    if (input < 0 || input >= static_cast<int>(to_mesh.size()) || to_mesh[input] < 0)
      invalid(std::string(kind) + " " + std::to_string(input) + " is not a vertex of the mesh");
    return to_mesh[input];
  }
  void cut_hole(int hole_vertex) {
    auto cut = mesh::cut_hole(mesh, hole_vertex >= 0 ? std::optional<int>(vertex(hole_vertex, "hole vertex")) : std::nullopt);
    cut_vertex = origin[cut.vertex];
    std::vector<int> o2;
    for (int v : cut.vertex_origin) o2.push_back(origin[v]);
    origin = std::move(o2);
    std::vector<int> f2;
    for (int f : cut.face_origin) f2.push_back(faces[static_cast<size_t>(f)]);
    faces = std::move(f2);
    mesh = std::move(cut.mesh);
    renumber();
  }
};

conformal::ConformalOptions conformal_options(const MapRequest& o, const Surface& s) {
  conformal::ConformalOptions co;
  co.tolerance = o.tolerance > 0 ? o.tolerance : 1e-7;
  co.max_iterations = o.max_iterations;
  if (o.domain == Domain::kDisk && !o.markers.empty()) {
    co.center_vertex = s.vertex(o.center(), "center vertex");
    co.boundary_vertex = s.vertex(o.boundary(), "boundary marker");
  }
  if (o.domain == Domain::kSphere && !o.markers.empty())
    co.sphere_markers = std::array<int, 3>{s.vertex(o.markers[0], "marker"), s.vertex(o.markers[1], "marker"),
                                           s.vertex(o.markers[2], "marker")};
  return co;
}

// The area-preserving map's options: the conformal start to 1e-7 rad, then the transport
// (Alg. 3) with the request's tolerance, phi_t and weights carried to the surface's vertices.
omt::AreaPreservingOptions area_preserving_options(const MapRequest& o, const Surface& s, int64_t input_vertices,
                                                   conformal::ConformalOptions co, const ProgressSink& progress) {
  omt::AreaPreservingOptions apo;
  apo.conformal = std::move(co);
  apo.conformal.tolerance = 1e-7;
  apo.conformal.progress = solver_progress(progress, "conformal", 1e-7, 0.0, 0.3);
  if (o.tolerance > 0) apo.omt.tolerance = o.tolerance;
  apo.omt.max_iterations = o.max_iterations;
  apo.omt.progress = solver_progress(progress, "omt", apo.omt.tolerance, 0.3, 0.95);
  apo.t = o.t;
  apo.refine.enabled = o.refine;
  if (o.refine_mean_tolerance > 0) apo.refine.mean_tolerance = o.refine_mean_tolerance;
  if (o.refine_p95_tolerance > 0) apo.refine.p95_tolerance = o.refine_p95_tolerance;
  // The refinement after the transport (iteration = Newton step, residual = mean |log area
  // ratio|), cancellable at each step.
  apo.refine.keep_going = solver_progress(progress, "area refinement", apo.refine.mean_tolerance, 0.95, 0.98);
  if (progress)
    apo.repair_progress = [progress](int round, int folds) {
      return progress(Progress{"fold repair", 0.95, round + 1, static_cast<double>(folds)});
    };
  if (!o.weights.empty()) {
    if (static_cast<int64_t>(o.weights.size()) != input_vertices)
      invalid(std::to_string(o.weights.size()) + " {weights} for " + std::to_string(input_vertices) + " vertices");
    apo.weights.resize(static_cast<int>(s.origin.size()));
    for (size_t i = 0; i < s.origin.size(); ++i) apo.weights[static_cast<int>(i)] = o.weights[s.origin[i]];
  }
  return apo;
}

// A map that folds faces (or covers the sphere more than once) is refused unless asked for.
void require_bijective(const quality::MapQuality& q, const Surface& s, const mesh::Vertices& positions,
                       const std::string& what) {
  if (q.flipped_faces > 0) {
    std::string list;
    for (size_t i = 0; i < q.flipped.size() && i < 8; ++i) list += (i ? ", " : "") + std::to_string(q.flipped[i]);
    // Say why when the first folded face is too small for doubles: a region the conformal
    // map compresses below ~1e-8 has cross products at round-off level (long protrusions).
    const int f = q.flipped.front();
    double size = 0;
    for (int k = 0; k < 3; ++k)
      size = std::max(size, (positions.row(s.mesh.F(f, k)) - positions.row(s.mesh.F(f, (k + 1) % 3))).norm());
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
  if (!quality::covers_once(q.degree)) {
    char buf[160];
    std::snprintf(buf, sizeof buf, ": the map covers the sphere %.0f times, so it is no bijection; set {allow_flips} to write it anyway",
                  q.degree);
    fail(ErrorCode::kNotConverged, what + buf);
  }
}

// The report of DESIGN.md's contract, but for seconds.read/total that the caller adds.
nlohmann::json map_report(const mesh::CleanMesh& cm, const MapRequest& o, const Surface& s, double t_map,
                          const conformal::ConformalMap& map, const omt::AreaPreservingMap* ap,
                          const quality::MapQuality& q) {
  const mesh::Topology topo = mesh::compute_topology(cm.mesh);
  nlohmann::json j;
  j["mesh"] = {{"vertices", topo.vertices}, {"faces", topo.faces}, {"boundary_loops", topo.boundary_loops},
               {"genus", topo.genus}, {"class", mesh::class_name(topo.mesh_class)}};
  if (s.cut_vertex >= 0) j["cut_hole_vertex"] = s.cut_vertex;
  j["domain"] = domain_name(o.domain);
  j["method"] = map_method_name(o.method);
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
                {"spreading_newton_iterations", ap->spreading_newton_iterations},
                {"refined", refinement_json(ap->refinement)}};
  if (ap && o.domain == Domain::kSphere) j["omt"]["pole"] = {ap->pole.x(), ap->pole.y(), ap->pole.z()};
  j["quality"] = {{"flipped_faces", q.flipped_faces},
                  {"degree", q.degree},
                  {"angle_distortion_deg", stats_json(q.angle_distortion_deg)},
                  {"area_distortion_log", stats_json(q.area_distortion_log_abs, "_abs")},
                  {"quasi_conformal", stats_json(q.quasi_conformal)}};
  j["problems"] = problems_json(cm.report);
  return j;
}

}  // namespace

MapOutcome run_map(const mesh::CleanMesh& cm, const std::string& what, const MapRequest& o,
                   const ProgressSink& progress, const omt::PoleChooser& pole) {
  o.validate();
  mesh::require_valid(cm, what);
  MapOutcome out;
  out.disk = o.domain == Domain::kDisk;
  Surface s(cm);
  if (o.cut_hole) s.cut_hole(o.hole_vertex);
  conformal::ConformalOptions co = conformal_options(o, s);

  const auto t1 = std::chrono::steady_clock::now();
  conformal::ConformalMap map;
  std::optional<omt::AreaPreservingMap> ap;
  if (o.method == MapMethod::kConformal) {
    co.progress = solver_progress(progress, "conformal", co.tolerance, 0.0, 0.95);
    map = out.disk ? conformal::map_to_disk(s.mesh, co) : conformal::map_to_sphere(s.mesh, co);
  } else {
    omt::AreaPreservingOptions apo = area_preserving_options(o, s, cm.input_vertices, co, progress);
    apo.pole = pole;
    ap = out.disk ? omt::area_preserving_disk(s.mesh, apo) : omt::area_preserving_sphere(s.mesh, apo);
    map = ap->conformal;
  }
  out.positions = ap ? ap->positions : map.positions;
  if (ap) out.conformal = map.positions;
  const double t_map = seconds_since(t1);
  if (!map.converged) {
    char buf[200];
    std::snprintf(buf, sizeof buf, ": the conformal map did not converge: max |K - Kbar| = %.3e rad after %d Newton iterations",
                  map.max_curvature_error, map.newton_iterations);
    fail(ErrorCode::kNotConverged, what + buf);
  }
  if (progress && !progress(Progress{"quality", 0.99, 0, 0})) fail(ErrorCode::kCancelled, "cancelled");

  const quality::MapQuality q =
      quality::measure(s.mesh, out.positions, out.disk ? quality::Target::kPlane : quality::Target::kSphere);
  if (!o.allow_flips) require_bijective(q, s, out.positions, what);
  out.report = map_report(cm, o, s, t_map, map, ap ? &*ap : nullptr, q);
  out.surface = std::move(s.mesh);
  out.vertex_origin = std::move(s.origin);
  out.face_origin = std::move(s.faces);
  out.cut_vertex = s.cut_vertex;
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

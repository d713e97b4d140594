// Distance jobs: shapes made ready for the distances (domain checks, cut holes, markers) and
// one pair (Alg. 5 / Def. 2.24) with its report.
#include <chrono>
#include <cmath>
#include <cstdio>

#include "common/error.hpp"
#include "common/parallel.hpp"
#include "jobs/jobs.hpp"
#include "mesh/geometry.hpp"
#include "mesh/topology.hpp"

namespace brenier::jobs {

distance::ShapeOptions shape_options(const ShapeRequest& request) {
  request.validate();
  distance::ShapeOptions o;
  o.sphere = request.domain == Domain::kSphere;
  o.transport_tolerance = request.tolerance;
  o.cost_tolerance = request.cost_tolerance;
  o.quadrature.rings = request.rings;
  o.quadrature.angles = request.angles;
  return o;
}

distance::WassersteinOptions wasserstein_options(const ShapeRequest& request) {
  distance::WassersteinOptions w;
  w.refine_rotation = request.refine_rotation;
  w.debias = !request.raw;
  w.exact_rotation = request.exact_rotation;
  return w;
}

distance::ShapeInput shape_input(const mesh::CleanMesh& cm, const std::string& name, const std::string& what,
                                 const ShapeRequest& request, DiskMarkers markers) {
  mesh::require_valid(cm, what);
  std::vector<int> to_clean(static_cast<size_t>(cm.input_vertices), -1);
  for (size_t i = 0; i < cm.vertex_origin.size(); ++i) to_clean[cm.vertex_origin[i]] = static_cast<int>(i);
  distance::ShapeInput in;
  in.name = name;
  in.mesh = cm.mesh;
  in.options = shape_options(request);
  const mesh::Topology t = mesh::compute_topology(in.mesh);
  if (request.domain == Domain::kSphere) {
    if (t.mesh_class != mesh::MeshClass::kSphere)
      invalid(what + ": is a " + std::string(mesh::class_name(t.mesh_class)) +
              " mesh; shape distances on the sphere need closed genus-0 surfaces");
  } else if (request.cut_hole && t.mesh_class == mesh::MeshClass::kSphere) {
    mesh::CutHole h = mesh::cut_hole(in.mesh, std::nullopt);
    std::vector<int> back(cm.vertex_origin.size(), -1);
    for (size_t i = 0; i < h.vertex_origin.size(); ++i) back[h.vertex_origin[i]] = static_cast<int>(i);
    for (int& v : to_clean) v = v >= 0 ? back[v] : -1;
    in.mesh = std::move(h.mesh);
  } else if (t.mesh_class != mesh::MeshClass::kDisk) {
    invalid(what + ": is a " + std::string(mesh::class_name(t.mesh_class)) +
            " mesh; shape distances on the disk need topological disks" +
            (t.mesh_class == mesh::MeshClass::kSphere ? " (set {cut_hole} to open it)" : ""));
  }
  auto marker = [&](int v, const char* kind) {
    if (v < 0 || v >= cm.input_vertices || to_clean[v] < 0)
      invalid(what + ": " + kind + " " + std::to_string(v) + " is not a vertex of the mesh");
    return to_clean[v];
  };
  if (markers.given()) {
    if (markers.center < 0 || markers.boundary < 0)
      invalid(what + ": give both {markers} (center and boundary) or neither");
    in.options.center_vertex = marker(markers.center, "center vertex");
    in.options.boundary_vertex = marker(markers.boundary, "boundary vertex");
  }
  return in;
}

nlohmann::json pair_json(const distance::PairResult& r, distance::Method method) {
  nlohmann::json j = {{"method", distance::method_name(method)},
                      {"distance", r.distance},
                      {"rotation_rad", r.rotation},
                      {"normalization", r.normalization},
                      {"converged", r.converged}};
  if (method == distance::Method::kWasserstein) {
    j["forward"] = r.forward;
    j["backward"] = r.backward;
    j["raw_forward"] = r.raw_forward;
    j["raw_backward"] = r.raw_backward;
    // Sphere pairs with one crowded density: the one direction solved (PairResult::source).
    j["directions"] = r.source < 0 ? nlohmann::json{"forward", "backward"}
                                   : nlohmann::json{r.source == 0 ? "forward" : "backward"};
    j["newton_iterations"] = r.newton_iterations;
    j["max_relative_area_error"] = r.max_relative_error;
    j["max_relative_cost_gap"] = r.max_relative_cost_gap;
    // The turns (disk) or half-turns (sphere) compared by the exact cost, the chosen one's
    // certificate: every other one converged above it or was abandoned with a lower bound
    // above it less the tolerance.
    nlohmann::json cands = nlohmann::json::array();
    for (const distance::PairResult::Candidate& c : r.candidates) {
      nlohmann::json x = {{"omt_map_distance", c.omt_map},
                          {"lower_bound", c.lower_bound},
                          {"abandoned", c.abandoned},
                          {"newton_iterations", c.newton_iterations}};
      x["distance"] = std::isfinite(c.distance) ? nlohmann::json(c.distance) : nlohmann::json();
      if (r.sphere_frames) x["frame"] = c.frame; else x["rotation_rad"] = c.rotation;
      cands.push_back(x);
    }
    j["rotation_candidates"] = cands;
    j["rotation_certified"] = r.rotation_certified;
  }
  return j;
}

nlohmann::json shape_json(const distance::Shape& x) {
  nlohmann::json j = {{"name", x.name},
          {"vertices", x.vertices},
          {"faces", x.faces},
          {"key", x.key},
          {"normalization", x.normalization},
          {"conformal_newton_iterations", x.conformal_iterations},
          {"quantization_w2", std::sqrt(x.quantization)},
          {"omt_newton_iterations", x.omt_iterations}};
  if (x.sphere) {
    j["merged_vertices"] = x.merged_vertices;
    j["merge_shift"] = x.merge_shift;
    j["merge_radius"] = x.merge_radius;
    j["density_shift"] = x.density_shift;
    j["capped_mass"] = x.capped_mass;
  }
  return j;
}

std::string not_converged_message(const distance::PairResult& r) {
  char buf[200];
  std::snprintf(buf, sizeof buf, "the transport did not converge (max relative cell-mass error %.2e)",
                r.max_relative_error);
  return buf;
}

DistanceOutcome run_distance(const distance::ShapeInput& a, const distance::ShapeInput& b,
                             const ShapeRequest& request, int threads, const ProgressSink& progress) {
  const auto t0 = std::chrono::steady_clock::now();
  request.validate();
  const distance::Method method = request.method;
  const distance::ShapeInput* in[2] = {&a, &b};
  distance::Shape s[2];
  // Two shapes may report at once: one sink call at a time, the fraction of the slower.
  std::mutex mutex;
  ProgressSink shared;
  if (progress)
    shared = [&](const Progress& p) {
      std::lock_guard<std::mutex> lock(mutex);
      return progress(p);
    };
  parallel_for(2, threads, [&](int k) {
    s[k] = distance::prepare_shape(in[k]->mesh, in[k]->name, in[k]->options,
                                   solver_progress(shared, "shapes", 1e-7, 0.0, 0.5));
  });
  const double t_shapes = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const auto t1 = std::chrono::steady_clock::now();
  distance::WassersteinOptions wo = wasserstein_options(request);
  wo.parallel_directions = threads > 1;
  wo.progress = solver_progress(shared, "pair", request.tolerance, 0.5, 1.0);
  DistanceOutcome out;
  out.result = method == distance::Method::kWasserstein ? distance::wasserstein(s[0], s[1], wo)
                                                        : distance::omt_linear(s[0], s[1]);
  const double t_pair = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  out.report = pair_json(out.result, request.method);
  out.report["domain"] = domain_name(request.domain);
  out.report["seconds"] = {{"shapes", t_shapes}, {"pair", t_pair}};
  for (const distance::Shape& x : s) out.report["shapes"].push_back(shape_json(x));
  if (s[0].sphere)
    // What the merge of close vertex images (ShapeOptions::merge_radius) guarantees: each
    // transport's W2 is within the farther shift of the one onto the unmerged measure.
    // The radius is the larger of the two shapes' (each starts at ShapeOptions::merge_radius
    // and grows where its transport needs it).
    out.report["measure_merge"] = {{"radius", std::max(s[0].merge_radius, s[1].merge_radius)},
                                   {"radii", {s[0].merge_radius, s[1].merge_radius}},
                                   {"merged_vertices", {s[0].merged_vertices, s[1].merged_vertices}},
                                   {"w2_bound", std::max(s[0].merge_shift, s[1].merge_shift)}};
  if (s[0].sphere && request.method == distance::Method::kWasserstein) {
    // What the cap on the source densities (ShapeOptions::density_cap) guarantees: each
    // transport's W2 is within the farther shift of the one from the uncapped density; a
    // direction that needed a lower cap (transport_cost_sphere's retry) adds that cap's shift
    // (the triangle inequality), and names the cap in lowered_caps (null: not lowered).
    const distance::PairResult& r = out.result;
    nlohmann::json lowered = nlohmann::json::array();
    for (const double cap : r.lowered_cap) lowered.push_back(cap > 0 ? nlohmann::json(cap) : nlohmann::json());
    out.report["density_cap"] = {
        {"cap", a.options.density_cap},
        {"capped_mass", {s[0].capped_mass, s[1].capped_mass}},
        {"lowered_caps", lowered},
        {"w2_bound", std::max(s[0].density_shift + r.lowered_shift[0], s[1].density_shift + r.lowered_shift[1])}};
  }
  out.a = std::move(s[0]);
  out.b = std::move(s[1]);
  return out;
}

}  // namespace brenier::jobs

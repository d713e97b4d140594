// Distance jobs: shapes made ready for the distances (domain checks, cut holes, markers) and
// one pair (Alg. 5 / Def. 2.24) with its report.
#include <chrono>
#include <cmath>

#include "common/error.hpp"
#include "common/parallel.hpp"
#include "jobs/jobs.hpp"
#include "mesh/geometry.hpp"
#include "mesh/topology.hpp"

namespace brenier::jobs {

distance::ShapeOptions ShapeRequest::shape_options() const {
  if (domain != "disk" && domain != "sphere") invalid("unknown domain '" + domain + "' (disk or sphere)");
  distance::parse_method(method);
  if (domain == "sphere" && cut_hole) invalid("cut_hole applies to the disk domain");
  if (domain == "sphere" && refine_rotation)
    invalid("refine_rotation applies to the disk domain (on the sphere the frame's half-turns are compared)");
  if (!(tolerance > 0) || !std::isfinite(tolerance)) invalid("the tolerance must be a positive number");
  distance::ShapeOptions o;
  o.sphere = domain == "sphere";
  o.transport_tolerance = tolerance;
  if (!(cost_tolerance >= 0) || !std::isfinite(cost_tolerance)) invalid("the cost tolerance must be 0 or a positive number");
  o.cost_tolerance = cost_tolerance;
  o.quadrature.rings = rings;
  o.quadrature.angles = angles;
  return o;
}

distance::WassersteinOptions ShapeRequest::wasserstein() const {
  distance::WassersteinOptions w;
  w.refine_rotation = refine_rotation;
  w.debias = !raw;
  return w;
}

distance::ShapeInput shape_input(const mesh::CleanMesh& cm, const std::string& name, const std::string& what,
                                 const ShapeRequest& request, int center, int boundary) {
  mesh::require_valid(cm, what);
  std::vector<int> to_clean(static_cast<size_t>(cm.input_vertices), -1);
  for (size_t i = 0; i < cm.vertex_origin.size(); ++i) to_clean[cm.vertex_origin[i]] = static_cast<int>(i);
  distance::ShapeInput in;
  in.name = name;
  in.mesh = cm.mesh;
  in.options = request.shape_options();
  const mesh::Topology t = mesh::compute_topology(in.mesh);
  if (request.domain == "sphere") {
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
  if ((center >= 0) != (boundary >= 0)) invalid(what + ": give both markers (center and boundary) or neither");
  if (center >= 0) {
    in.options.center_vertex = marker(center, "center vertex");
    in.options.boundary_vertex = marker(boundary, "boundary vertex");
  }
  return in;
}

nlohmann::json pair_json(const distance::PairResult& r, const std::string& method) {
  nlohmann::json j = {{"method", method},
                      {"distance", r.distance},
                      {"rotation_rad", r.rotation},
                      {"normalization", r.normalization},
                      {"converged", r.converged}};
  if (method == "wasserstein") {
    j["forward"] = r.forward;
    j["backward"] = r.backward;
    j["raw_forward"] = r.raw_forward;
    j["raw_backward"] = r.raw_backward;
    j["newton_iterations"] = r.newton_iterations;
    j["max_relative_area_error"] = r.max_relative_error;
    j["max_relative_cost_gap"] = r.max_relative_cost_gap;
  }
  return j;
}

nlohmann::json shape_json(const distance::Shape& x) {
  return {{"name", x.name},
          {"vertices", x.vertices},
          {"faces", x.faces},
          {"key", x.key},
          {"normalization", x.normalization},
          {"conformal_newton_iterations", x.conformal_iterations},
          {"quantization_w2", std::sqrt(x.quantization)},
          {"omt_newton_iterations", x.omt_iterations}};
}

DistanceOutcome run_distance(const distance::ShapeInput& a, const distance::ShapeInput& b,
                             const ShapeRequest& request, int threads, const ProgressSink& progress) {
  const auto t0 = std::chrono::steady_clock::now();
  const distance::Method method = distance::parse_method(request.method);
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
  distance::WassersteinOptions wo = request.wasserstein();
  wo.parallel_directions = threads > 1;
  wo.progress = solver_progress(shared, "pair", request.tolerance, 0.5, 1.0);
  DistanceOutcome out;
  out.result = method == distance::Method::kWasserstein ? distance::wasserstein(s[0], s[1], wo)
                                                        : distance::omt_linear(s[0], s[1]);
  const double t_pair = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  out.report = pair_json(out.result, request.method);
  out.report["domain"] = request.domain;
  out.report["seconds"] = {{"shapes", t_shapes}, {"pair", t_pair}};
  for (const distance::Shape& x : s) out.report["shapes"].push_back(shape_json(x));
  out.a = std::move(s[0]);
  out.b = std::move(s[1]);
  return out;
}

}  // namespace brenier::jobs

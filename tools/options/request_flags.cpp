#include "request_flags.hpp"

#include <algorithm>
#include <cmath>
#include <optional>
#include <string_view>
#include <vector>

#include "common/error.hpp"

namespace brenier::options {
namespace {

// An enum option given by name (the requests' own names and lookup, requests.hpp): the
// name becomes the enum's number for CLI11 to store, and anything else is refused with the
// names to choose from.
template <class E>
CLI::Validator choices(std::initializer_list<E> values, const char* (*name)(E), std::optional<E> (*find)(std::string_view)) {
  std::vector<std::string> names;
  for (E e : values) names.push_back(name(e));
  std::sort(names.begin(), names.end());
  std::string list;
  for (const std::string& n : names) list += (list.empty() ? "" : ", ") + n;
  return CLI::Validator(
      [find, list](std::string& in) -> std::string {
        const std::optional<E> e = find(in);
        if (!e) return "'" + in + "' is not one of " + list;
        in = std::to_string(static_cast<int>(*e));
        return {};
      },
      "{" + list + "}");
}

// A number whose value passes `ok`, described as `what` ("a positive number") in the refusal and
// as `name` in the help's type column.
CLI::Validator number_that(bool (*ok)(double), const std::string& what, const std::string& name) {
  return CLI::Validator(
      [ok, what](std::string& in) -> std::string {
        double x = 0;
        if (!CLI::detail::lexical_cast(in, x) || !std::isfinite(x) || !ok(x)) return "'" + in + "' is not " + what;
        return {};
      },
      name);
}

}  // namespace

CLI::Validator positive_number() {
  return number_that([](double x) { return x > 0; }, "a positive number", "POSITIVE");
}
CLI::Validator non_negative_number() {
  return number_that([](double x) { return x >= 0; }, "a non-negative number", "NONNEGATIVE");
}

CLI::Option* add_domain(CLI::App* cmd, jobs::Domain& domain, const std::string& help) {
  return cmd->add_option("--domain", domain, help)
      ->transform(choices({jobs::Domain::kDisk, jobs::Domain::kSphere}, jobs::domain_name, jobs::find_domain));
}

void add_cut_hole(CLI::App* cmd, bool& cut_hole, int& hole_vertex, const std::string& help) {
  cmd->add_flag("--cut-hole", cut_hole, help);
  cmd->add_option("--hole-vertex", hole_vertex,
                  "with --cut-hole: the vertex whose star is removed (default: a vertex near the surface's "
                  "centre, splitting a near-diametral pair of vertices)")
      ->check(non_negative_number());
}

void MapFlags::add_to(CLI::App* cmd) {
  jobs::MapRequest& r = request;
  add_domain(cmd, r.domain, "disk or sphere");
  cmd->add_option("--method", r.method, "conformal (Alg. 1) or area-preserving (Alg. 3)")
      ->transform(choices({jobs::MapMethod::kConformal, jobs::MapMethod::kAreaPreserving}, jobs::map_method_name, jobs::find_map_method));
  cmd->add_option("--markers", r.markers,
                  "input vertex numbers: disk center,boundary (sent to 0 and 1); sphere v0,v1,vinf (sent to 0, 1, infinity)")
      ->delimiter(',');
  add_cut_hole(cmd, r.cut_hole, r.hole_vertex, "disk: open a closed genus-0 mesh by removing one vertex's star");
  cmd->add_option("--tolerance", r.tolerance,
                  "conformal: max |K - Kbar| (radians, default 1e-7); area-preserving: max relative "
                  "cell-mass error (default 1e-8)")
      ->check(positive_number());
  cmd->add_option("--max-iterations", r.max_iterations, "Newton iterations (default 200)")
      ->check(CLI::Range(1, jobs::MapRequest::kMaxIterations));
  cmd->add_option("--weights", weights_file,
                  "area-preserving: file of one positive weight per input vertex (region of interest)");
  cmd->add_option("--t", r.t, "area-preserving: the polar-factorization map phi_t, 0 area-preserving .. 1 conformal")
      ->check(CLI::Range(0.0, 1.0));
  cmd->add_flag("--allow-flips", r.allow_flips, "return a map even if it folds faces");
  cmd->add_flag("--no-refine{false}", r.refine,
                "area-preserving: the seed's centroid map, without the face-by-face area refinement");
  cmd->add_option("--refine-mean-tolerance", r.refine_mean_tolerance,
                  "area-preserving: the refinement stops once the mean |log area ratio| is at most this (default 0.01) "
                  "and its 95th percentile meets --refine-p95-tolerance")
      ->check(positive_number());
  cmd->add_option("--refine-p95-tolerance", r.refine_p95_tolerance,
                  "area-preserving: the refinement's stop on the 95th percentile of |log area ratio| (default 0.05)")
      ->check(positive_number());
}

jobs::MapRequest MapFlags::resolve() const {
  jobs::MapRequest r = request;
  if (!weights_file.empty()) r.weights = jobs::read_weights_file(weights_file);
  r.validate();
  return r;
}

void RegisterFlags::add_to(CLI::App* cmd) {
  jobs::RegisterRequest& r = request;
  add_domain(cmd, r.domain, "disk (topological disks; closed genus-0 meshes with --cut-hole) or sphere (closed genus-0)");
  cmd->add_option("--method", r.method, "the parameter maps: area-preserving (OMT, Alg. 3; default) or conformal")
      ->transform(choices({jobs::MapMethod::kConformal, jobs::MapMethod::kAreaPreserving}, jobs::map_method_name, jobs::find_map_method));
  cmd->add_flag("--cut-hole", r.cut_hole,
                "disk: open closed genus-0 meshes by removing one vertex's star (at the first landmark pair if given)");
  cmd->add_option("--landmarks", landmark_files,
                  "two files, the source's and the target's landmarks: one vertex number per line, paired by order")
      ->expected(2);
  cmd->add_option("--tolerance", r.tolerance, "the maps' tolerance (as map --tolerance)")->check(positive_number());
  cmd->add_option("--max-iterations", r.max_iterations, "Newton iterations of each map (default 200)")
      ->check(CLI::Range(1, jobs::MapRequest::kMaxIterations));
  cmd->add_flag("--harmonic-only{false}", r.isometric,
                "keep g as Alg. 7 makes it (harmonic, held by the landmarks), without moving it toward an "
                "isometry of the two surfaces afterwards");
  cmd->add_flag("--isometric-sphere", r.isometric_sphere,
                "sphere, conformal route: move g toward an isometry too (on the disk and the sphere's "
                "area-preserving route it is by default; on crowded conformal sphere maps it helps some pairs and "
                "sets others back)");
}

jobs::RegisterRequest RegisterFlags::resolve() const {
  jobs::RegisterRequest r = request;
  if (landmark_files.size() == 2) {
    r.source_landmarks = jobs::read_landmarks_file(landmark_files[0]);
    r.target_landmarks = jobs::read_landmarks_file(landmark_files[1]);
    if (r.source_landmarks.size() != r.target_landmarks.size())
      invalid(landmark_files[0] + " has " + std::to_string(r.source_landmarks.size()) + " landmarks and " + landmark_files[1] +
              " has " + std::to_string(r.target_landmarks.size()) + "; they are paired by order");
  }
  r.validate();
  return r;
}

void ShapeFlags::add_to(CLI::App* cmd) {
  jobs::ShapeRequest& r = request;
  cmd->add_option("--method", r.method, "wasserstein (exact, Alg. 5) or omt-linear (Def. 2.24 as an embedding)")
      ->transform(choices({distance::Method::kWasserstein, distance::Method::kOmtLinear}, distance::method_name, distance::find_method));
  add_domain(cmd, r.domain,
             "disk (topological disks; closed genus-0 surfaces with --cut-hole) or sphere (closed genus-0 "
             "surfaces; wasserstein with the squared chordal cost)");
  cmd->add_flag("--cut-hole", r.cut_hole, "open closed genus-0 meshes into disks by removing one vertex's star");
  cmd->add_option("--tolerance", r.tolerance,
                  "wasserstein: max relative cell-mass error of each transport (default 1e-3; the distance is read "
                  "from the dual, accurate to about the square of it)")
      ->check(positive_number());
  cmd->add_option("--cost-tolerance", r.cost_tolerance,
                  "wasserstein: or stop each transport once its cost is known to this relative accuracy (the "
                  "Newton decrement; default 1e-6, 0: off)")
      ->check(CLI::Range(0.0, 1.0));
  cmd->add_flag("--refine-rotation", r.refine_rotation,
                "wasserstein without markers: refine the rotation beyond the quadrature's step by exact "
                "evaluations (3-4 times the work)");
  cmd->add_flag("--exact-rotation", r.exact_rotation,
                "wasserstein without markers: choose the turn (disk: among the OMT-map distance's local "
                "minima within 10 %) or the frame's half-turn (sphere) by the exact cost, with lower "
                "bounds as the certificate (rotation_candidates in the JSON; several times the work)");
  cmd->add_flag("--raw", r.raw, "wasserstein: eq. 3.31 as it stands, without removing the sites' quantization cost");
  cmd->add_option("--rings", r.rings, "quadrature rings of the OMT-map samples (default 64)")->check(CLI::Range(1, 4096));
  cmd->add_option("--angles", r.angles, "quadrature angles per ring (default 256)")->check(CLI::Range(4, 65536));
}

void DistanceFlags::add_to(CLI::App* cmd) {
  shape.add_to(cmd);
  cmd->add_option("--center-a", a.center, "interior marker of the first mesh (sent to 0)")->check(non_negative_number());
  cmd->add_option("--boundary-a", a.boundary, "boundary marker of the first mesh (sent to 1)")
      ->check(non_negative_number());
  cmd->add_option("--center-b", b.center, "interior marker of the second mesh")->check(non_negative_number());
  cmd->add_option("--boundary-b", b.boundary, "boundary marker of the second mesh")->check(non_negative_number());
}

jobs::DistanceRequest DistanceFlags::resolve() const {
  jobs::DistanceRequest r{shape.request, a, b};
  r.validate();
  return r;
}

void MatrixFlags::add_to(CLI::App* cmd) {
  shape.add_to(cmd);
  cmd->add_option("--markers", markers_file, "file of lines mesh,center_vertex,boundary_vertex (every mesh)");
}

jobs::MatrixRequest MatrixFlags::resolve(const std::vector<std::string>& meshes) const {
  jobs::MatrixRequest r;
  r.shape = shape.request;
  if (!markers_file.empty()) {
    const jobs::MarkersFile file = jobs::read_markers_file(markers_file);
    for (const std::string& m : meshes) r.markers.push_back(file.of(m));
  }
  r.validate(meshes.size());
  return r;
}

}  // namespace brenier::options

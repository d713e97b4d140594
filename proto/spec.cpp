#include "spec.hpp"

#include <cmath>

#include "common/error.hpp"

namespace brenier::spec {
namespace {

// The proto's zero values mean "the default" (proto3 cannot tell unset from 0).
void set_wasserstein(const jobs::ShapeRequest& r, pb::WassersteinOptions* w) {
  w->set_tolerance(r.tolerance);
  w->set_cost_tolerance(r.cost_tolerance > 0 ? r.cost_tolerance : -1.0);
  w->set_refine_rotation(r.refine_rotation);
  w->set_raw(r.raw);
  w->set_exact_rotation(r.exact_rotation);
  w->set_rings(r.rings);
  w->set_angles(r.angles);
}

template <class Spec>
jobs::ShapeRequest shape_request(const Spec& s) {
  jobs::ShapeRequest r;
  r.method = from_proto(s.method());
  r.domain = from_proto(s.domain());
  r.cut_hole = s.cut_hole();
  const pb::WassersteinOptions& w = s.wasserstein();
  if (!(w.tolerance() >= 0) || !std::isfinite(w.tolerance())) invalid("{tolerance} must be a positive number");
  if (w.tolerance() > 0) r.tolerance = w.tolerance();
  if (!std::isfinite(w.cost_tolerance()) || w.cost_tolerance() > 1)
    invalid("{cost_tolerance} must be at most 1 (0: the default, negative: off)");
  if (w.cost_tolerance() != 0) r.cost_tolerance = std::max(0.0, w.cost_tolerance());
  r.refine_rotation = w.refine_rotation();
  r.raw = w.raw();
  r.exact_rotation = w.exact_rotation();
  if (w.rings() != 0) r.rings = w.rings();
  if (w.angles() != 0) r.angles = w.angles();
  return r;
}

// The shape fields every distance spec has.
template <class Spec>
void set_shape(const jobs::ShapeRequest& r, Spec* s) {
  s->set_method(spec::to_proto(r.method));
  s->set_domain(spec::to_proto(r.domain));
  s->set_cut_hole(r.cut_hole);
  set_wasserstein(r, s->mutable_wasserstein());
}

void set_markers(const jobs::DiskMarkers& m, pb::DiskMarkers* p) {
  p->set_center(m.center);
  p->set_boundary(m.boundary);
}

// An absent message is no markers; a present one must give both vertices.
jobs::DiskMarkers markers_from_proto(bool has, const pb::DiskMarkers& m) {
  if (!has) return {};
  if (m.center() < 0 || m.boundary() < 0) invalid("{markers} are vertex numbers");
  return {m.center(), m.boundary()};
}

}  // namespace

pb::Domain to_proto(jobs::Domain d) { return d == jobs::Domain::kSphere ? pb::SPHERE : pb::DISK; }
pb::MapMethod to_proto(jobs::MapMethod m) {
  return m == jobs::MapMethod::kAreaPreserving ? pb::AREA_PRESERVING : pb::CONFORMAL;
}
pb::DistanceMethod to_proto(distance::Method m) {
  return m == distance::Method::kOmtLinear ? pb::OMT_LINEAR : pb::WASSERSTEIN;
}
jobs::Domain from_proto(pb::Domain d) { return d == pb::SPHERE ? jobs::Domain::kSphere : jobs::Domain::kDisk; }
jobs::MapMethod from_proto(pb::MapMethod m) {
  return m == pb::AREA_PRESERVING ? jobs::MapMethod::kAreaPreserving : jobs::MapMethod::kConformal;
}
distance::Method from_proto(pb::DistanceMethod m) {
  return m == pb::OMT_LINEAR ? distance::Method::kOmtLinear : distance::Method::kWasserstein;
}

void to_proto(const jobs::MapRequest& r, pb::MapSpec* s) {
  s->set_domain(to_proto(r.domain));
  s->set_method(to_proto(r.method));
  for (double w : r.weights) s->add_weights(w);
  s->set_t(r.t);
  for (int v : r.markers) s->add_markers(v);
  s->set_cut_hole(r.cut_hole);
  s->set_tolerance(r.tolerance);
  s->set_has_hole_vertex(r.hole_vertex >= 0);
  s->set_hole_vertex(std::max(0, r.hole_vertex));
  s->set_max_iterations(r.max_iterations);
  s->set_allow_flips(r.allow_flips);
  s->set_no_refine(!r.refine);
  s->set_refine_mean_tolerance(r.refine_mean_tolerance);
  s->set_refine_p95_tolerance(r.refine_p95_tolerance);
}

jobs::MapRequest from_proto(const pb::MapSpec& s) {
  jobs::MapRequest r;
  r.domain = from_proto(s.domain());
  r.method = from_proto(s.method());
  r.weights.assign(s.weights().begin(), s.weights().end());
  r.t = s.t();
  r.markers.assign(s.markers().begin(), s.markers().end());
  r.cut_hole = s.cut_hole();
  r.tolerance = s.tolerance();
  if (s.has_hole_vertex()) {
    if (s.hole_vertex() < 0) invalid("{hole_vertex} must be a vertex number");
    r.hole_vertex = s.hole_vertex();
  }
  if (s.max_iterations() != 0) r.max_iterations = s.max_iterations();
  r.allow_flips = s.allow_flips();
  r.refine = !s.no_refine();
  r.refine_mean_tolerance = s.refine_mean_tolerance();
  r.refine_p95_tolerance = s.refine_p95_tolerance();
  r.validate();
  return r;
}

void to_proto(const jobs::DistanceRequest& r, pb::DistanceSpec* s) {
  set_shape(r.shape, s);
  if (r.a.given() || r.b.given()) {
    set_markers(r.a, s->mutable_markers_a());
    set_markers(r.b, s->mutable_markers_b());
  }
}

jobs::DistanceRequest from_proto(const pb::DistanceSpec& s) {
  jobs::DistanceRequest r;
  r.shape = shape_request(s);
  r.a = markers_from_proto(s.has_markers_a(), s.markers_a());
  r.b = markers_from_proto(s.has_markers_b(), s.markers_b());
  r.validate();
  return r;
}

void to_proto(const jobs::MatrixRequest& r, pb::MatrixSpec* s) {
  set_shape(r.shape, s);
  for (const jobs::DiskMarkers& m : r.markers) set_markers(m, s->add_markers());
}

jobs::MatrixRequest from_proto(const pb::MatrixSpec& s) {
  jobs::MatrixRequest r;
  r.shape = shape_request(s);
  for (const pb::DiskMarkers& m : s.markers()) r.markers.push_back(markers_from_proto(true, m));
  r.validate(static_cast<size_t>(s.meshes_size()));
  return r;
}

void to_proto(const jobs::RegisterRequest& r, pb::RegisterSpec* s) {
  s->set_domain(to_proto(r.domain));
  s->set_method(to_proto(r.method));
  s->set_cut_hole(r.cut_hole);
  for (int v : r.source_landmarks) s->add_source_landmarks(v);
  for (int v : r.target_landmarks) s->add_target_landmarks(v);
  s->set_tolerance(r.tolerance);
  s->set_max_iterations(r.max_iterations);
  s->set_harmonic_only(!r.isometric);
  s->set_isometric_sphere(r.isometric_sphere);
}

jobs::RegisterRequest from_proto(const pb::RegisterSpec& s) {
  jobs::RegisterRequest r;
  r.domain = from_proto(s.domain());
  // Unspecified is the OMT route here (Alg. 7's own), unlike a map job's default.
  r.method = s.method() == pb::CONFORMAL ? jobs::MapMethod::kConformal : jobs::MapMethod::kAreaPreserving;
  r.cut_hole = s.cut_hole();
  r.source_landmarks.assign(s.source_landmarks().begin(), s.source_landmarks().end());
  r.target_landmarks.assign(s.target_landmarks().begin(), s.target_landmarks().end());
  r.tolerance = s.tolerance();
  if (s.max_iterations() != 0) r.max_iterations = s.max_iterations();
  r.isometric = !s.harmonic_only();
  r.isometric_sphere = s.isometric_sphere();
  r.validate();
  return r;
}

}  // namespace brenier::spec

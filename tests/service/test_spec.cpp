// The specs of brenier.v1 and the typed requests: what the thin CLI sends is what brenierd
// reads back, and a spec's zero values are the requests' defaults.
#include <gtest/gtest.h>

#include "../unit/expect_error.hpp"
#include "spec.hpp"

namespace brenier::test {
namespace {

namespace pb = brenier::v1;

TEST(Spec, MapRequestsSurviveTheWire) {
  jobs::MapRequest r;
  r.domain = jobs::Domain::kSphere;
  r.method = jobs::MapMethod::kAreaPreserving;
  r.markers = {4, 9, 2};
  r.tolerance = 1e-9;
  r.max_iterations = 77;
  r.weights = {1, 2, 3};
  r.t = 0.25;
  r.allow_flips = true;
  r.refine = false;
  pb::MapSpec s;
  spec::to_proto(r, &s);
  const jobs::MapRequest back = spec::from_proto(s);
  EXPECT_EQ(back.domain, r.domain);
  EXPECT_EQ(back.method, r.method);
  EXPECT_EQ(back.markers, r.markers);
  EXPECT_EQ(back.tolerance, r.tolerance);
  EXPECT_EQ(back.max_iterations, r.max_iterations);
  EXPECT_EQ(back.weights, r.weights);
  EXPECT_EQ(back.t, r.t);
  EXPECT_TRUE(back.allow_flips);
  EXPECT_FALSE(back.refine);
  EXPECT_TRUE(s.no_refine());
  EXPECT_TRUE(spec::from_proto(pb::MapSpec()).refine);  // an old client's spec: refined
  // The refinement's stop travels with a refined request; zero is the engine's default.
  jobs::MapRequest stop;
  stop.method = jobs::MapMethod::kAreaPreserving;
  stop.refine_mean_tolerance = 0.02;
  stop.refine_p95_tolerance = 0.1;
  s.Clear();
  spec::to_proto(stop, &s);
  EXPECT_EQ(s.refine_mean_tolerance(), 0.02);
  EXPECT_EQ(spec::from_proto(s).refine_p95_tolerance, 0.1);
  EXPECT_EQ(spec::from_proto(pb::MapSpec()).refine_mean_tolerance, 0);
  EXPECT_EQ(back.hole_vertex, -1);
  jobs::MapRequest cut;
  cut.cut_hole = true;
  cut.hole_vertex = 0;  // vertex 0 is a vertex: has_hole_vertex carries it
  s.Clear();
  spec::to_proto(cut, &s);
  EXPECT_EQ(spec::from_proto(s).hole_vertex, 0);
  // The zero spec is the default request.
  const jobs::MapRequest zero = spec::from_proto(pb::MapSpec());
  EXPECT_EQ(zero.max_iterations, jobs::MapRequest().max_iterations);
  EXPECT_EQ(zero.domain, jobs::Domain::kDisk);
  EXPECT_EQ(zero.method, jobs::MapMethod::kConformal);
}

TEST(Spec, DistanceAndMatrixRequestsSurviveTheWire) {
  jobs::DistanceRequest d;
  d.shape.method = distance::Method::kOmtLinear;
  d.shape.cut_hole = true;
  d.shape.tolerance = 1e-5;
  d.shape.cost_tolerance = 0;  // off: negative on the wire
  d.shape.rings = 16;
  d.shape.angles = 64;
  d.a = {0, 7};
  d.b = {3, 1};
  pb::DistanceSpec s;
  spec::to_proto(d, &s);
  EXPECT_LT(s.wasserstein().cost_tolerance(), 0);
  const jobs::DistanceRequest back = spec::from_proto(s);
  EXPECT_EQ(back.shape.method, d.shape.method);
  EXPECT_TRUE(back.shape.cut_hole);
  EXPECT_EQ(back.shape.tolerance, 1e-5);
  EXPECT_EQ(back.shape.cost_tolerance, 0);
  EXPECT_EQ(back.shape.rings, 16);
  EXPECT_EQ(back.shape.angles, 64);
  EXPECT_EQ(back.a.center, 0);
  EXPECT_EQ(back.a.boundary, 7);
  EXPECT_EQ(back.b.center, 3);
  const jobs::ShapeRequest zero = spec::from_proto(pb::DistanceSpec()).shape;
  EXPECT_EQ(zero.tolerance, jobs::ShapeRequest().tolerance);
  EXPECT_EQ(zero.cost_tolerance, jobs::ShapeRequest().cost_tolerance);
  EXPECT_EQ(zero.rings, 64);

  jobs::MatrixRequest m;
  m.shape.domain = jobs::Domain::kSphere;
  m.markers = {{0, 1}, {2, 3}, {4, 5}};
  pb::MatrixSpec ms;
  spec::to_proto(m, &ms);
  for (const char* id : {"a", "b", "c"}) ms.add_meshes(id);
  const jobs::MatrixRequest mb = spec::from_proto(ms);
  EXPECT_EQ(mb.shape.domain, jobs::Domain::kSphere);
  ASSERT_EQ(mb.markers.size(), 3u);
  EXPECT_EQ(mb.markers[2].boundary, 5);
}

TEST(Spec, RegisterRequestsSurviveTheWire) {
  jobs::RegisterRequest r;
  r.domain = jobs::Domain::kSphere;
  r.method = jobs::MapMethod::kConformal;
  r.source_landmarks = {3, 8, 1};
  r.target_landmarks = {5, 2, 9};
  r.tolerance = 1e-7;
  r.max_iterations = 55;
  r.isometric = false;
  pb::RegisterSpec s;
  spec::to_proto(r, &s);
  const jobs::RegisterRequest back = spec::from_proto(s);
  EXPECT_EQ(back.domain, r.domain);
  EXPECT_EQ(back.method, r.method);
  EXPECT_EQ(back.source_landmarks, r.source_landmarks);
  EXPECT_EQ(back.target_landmarks, r.target_landmarks);
  EXPECT_EQ(back.tolerance, r.tolerance);
  EXPECT_EQ(back.max_iterations, r.max_iterations);
  EXPECT_FALSE(back.isometric);
  EXPECT_TRUE(s.harmonic_only());
  EXPECT_FALSE(back.isometric_sphere);
  r.isometric = true;
  r.isometric_sphere = true;
  s = pb::RegisterSpec();
  spec::to_proto(r, &s);
  const jobs::RegisterRequest refined = spec::from_proto(s);
  EXPECT_TRUE(refined.isometric);
  EXPECT_FALSE(s.harmonic_only());
  EXPECT_TRUE(refined.isometric_sphere);
  EXPECT_TRUE(refined.refines());
  // Both together contradict each other: refused, naming both fields.
  s.set_harmonic_only(true);
  EXPECT_ERROR(spec::from_proto(s), ErrorCode::kInvalidArgument,
               "{harmonic_only} keeps g without the isometric refinement and {isometric_sphere} asks for it");
  // An old client's spec: the OMT route, refined on the disk and on the sphere.
  const jobs::RegisterRequest old = spec::from_proto(pb::RegisterSpec());
  EXPECT_TRUE(old.isometric);
  EXPECT_FALSE(old.isometric_sphere);
  EXPECT_EQ(old.method, jobs::MapMethod::kAreaPreserving);
  EXPECT_TRUE(old.refines());
}

TEST(Spec, BadSpecsNameTheirField) {
  pb::MapSpec s;
  s.set_t(0.5);
  EXPECT_ERROR(spec::from_proto(s), ErrorCode::kInvalidArgument, "{t} and {weights} apply to the area-preserving method");
  EXPECT_EQ(name_options("{t} and {weights}", OptionStyle::kField), "t and weights");
  // Field names may hold digits after their first letter; braces around anything else stay.
  EXPECT_EQ(name_options("{refine_p95_tolerance}, {3}, {_x}", OptionStyle::kFlag), "--refine-p95-tolerance, {3}, {_x}");
  s.Clear();
  s.set_method(pb::AREA_PRESERVING);
  s.set_refine_p95_tolerance(-0.1);
  EXPECT_ERROR(spec::from_proto(s), ErrorCode::kInvalidArgument, "{refine_p95_tolerance} must be a positive number");
  s.set_refine_p95_tolerance(0.1);
  s.set_no_refine(true);
  EXPECT_ERROR(spec::from_proto(s), ErrorCode::kInvalidArgument,
               "{refine_mean_tolerance} and {refine_p95_tolerance} stop the area-preserving refinement");
  s.Clear();
  s.set_has_hole_vertex(true);
  s.set_hole_vertex(-3);
  EXPECT_ERROR(spec::from_proto(s), ErrorCode::kInvalidArgument, "{hole_vertex} must be a vertex number");
  pb::DistanceSpec d;
  d.mutable_markers_a()->set_center(2);
  d.mutable_markers_a()->set_boundary(4);
  EXPECT_ERROR(spec::from_proto(d), ErrorCode::kInvalidArgument, "give {markers} for both meshes or neither");
  d.mutable_wasserstein()->set_cost_tolerance(3);
  EXPECT_ERROR(spec::from_proto(d), ErrorCode::kInvalidArgument, "{cost_tolerance} must be at most 1");
  pb::MatrixSpec m;
  m.add_meshes("a");
  EXPECT_ERROR(spec::from_proto(m), ErrorCode::kInvalidArgument, "at least two meshes");
}

}  // namespace
}  // namespace brenier::test

// The typed job requests: their validation (the one place every front end's checks live)
// and the markers and weights files every front end reads with one parser.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <limits>

#include "expect_error.hpp"
#include "jobs/requests.hpp"

using namespace brenier;
using namespace brenier::jobs;
using brenier::ErrorCode;

namespace {

std::string write_temp(const std::string& name, const std::string& text) {
  const std::string path = (std::filesystem::temp_directory_path() / ("brenier-requests-" + name)).string();
  std::ofstream(path) << text;
  return path;
}

TEST(Requests, NamesRoundTrip) {
  for (Domain d : {Domain::kDisk, Domain::kSphere}) EXPECT_EQ(find_domain(domain_name(d)), d);
  for (MapMethod m : {MapMethod::kConformal, MapMethod::kAreaPreserving}) EXPECT_EQ(find_map_method(map_method_name(m)), m);
  for (distance::Method m : {distance::Method::kWasserstein, distance::Method::kOmtLinear})
    EXPECT_EQ(distance::find_method(distance::method_name(m)), m);
  EXPECT_FALSE(find_domain("torus"));
  EXPECT_FALSE(find_map_method("authalic"));
  EXPECT_ERROR(distance::parse_method("l2"), ErrorCode::kInvalidArgument, "unknown distance method 'l2'");
}

TEST(Requests, MapRequestsThatCannotRunOnAnyMeshAreRefusedNamingTheField) {
  MapRequest ok;
  EXPECT_NO_THROW(ok.validate());
  auto with = [&](auto change) {
    MapRequest r;
    change(r);
    return r;
  };
  const auto bad = ErrorCode::kInvalidArgument;
  EXPECT_ERROR(with([](MapRequest& r) { r.markers = {1, 2, 3}; }).validate(), bad, "disk {markers} are two vertices");
  EXPECT_ERROR(with([](MapRequest& r) { r.domain = Domain::kSphere; r.markers = {1, 2}; }).validate(), bad,
               "sphere {markers} are three vertices");
  EXPECT_ERROR(with([](MapRequest& r) { r.markers = {1, -4}; }).validate(), bad, "-4 is not");
  EXPECT_ERROR(with([](MapRequest& r) { r.domain = Domain::kSphere; r.cut_hole = true; }).validate(), bad,
               "{cut_hole} applies to the disk domain");
  EXPECT_ERROR(with([](MapRequest& r) { r.hole_vertex = 3; }).validate(), bad, "{hole_vertex} goes with {cut_hole}");
  EXPECT_ERROR(with([](MapRequest& r) { r.tolerance = std::numeric_limits<double>::quiet_NaN(); }).validate(), bad, "{tolerance}");
  EXPECT_ERROR(with([](MapRequest& r) { r.max_iterations = 0; }).validate(), bad, "{max_iterations} must lie in [1, 100000]");
  EXPECT_ERROR(with([](MapRequest& r) { r.max_iterations = 100001; }).validate(), bad, "{max_iterations}");
  EXPECT_ERROR(with([](MapRequest& r) { r.method = MapMethod::kAreaPreserving; r.t = 1.5; }).validate(), bad,
               "{t} must lie in [0, 1]");
  EXPECT_ERROR(with([](MapRequest& r) { r.t = 0.5; }).validate(), bad, "apply to the area-preserving method");
  EXPECT_ERROR(with([](MapRequest& r) { r.method = MapMethod::kAreaPreserving; r.weights = {1, 0, 2}; }).validate(), bad,
               "weight 1 is");
  // And what is fine: sphere markers, a hole vertex with the cut, weights with the method.
  EXPECT_NO_THROW(with([](MapRequest& r) { r.domain = Domain::kSphere; r.markers = {0, 1, 2}; }).validate());
  EXPECT_NO_THROW(with([](MapRequest& r) { r.cut_hole = true; r.hole_vertex = 0; }).validate());
  EXPECT_NO_THROW(with([](MapRequest& r) { r.method = MapMethod::kAreaPreserving; r.weights = {1, 2}; r.t = 0.3; }).validate());
}

TEST(Requests, ShapeDistanceAndMatrixRequestsAreChecked) {
  const auto bad = ErrorCode::kInvalidArgument;
  ShapeRequest s;
  EXPECT_NO_THROW(s.validate());
  s.domain = Domain::kSphere;
  s.refine_rotation = true;
  EXPECT_ERROR(s.validate(), bad, "{refine_rotation} applies to the disk domain");
  s = {};
  s.tolerance = 0;
  EXPECT_ERROR(s.validate(), bad, "{tolerance} must be a positive number");
  s = {};
  s.cost_tolerance = 2;
  EXPECT_ERROR(s.validate(), bad, "{cost_tolerance} must lie in [0, 1]");
  s = {};
  s.rings = 0;
  EXPECT_ERROR(s.validate(), bad, "{rings}");
  s = {};
  s.angles = 1 << 20;
  EXPECT_ERROR(s.validate(), bad, "{angles}");
  s = {};
  s.rings = 4096;
  s.angles = 65536;  // each within its range, together 2^28 samples per shape
  EXPECT_ERROR(s.validate(), bad, "{rings} x {angles} = 268435456 quadrature samples; at most 1048576");

  DistanceRequest d;
  d.a = {0, 5};
  EXPECT_ERROR(d.validate(), bad, "give {markers} for both meshes or neither");
  d.b = {3, -1};
  EXPECT_ERROR(d.validate(), bad, "the second mesh's {markers}");
  d.b = {3, 9};
  EXPECT_NO_THROW(d.validate());

  MatrixRequest m;
  EXPECT_ERROR(m.validate(1), bad, "at least two meshes");
  m.markers = {{0, 1}};
  EXPECT_ERROR(m.validate(2), bad, "1 {markers} for 2 meshes");
  m.markers = {{0, 1}, {}};
  EXPECT_ERROR(m.validate(2), bad, "mesh 1 has no {markers}");
  m.markers = {{0, 1}, {2, 3}};
  EXPECT_NO_THROW(m.validate(2));
}

TEST(Requests, OneMarkersFileParserForEveryFrontEnd) {
  const std::string good = write_temp("good.csv", "# mesh,center,boundary\r\nshapes/a.off,3,17\r\n\nb,0, 4\n");
  const MarkersFile f = read_markers_file(good);
  ASSERT_EQ(f.entries.size(), 2u);
  EXPECT_EQ(f.of("shapes/a.off").center, 3);
  EXPECT_EQ(f.of("shapes/a.off").boundary, 17);
  EXPECT_EQ(f.of("elsewhere/b.ply").boundary, 4);  // by the stem
  EXPECT_ERROR(f.of("c.off"), ErrorCode::kInvalidArgument, "has no markers for c.off");
  // Lines that the two readers of old took differently: trailing text after a number, a
  // fourth field, a missing field, negative vertices.
  for (const char* line : {"a.off,12abc,3", "a.off,1,2,3", "a.off,1", "a.off,-1,2", ",1,2", "a.off,1,"}) {
    const std::string path = write_temp("bad.csv", std::string("ok,1,2\n") + line + "\n");
    EXPECT_ERROR(read_markers_file(path), ErrorCode::kInvalidArgument, ":2: expected mesh,center_vertex,boundary_vertex")
        << line;
  }
  EXPECT_ERROR(read_markers_file("/nonexistent/markers.csv"), ErrorCode::kInvalidArgument,
               "cannot read the markers file /nonexistent/markers.csv");
}

TEST(Requests, WeightsFiles) {
  EXPECT_EQ(read_weights_file(write_temp("w.txt", "1 2.5\n3e-1\n")), (std::vector<double>{1, 2.5, 0.3}));
  EXPECT_ERROR(read_weights_file(write_temp("w0.txt", "1 0 2\n")), ErrorCode::kInvalidArgument, "weight 1 is '0'");
  EXPECT_ERROR(read_weights_file(write_temp("wx.txt", "1 2x\n")), ErrorCode::kInvalidArgument, "weight 1 is '2x'");
  EXPECT_ERROR(read_weights_file(write_temp("we.txt", "\n")), ErrorCode::kInvalidArgument, "no weights");
}

}  // namespace

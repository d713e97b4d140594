// Validation: each defect of a mesh gives its own error (or warning) naming the element.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "common/error.hpp"

#include "mesh/io.hpp"
#include "mesh/shapes.hpp"
#include "mesh/validate.hpp"

using namespace brenier::mesh;

namespace {

const std::string kFixtures = BRENIER_TEST_FIXTURES;

PolygonSoup soup_of(const TriMesh& m) {
  PolygonSoup s;
  for (int i = 0; i < m.V.rows(); ++i) s.positions.push_back(m.V.row(i).transpose());
  for (int f = 0; f < m.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) s.indices.push_back(m.F(f, k));
    s.face_offsets.push_back(static_cast<int64_t>(s.indices.size()));
  }
  return s;
}

void add_face(PolygonSoup& s, std::initializer_list<int64_t> idx) {
  for (auto i : idx) s.indices.push_back(i);
  s.face_offsets.push_back(static_cast<int64_t>(s.indices.size()));
}

const Problem* find(const Report& r, const std::string& code) {
  for (const auto& p : r.problems)
    if (p.code == code) return &p;
  return nullptr;
}

// The fixture gives exactly this first error, and its message names `element`.
void expect_fixture_error(const std::string& file, const std::string& code,
                          const std::string& element) {
  SCOPED_TRACE(file);
  CleanMesh cm = load_mesh(kFixtures + "/malformed/" + file);
  const Problem* p = cm.report.first_error();
  ASSERT_NE(p, nullptr) << "no error reported";
  EXPECT_EQ(p->code, code) << p->message;
  EXPECT_NE(p->message.find(element), std::string::npos) << p->message;
}

}  // namespace

TEST(Validate, CleanMeshesHaveNoProblems) {
  for (const TriMesh& m : {make_icosphere(2), make_grid(5), make_torus(10, 7), make_disk(4),
                           make_hemisphere(5), make_cylinder(12, 6, 1.0, 3.0, true)}) {
    Report r = validate(m);
    EXPECT_TRUE(r.problems.empty()) << r.problems.front().message;
  }
}

TEST(Validate, EachMalformedFixtureGivesItsOwnError) {
  expect_fixture_error("empty.off", "empty_mesh", "0 vertices");
  expect_fixture_error("point_cloud.ply", "empty_mesh", "0 faces");
  expect_fixture_error("nan.off", "non_finite_coordinate", "vertex 1");
  expect_fixture_error("index_out_of_range.off", "index_out_of_range", "face 1 refers to vertex 7");
  expect_fixture_error("zero_area.off", "zero_area_face", "face 2");
  expect_fixture_error("nonmanifold_edge.off", "non_manifold_edge", "edge (0, 1)");
  expect_fixture_error("nonmanifold_vertex.off", "non_manifold_vertex", "vertex 0");
  expect_fixture_error("inconsistent_orientation.off", "inconsistent_orientation", "faces 0 and 2");
  expect_fixture_error("mobius.off", "non_orientable", "non-orientable");
  expect_fixture_error("two_components.off", "several_components", "2 connected components");
  expect_fixture_error("duplicate_face.off", "duplicate_face", "faces 0 and 4");
  expect_fixture_error("face_too_small.off", "face_too_small", "face 4 has 2 vertices");
  expect_fixture_error("degenerate_face.off", "degenerate_face", "face 4 uses vertex 1");
}

TEST(Validate, InfiniteCoordinateIsAnError) {
  TriMesh m = make_grid(3);
  m.V(4, 1) = std::numeric_limits<double>::infinity();
  Report r = validate(m);
  ASSERT_NE(r.first_error(), nullptr);
  EXPECT_EQ(r.first_error()->code, "non_finite_coordinate");
  EXPECT_NE(r.first_error()->message.find("vertex 4"), std::string::npos);
}

TEST(Validate, DuplicateVerticesAreReportedAndMergedWhenAsked) {
  // A grid whose middle column is split into two copies: a crack along it.
  TriMesh m = make_grid(3);
  PolygonSoup s = soup_of(m);
  s.positions.push_back(m.V.row(4).transpose());  // vertex 9 duplicates vertex 4
  for (int64_t& i : s.indices)
    if (i == 4 && (&i - s.indices.data()) >= 12) i = 9;  // faces 4.. use the copy
  CleanMesh warned = clean(s);
  const Problem* p = find(warned.report, "duplicate_vertices");
  ASSERT_NE(p, nullptr);
  EXPECT_NE(p->message.find("vertex 9 has the same coordinates as vertex 4"), std::string::npos)
      << p->message;
  CleanMesh merged = clean(s, {.merge_duplicates = true});
  ASSERT_TRUE(merged.valid());
  EXPECT_NE(find(merged.report, "duplicate_vertices_merged"), nullptr);
  EXPECT_EQ(merged.mesh.num_vertices(), 9);
}

TEST(Validate, UnreferencedVerticesAreDroppedAndOriginsKept) {
  TriMesh m = make_grid(3);
  PolygonSoup s = soup_of(m);
  s.positions.insert(s.positions.begin(), Eigen::Vector3d(7, 7, 7));  // vertex 0 unused
  for (int64_t& i : s.indices) ++i;
  CleanMesh cm = clean(s);
  ASSERT_TRUE(cm.valid());
  const Problem* p = find(cm.report, "unreferenced_vertices");
  ASSERT_NE(p, nullptr);
  EXPECT_NE(p->message.find("vertex 0"), std::string::npos);
  EXPECT_EQ(cm.mesh.num_vertices(), 9);
  EXPECT_EQ(cm.vertex_origin.front(), 1);
  EXPECT_EQ(cm.mesh.V, m.V);
}

TEST(Validate, KeepLargestComponent) {
  CleanMesh cm = load_mesh(kFixtures + "/malformed/two_components.off", {.keep_largest_component = true});
  ASSERT_TRUE(cm.valid()) << cm.report.first_error()->message;
  EXPECT_EQ(cm.mesh.num_faces(), 4);
  EXPECT_NE(find(cm.report, "components_dropped"), nullptr);

  TriMesh big = make_icosphere(1), small = make_icosphere(0);
  PolygonSoup s = soup_of(small);
  int off = static_cast<int>(s.positions.size());
  for (int i = 0; i < big.V.rows(); ++i) s.positions.push_back(big.V.row(i).transpose() * 3.0);
  for (int f = 0; f < big.F.rows(); ++f) add_face(s, {big.F(f, 0) + off, big.F(f, 1) + off, big.F(f, 2) + off});
  CleanMesh kept = clean(s, {.keep_largest_component = true});
  ASSERT_TRUE(kept.valid());
  EXPECT_EQ(kept.mesh.num_faces(), big.num_faces());
  EXPECT_EQ(kept.vertex_origin.front(), off);
}

TEST(Validate, FixOrientationRestoresAConsistentWinding) {
  TriMesh m = make_icosphere(2);
  PolygonSoup s = soup_of(m);
  // Flip every third face.
  for (int64_t f = 0; f < s.num_faces(); f += 3)
    std::swap(s.indices[s.face_offsets[f] + 1], s.indices[s.face_offsets[f] + 2]);
  EXPECT_EQ(clean(s).report.first_error()->code, "inconsistent_orientation");
  CleanMesh fixed = clean(s, {.fix_orientation = true});
  ASSERT_TRUE(fixed.valid());
  // A closed surface ends up facing outward: the original orientation.
  EXPECT_EQ(fixed.mesh.F, m.F);
  EXPECT_TRUE(validate(fixed.mesh).problems.empty());
  // Even when most faces were inward.
  PolygonSoup inward = soup_of(m);
  for (int64_t f = 0; f < inward.num_faces(); ++f)
    if (f % 3 != 0) std::swap(inward.indices[inward.face_offsets[f] + 1], inward.indices[inward.face_offsets[f] + 2]);
  EXPECT_EQ(clean(inward, {.fix_orientation = true}).mesh.F, m.F);
}

TEST(Validate, FixOrientationRefusesAMoebiusBand) {
  CleanMesh cm = load_mesh(kFixtures + "/malformed/mobius.off", {.fix_orientation = true});
  ASSERT_NE(cm.report.first_error(), nullptr);
  EXPECT_EQ(cm.report.first_error()->code, "non_orientable");
}

TEST(Validate, NearDegenerateButNonZeroFacesAreAccepted) {
  // A 0.01 degree sliver (like mannequin-devil's 0.026 degree corners) is valid.
  TriMesh m;
  m.V.resize(3, 3);
  m.V << 0, 0, 0, 1, 0, 0, 0.5, 1e-4, 0;
  m.F.resize(1, 3);
  m.F << 0, 1, 2;
  EXPECT_TRUE(validate(m).problems.empty());
  m.V(2, 1) = 1e-14;
  EXPECT_EQ(validate(m).first_error()->code, "zero_area_face");
}

TEST(Validate, RequireValidThrowsTheFirstError) {
  CleanMesh cm = load_mesh(kFixtures + "/malformed/nan.off");
  try {
    require_valid(cm, "nan.off");
    FAIL();
  } catch (const brenier::Error& e) {
    EXPECT_EQ(e.code(), brenier::ErrorCode::kInvalidArgument);
    EXPECT_EQ(std::string(e.what()).rfind("nan.off: vertex 1", 0), 0u) << e.what();
  }
}

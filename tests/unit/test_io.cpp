// Readers and writers: round trips, every format's variants, and corrupt input.
#include <gtest/gtest.h>

#include "expect_error.hpp"

#include <chrono>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>

#include "common/error.hpp"
#include "mesh/io.hpp"
#include "mesh/shapes.hpp"
#include "mesh/validate.hpp"

using namespace brenier;
using namespace brenier::mesh;

namespace {

const std::string kFixtures = BRENIER_TEST_FIXTURES;

TriMesh soup_to_mesh(const PolygonSoup& s) {
  CleanMesh cm = clean(s);
  EXPECT_TRUE(cm.valid()) << (cm.report.first_error() ? cm.report.first_error()->message : "");
  return cm.mesh;
}

// A mesh whose coordinates need all 17 digits.
TriMesh awkward_mesh() {
  TriMesh m = make_icosphere(1);
  m.V *= 1.0 / 3.0;
  m.V.col(0).array() += 1e-7;
  m.V(3, 2) = 0.12345678901234567;
  return m;
}

std::string error_of(std::string_view bytes, Format f) {
  try {
    (void)read_soup(bytes, f);
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kInvalidArgument) << e.what();
    return e.what();
  }
  return "";
}

}  // namespace

class RoundTrip : public ::testing::TestWithParam<Format> {};

TEST_P(RoundTrip, WriteThenReadGivesTheSameMesh) {
  TriMesh m = awkward_mesh();
  std::string bytes = write_mesh_string(m, GetParam());
  PolygonSoup s = read_soup(bytes, GetParam());
  ASSERT_EQ(static_cast<int>(s.positions.size()), m.num_vertices());
  ASSERT_EQ(s.num_faces(), m.num_faces());
  TriMesh back = soup_to_mesh(s);
  EXPECT_EQ(back.F, m.F) << "faces must keep their order and winding";
  if (GetParam() == Format::kFreeSurfer) {
    // FreeSurfer stores float32 coordinates.
    EXPECT_LT((back.V - m.V).cwiseAbs().maxCoeff(), 1e-7);
  } else {
    EXPECT_EQ(back.V, m.V) << "ascii is written with 17 digits and PLY as doubles: exact";
  }
}

INSTANTIATE_TEST_SUITE_P(Formats, RoundTrip,
                         ::testing::Values(Format::kObj, Format::kOff, Format::kPly,
                                           Format::kFreeSurfer),
                         [](const auto& info) { return std::string(format_name(info.param)); });

TEST(Io, ObjWritesVtPerVertexAndSlashedFaces) {
  TriMesh m = make_grid(3);
  UV uv = m.V.leftCols(2);
  std::string s = write_mesh_string(m, Format::kObj, &uv);
  EXPECT_NE(s.find("vt 0.5 0\n"), std::string::npos);
  EXPECT_NE(s.find("f 1/1 2/2 5/5\n"), std::string::npos) << s.substr(0, 400);
  // And it reads back with the same faces.
  EXPECT_EQ(soup_to_mesh(read_soup(s, Format::kObj)).F, m.F);
  // And its vt read back exactly (what `render` draws a disk map from).
  const std::optional<UV> back = read_obj_uv(s, m.V.rows());
  ASSERT_TRUE(back.has_value());
  EXPECT_EQ(*back, uv);
  EXPECT_FALSE(read_obj_uv(write_mesh_string(m, Format::kObj), m.V.rows()).has_value());
  EXPECT_ERROR(read_obj_uv(s, m.V.rows() + 1), ErrorCode::kInvalidArgument, "not one per vertex");
  EXPECT_ERROR(read_obj_uv("v 0 0 0\nvt 0 0\nf 1/2 1/1 1/1\n", 1), ErrorCode::kInvalidArgument, "corner 1/2");
  EXPECT_ERROR(read_obj_uv("vt 0 nan\n", 1), ErrorCode::kInvalidArgument, "two finite numbers");
}

TEST(Io, FileRoundTripThroughDisk) {
  TriMesh m = make_torus(8, 6);
  std::string path = ::testing::TempDir() + "/brenier_torus.ply";
  write_mesh_file(path, m);
  CleanMesh back = load_mesh(path);
  ASSERT_TRUE(back.valid());
  EXPECT_EQ(back.mesh.V, m.V);
  EXPECT_EQ(back.mesh.F, m.F);
}

TEST(Io, EveryValidFixtureIsTheSameTetrahedron) {
  for (std::string name : {"tetra.obj", "tetra_ascii.stl", "tetra_binary.stl", "tetra_ascii.ply",
                           "tetra_be.ply", "lh.tetra"}) {
    SCOPED_TRACE(name);
    CleanMesh cm = load_mesh(kFixtures + "/valid/" + name, {.merge_duplicates = true});
    ASSERT_TRUE(cm.valid()) << cm.report.first_error()->message;
    EXPECT_EQ(cm.mesh.num_vertices(), 4);
    EXPECT_EQ(cm.mesh.num_faces(), 4);
    EXPECT_DOUBLE_EQ(cm.mesh.V.colwise().sum().sum(), 3.0);
  }
}

TEST(Io, ObjNegativeAndSlashedIndices) {
  PolygonSoup s = read_soup_file(kFixtures + "/valid/tetra.obj");
  ASSERT_EQ(s.num_faces(), 4);
  // "f -4 -1 -2" with 4 vertices is 0 3 2.
  EXPECT_EQ(s.indices[6], 0);
  EXPECT_EQ(s.indices[7], 3);
  EXPECT_EQ(s.indices[8], 2);
}

TEST(Io, OffVariantsCommentsColoursAndDimension) {
  std::string off =
      "# comment before the keyword\nCOFF\n# counts\n3 1 0\n0 0 0 1 0 0 1\n1 0 0 0 1 0 1 # c\n"
      "\n0 1 0 0 0 1 1\n3 0 1 2 0.5 0.5 0.5\n";
  PolygonSoup s = read_soup(off, Format::kOff);
  ASSERT_EQ(s.positions.size(), 3u);
  EXPECT_EQ(s.positions[1], Eigen::Vector3d(1, 0, 0));
  ASSERT_EQ(s.num_faces(), 1);
  EXPECT_EQ(s.indices, (std::vector<int64_t>{0, 1, 2}));
  PolygonSoup n = read_soup("nOFF 3\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", Format::kOff);
  EXPECT_EQ(n.num_faces(), 1);
  PolygonSoup same_line = read_soup("OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", Format::kOff);
  EXPECT_EQ(same_line.positions.size(), 3u);
}

TEST(Io, QuadsAreTriangulatedWithAWarning) {
  CleanMesh cm = load_mesh(kFixtures + "/valid/quad_grid.off");
  ASSERT_TRUE(cm.valid());
  EXPECT_EQ(cm.mesh.num_faces(), 8);
  ASSERT_FALSE(cm.report.problems.empty());
  EXPECT_EQ(cm.report.problems[0].code, "triangulated");
  EXPECT_EQ(cm.report.problems[0].count, 4);
  EXPECT_EQ(cm.face_origin[7], 3) << "each triangle remembers its input polygon";
}

TEST(Io, DetectsFormatsFromMagicExtensionAndContent) {
  EXPECT_EQ(detect_format("lh.pial", "\xFF\xFF\xFE" "created"), Format::kFreeSurfer);
  EXPECT_EQ(detect_format("a.OBJ", "v 1 2 3"), Format::kObj);
  EXPECT_EQ(detect_format("noext", "ply\nformat"), Format::kPly);
  EXPECT_EQ(detect_format("noext", "OFF\n1 2 3"), Format::kOff);
  EXPECT_EQ(detect_format("noext", "solid x\n"), Format::kStl);
  EXPECT_ERROR(detect_format("noext", "\x01\x02"), ErrorCode::kInvalidArgument, "cannot tell the mesh format of 'noext': use a .obj, .off, .ply or .stl");
}

TEST(Io, TruncatedAndCorruptFilesNameTheProblem) {
  EXPECT_NE(error_of("OFF\n3 1 0\n0 0 0\n1 0 0\n", Format::kOff).find("truncated"), std::string::npos);
  EXPECT_NE(error_of("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1\n", Format::kOff).find("lists fewer"),
            std::string::npos);
  EXPECT_NE(error_of("OFF\nx y z\n", Format::kOff).find("counts"), std::string::npos);
  EXPECT_NE(error_of("v 0 0\n", Format::kObj).find("three coordinates"), std::string::npos);
  EXPECT_NE(error_of("v 0 0 0\nf 1 a 2\n", Format::kObj).find("not a vertex index"),
            std::string::npos);
  EXPECT_NE(error_of("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", Format::kPly)
                .find("end_header"),
            std::string::npos);
  EXPECT_NE(error_of("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n0 0 0\n1 1\n",
                     Format::kPly)
                .find("truncated"),
            std::string::npos);
  EXPECT_NE(error_of(std::string("\xFF\xFF\xFE" "no newline", 13), Format::kFreeSurfer).find("corrupt"),
            std::string::npos);
  EXPECT_NE(error_of(std::string(100, 'x'), Format::kStl).find("truncated"), std::string::npos);
  EXPECT_NE(error_of("", Format::kObj).find("empty"), std::string::npos);
}

TEST(Io, AbsurdHeaderCountsAreRefusedBeforeAllocating) {
  // 2^31-1 vertices declared in a few bytes: must be refused at once, not looped over or
  // allocated. (A wrong implementation would take seconds or run out of memory.)
  auto t0 = std::chrono::steady_clock::now();
  EXPECT_NE(error_of("OFF\n40000000 40000000 0\n0 0 0\n", Format::kOff).find("declares"),
            std::string::npos);
  std::string ply =
      "ply\nformat binary_little_endian 1.0\nelement vertex 40000000\nproperty double x\n"
      "property double y\nproperty double z\nend_header\n" + std::string(64, '\0');
  EXPECT_NE(error_of(ply, Format::kPly).find("declares"), std::string::npos);
  std::string fs("\xFF\xFF\xFE" "c\n\n", 6);
  fs += std::string("\x02\x00\x00\x00\x02\x00\x00\x00", 8) + std::string(32, '\0');
  EXPECT_NE(error_of(fs, Format::kFreeSurfer).find("truncated"), std::string::npos);
  std::string stl(84, '\0');
  stl[83] = 0x10;  // 2^28 triangles
  EXPECT_NE(error_of(stl, Format::kStl).find("declares"), std::string::npos);
  auto secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_LT(secs, 5.0);
}

// Regression (issue 20): the 88-byte upload that killed brenierd. Its keyword "BINARYOFF"
// holds "BINARY"; the reader used to find the counts again by searching for that word, land
// inside the keyword and read four bytes of text as a vertex count (gigabytes allocated,
// reads far past the buffer). Now the keyword is refused, and the reader never re-parses.
TEST(Io, BinaryInsideTheOffKeywordIsRefused) {
  std::string bytes;
  {
    std::ifstream in(kFixtures + "/malformed/binary_in_keyword.off", std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_EQ(bytes.size(), 88u);
  EXPECT_NE(error_of(bytes, Format::kOff).find("does not start with an OFF keyword"), std::string::npos);
  EXPECT_NE(error_of("STCNnOFFX\n3 1 0\n", Format::kOff).find("OFF keyword"), std::string::npos);
  EXPECT_NE(error_of("XOFF\n3 1 0\n", Format::kOff).find("OFF keyword"), std::string::npos);
}

namespace {
std::string be32s(std::initializer_list<int32_t> v) {
  std::string out;
  for (int32_t x : v) {
    uint32_t u = static_cast<uint32_t>(x);
    for (int k = 3; k >= 0; --k) out += static_cast<char>((u >> (8 * k)) & 0xFF);
  }
  return out;
}
std::string be_floats(std::initializer_list<float> v) {
  std::string out;
  for (float x : v) {
    uint32_t u;
    std::memcpy(&u, &x, 4);
    out += be32s({static_cast<int32_t>(u)});
  }
  return out;
}
}  // namespace

// The counts are read where the header guard checked them: a comment naming BINARY before
// the keyword, or junk after the BINARY token, must not move them.
TEST(Io, BinaryOffCountsAreReadWhereTheGuardCheckedThem) {
  const std::string body = be32s({3, 1, 0}) + be_floats({0, 0, 0, 1, 0, 0, 0, 1, 0}) +
                           be32s({3, 0, 1, 2, 0});
  for (std::string head : {"OFF BINARY\n", "# BINARY comment\nOFF BINARY\n", "COFF\nBINARY junk\n"}) {
    PolygonSoup soup = read_soup(head + body, Format::kOff);
    ASSERT_EQ(soup.positions.size(), 3u) << head;
    ASSERT_EQ(soup.num_faces(), 1) << head;
    EXPECT_EQ(soup.positions[1], Eigen::Vector3d(1, 0, 0)) << head;
  }
  // Counts that do not fit the bytes are refused, whatever precedes them.
  EXPECT_NE(error_of("# BINARY\nOFF BINARY\n" + be32s({1000, 1, 0}) + body.substr(12), Format::kOff)
                .find("declares"),
            std::string::npos);
  // And the ascii body starts after the counts' line, with line numbers counted from the file's start.
  EXPECT_NE(error_of("OFF\n# c\n3 1 0 # counts\n0 0 0\n1 0 0\nx y z\n3 0 1 2\n", Format::kOff).find("OFF line 6"),
            std::string::npos);
}

TEST(Io, LimitsAreEnforced) {
  ReadLimits small{.max_bytes = 1 << 20, .max_vertices = 10, .max_faces = 10};
  std::string s = write_mesh_string(make_icosphere(1), Format::kOff);
  try {
    (void)read_soup(s, Format::kOff, small);
    FAIL() << "42 vertices over a limit of 10 must be refused";
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kResourceExhausted);
  }
}

TEST(Io, MissingFileIsNotFound) {
  try {
    (void)read_soup_file("/nonexistent/brenier.off");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.code(), ErrorCode::kNotFound);
    EXPECT_NE(std::string(e.what()).find("/nonexistent/brenier.off"), std::string::npos);
  }
}

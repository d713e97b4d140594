// Every real mesh of data/meshes (scripts/fetch-data.sh) is read without a crash; for every
// valid one our topology agrees with OpenMesh's half-edge structure (an independent
// implementation), and the classes of well-known models are checked by name.
#include <gtest/gtest.h>

#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <filesystem>
#include <map>
#include <queue>

#include "common/error.hpp"
#include "mesh/geometry.hpp"
#include "mesh/io.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"

using namespace brenier;
using namespace brenier::mesh;
namespace fs = std::filesystem;

namespace {

const fs::path kData = BRENIER_TEST_DATA_DIR;

std::vector<fs::path> data_files() {
  std::vector<fs::path> out;
  if (!fs::is_directory(kData)) return out;
  for (const auto& e : fs::directory_iterator(kData))
    if (e.is_regular_file() && e.path().filename().string()[0] != '.') out.push_back(e.path());
  std::sort(out.begin(), out.end());
  return out;
}

struct Reference {
  int euler = 0, boundary_loops = 0, components = 0;
};

// Euler characteristic, boundary loops and components from OpenMesh's half-edge mesh.
Reference openmesh_reference(const TriMesh& m) {
  using OM = OpenMesh::TriMesh_ArrayKernelT<>;
  OM om;
  std::vector<OM::VertexHandle> vh;
  for (int i = 0; i < m.V.rows(); ++i) vh.push_back(om.add_vertex(OM::Point(m.V(i, 0), m.V(i, 1), m.V(i, 2))));
  for (int f = 0; f < m.F.rows(); ++f) {
    auto fh = om.add_face(vh[m.F(f, 0)], vh[m.F(f, 1)], vh[m.F(f, 2)]);
    EXPECT_TRUE(fh.is_valid()) << "OpenMesh refused face " << f;
  }
  Reference r;
  r.euler = static_cast<int>(om.n_vertices()) - static_cast<int>(om.n_edges()) + static_cast<int>(om.n_faces());
  std::vector<char> seen(om.n_halfedges(), 0);
  for (auto h : om.halfedges()) {
    if (!om.is_boundary(h) || seen[h.idx()]) continue;
    ++r.boundary_loops;
    auto g = h;
    do {
      seen[g.idx()] = 1;
      g = om.next_halfedge_handle(g);
    } while (g != h);
  }
  std::vector<char> vis(om.n_vertices(), 0);
  for (auto v : om.vertices()) {
    if (vis[v.idx()]) continue;
    ++r.components;
    std::queue<OM::VertexHandle> q;
    q.push(v);
    vis[v.idx()] = 1;
    while (!q.empty()) {
      auto a = q.front();
      q.pop();
      for (auto b : om.vv_range(a))
        if (!vis[b.idx()]) {
          vis[b.idx()] = 1;
          q.push(b);
        }
    }
  }
  return r;
}

}  // namespace

TEST(RealMeshes, DataIsPresent) {
  ASSERT_TRUE(fs::is_directory(kData)) << kData << " is missing: run scripts/fetch-data.sh";
  EXPECT_GE(data_files().size(), 100u);
}

TEST(RealMeshes, EveryFileReadsWithoutCrashAndValidOnesMatchOpenMesh) {
  int valid = 0, checked_against_openmesh = 0;
  for (const auto& path : data_files()) {
    SCOPED_TRACE(path.filename().string());
    CleanMesh cm;
    try {
      cm = load_mesh(path.string());
    } catch (const Error& e) {
      // A read error is fine (b9.ply-like oddities), but it must be an input error.
      EXPECT_TRUE(e.code() == ErrorCode::kInvalidArgument) << e.what();
      continue;
    }
    if (!cm.valid()) continue;
    ++valid;
    Topology t = compute_topology(cm.mesh);
    EXPECT_TRUE(t.manifold);
    EXPECT_EQ(t.components, 1);
    Reference ref = openmesh_reference(cm.mesh);
    EXPECT_EQ(t.euler, ref.euler);
    EXPECT_EQ(t.boundary_loops, ref.boundary_loops);
    EXPECT_EQ(t.components, ref.components);
    int genus = (2 - ref.euler - ref.boundary_loops) / 2;
    EXPECT_EQ(t.genus, genus);
    MeshClass expect = genus == 0 && ref.boundary_loops == 0   ? MeshClass::kSphere
                       : genus == 0 && ref.boundary_loops == 1 ? MeshClass::kDisk
                                                               : MeshClass::kOther;
    EXPECT_EQ(t.mesh_class, expect);
    EXPECT_GT(total_area(cm.mesh), 0.0);
    ++checked_against_openmesh;
  }
  EXPECT_GE(valid, 100);
  EXPECT_EQ(valid, checked_against_openmesh);
}

TEST(RealMeshes, KnownModelsHaveTheirKnownTopology) {
  struct Known {
    const char* file;
    MeshClass cls;
    int genus, loops, vertices;
  };
  // Facts about these models (a scanned face with an open neck, closed animals, tori).
  const Known known[] = {
      {"lion-head.off", MeshClass::kDisk, 0, 1, 8356},
      {"mannequin-devil.off", MeshClass::kDisk, 0, 1, 12977},
      {"nefertiti.off", MeshClass::kDisk, 0, 1, 299},
      {"three_peaks.off", MeshClass::kDisk, 0, 1, 1907},
      {"armadillo.off", MeshClass::kSphere, 0, 0, 26002},
      {"bunny00.off", MeshClass::kSphere, 0, 0, 37706},
      {"bear.off", MeshClass::kSphere, 0, 0, 13826},
      {"camel.off", MeshClass::kSphere, 0, 0, 9770},
      {"man.off", MeshClass::kSphere, 0, 0, 17495},
      {"dino.off", MeshClass::kSphere, 0, 0, 3916},
      {"3torus.off", MeshClass::kOther, 3, 0, 19},
      {"double-torus-example.off", MeshClass::kOther, 2, 0, 231},
      {"elephant.off", MeshClass::kOther, 3, 0, 2775},
      {"cylinder.off", MeshClass::kDisk, 0, 1, 1200},
      {"head.off", MeshClass::kOther, 0, 3, 1487},
  };
  for (const auto& k : known) {
    SCOPED_TRACE(k.file);
    CleanMesh cm = load_mesh((kData / k.file).string());
    ASSERT_TRUE(cm.valid()) << cm.report.first_error()->message;
    Topology t = compute_topology(cm.mesh);
    EXPECT_EQ(t.mesh_class, k.cls);
    EXPECT_EQ(t.genus, k.genus);
    EXPECT_EQ(t.boundary_loops, k.loops);
    EXPECT_EQ(t.vertices, k.vertices);
  }
}

TEST(RealMeshes, DefectiveModelsAreRefusedWithTheRightReason) {
  const std::map<std::string, std::string> defective = {
      {"blobby-shuffled.off", "inconsistent_orientation"},
      {"tet-shuffled.off", "inconsistent_orientation"},
      {"blobby_3cc.off", "several_components"},
      {"degtri_sliding.off", "zero_area_face"},
      {"pig.stl", "non_manifold_vertex"},
  };
  for (const auto& [file, code] : defective) {
    SCOPED_TRACE(file);
    CleanMesh cm = load_mesh((kData / file).string());
    ASSERT_NE(cm.report.first_error(), nullptr);
    EXPECT_EQ(cm.report.first_error()->code, code) << cm.report.first_error()->message;
  }
  // And the repairs the user can ask for make them usable.
  CleanMesh fixed = load_mesh((kData / "blobby-shuffled.off").string(), {.fix_orientation = true});
  EXPECT_TRUE(fixed.valid());
  EXPECT_EQ(compute_topology(fixed.mesh).mesh_class, MeshClass::kSphere);
  CleanMesh largest = load_mesh((kData / "blobby_3cc.off").string(), {.keep_largest_component = true});
  EXPECT_TRUE(largest.valid());
}

TEST(RealMeshes, ClosedModelsOpenIntoDisks) {
  for (const char* file : {"armadillo.off", "bunny00.off", "camel.off", "man.off"}) {
    SCOPED_TRACE(file);
    CleanMesh cm = load_mesh((kData / file).string());
    ASSERT_TRUE(cm.valid());
    CutHole c = cut_hole(cm.mesh);
    EXPECT_EQ(compute_topology(c.mesh).mesh_class, MeshClass::kDisk);
  }
}

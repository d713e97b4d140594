// Topology, normalization and hole cutting on meshes with known answers.
#include <gtest/gtest.h>

#include "expect_error.hpp"

#include <cmath>
#include <numbers>

#include "common/error.hpp"
#include "mesh/geometry.hpp"
#include "mesh/shapes.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"

using namespace brenier::mesh;

TEST(Topology, Icospheres) {
  for (int level = 0; level <= 3; ++level) {
    TriMesh m = make_icosphere(level);
    Topology t = compute_topology(m);
    int n = 10 * (1 << (2 * level)) + 2;
    EXPECT_EQ(t.vertices, n);
    EXPECT_EQ(t.faces, 2 * n - 4);
    EXPECT_EQ(t.edges, 3 * n - 6);
    EXPECT_EQ(t.euler, 2);
    EXPECT_EQ(t.genus, 0);
    EXPECT_EQ(t.boundary_loops, 0);
    EXPECT_EQ(t.mesh_class, MeshClass::kSphere);
  }
}

TEST(Topology, DisksGridsHemispheres) {
  for (const TriMesh& m : {make_grid(6), make_disk(5), make_hemisphere(4),
                           make_cylinder(10, 5, 1.0, 4.0, true)}) {
    Topology t = compute_topology(m);
    EXPECT_EQ(t.euler, 1);
    EXPECT_EQ(t.boundary_loops, 1);
    EXPECT_EQ(t.genus, 0);
    EXPECT_EQ(t.mesh_class, MeshClass::kDisk);
    EXPECT_TRUE(domain_mismatch(t, Domain::kDisk).empty());
    EXPECT_FALSE(domain_mismatch(t, Domain::kSphere).empty());
  }
}

TEST(Topology, TorusAndAnnulus) {
  Topology torus = compute_topology(make_torus(12, 8));
  EXPECT_EQ(torus.euler, 0);
  EXPECT_EQ(torus.genus, 1);
  EXPECT_EQ(torus.mesh_class, MeshClass::kOther);
  EXPECT_NE(domain_mismatch(torus, Domain::kSphere).find("genus 1"), std::string::npos);
  Topology annulus = compute_topology(make_cylinder(10, 4, 1.0, 2.0, false));
  EXPECT_EQ(annulus.euler, 0);
  EXPECT_EQ(annulus.boundary_loops, 2);
  EXPECT_EQ(annulus.genus, 0);
  EXPECT_EQ(annulus.mesh_class, MeshClass::kOther);
}

// Across edge (F(f, k), F(f, k + 1)) lies a face that holds that edge's two vertices and not
// the face's third corner; the relation is mutual; exactly the boundary's edges have none.
TEST(Topology, FaceNeighborsShareTheEdgeOppositeEachCorner) {
  for (const TriMesh& m : {make_disk(5), make_icosphere(2)}) {
    const auto n = face_neighbors(m.F);
    int open = 0;
    for (int f = 0; f < m.num_faces(); ++f)
      for (int k = 0; k < 3; ++k) {
        const int g = n[f][k];
        if (g < 0) {
          ++open;
          continue;
        }
        const int a = m.F(f, k), b = m.F(f, (k + 1) % 3), c = m.F(f, (k + 2) % 3);
        int shared = 0;
        for (int j = 0; j < 3; ++j) {
          shared += m.F(g, j) == a || m.F(g, j) == b;
          EXPECT_NE(m.F(g, j), c);
        }
        EXPECT_EQ(shared, 2);
        int back = 0;
        for (int j = 0; j < 3; ++j) back += n[g][j] == f;
        EXPECT_EQ(back, 1);
      }
    EXPECT_EQ(open, compute_topology(m).boundary_loops ? static_cast<int>(boundary_loops(m)[0].size()) : 0);
  }
}

TEST(Topology, BoundaryLoopFollowsTheFaces) {
  TriMesh m = make_disk(3);
  auto loops = boundary_loops(m);
  ASSERT_EQ(loops.size(), 1u);
  EXPECT_EQ(loops[0].size(), 18u);
  // Counter-clockwise faces give a counter-clockwise boundary: positive signed area.
  double a = 0;
  for (size_t i = 0; i < loops[0].size(); ++i) {
    Eigen::Vector3d p = m.V.row(loops[0][i]), q = m.V.row(loops[0][(i + 1) % loops[0].size()]);
    a += p.x() * q.y() - q.x() * p.y();
  }
  EXPECT_GT(a, 0);
}

TEST(Geometry, AreasAndNormalization) {
  TriMesh g = make_grid(11);
  EXPECT_NEAR(total_area(g), 1.0, 1e-14);
  EXPECT_NEAR(vertex_areas(g).sum(), 1.0, 1e-14);
  Eigen::Vector3d c = area_centroid(g);
  EXPECT_NEAR(c.x(), 0.5, 1e-14);
  EXPECT_NEAR(c.y(), 0.5, 1e-14);

  TriMesh s = make_icosphere(3);
  s.V = (s.V * 7.0).rowwise() + Eigen::RowVector3d(1, -2, 3);
  Normalization n = normalize(s, 4 * std::numbers::pi);
  EXPECT_NEAR(total_area(s), 4 * std::numbers::pi, 1e-10);
  EXPECT_LT(area_centroid(s).norm(), 1e-12);
  EXPECT_NEAR(n.centre.x(), 1.0, 1e-12);
  EXPECT_NEAR(n.scale * 7.0, std::sqrt(4 * std::numbers::pi / total_area(make_icosphere(3))), 1e-10);
}

TEST(CutHole, OpensASphereIntoADisk) {
  TriMesh s = make_icosphere(2);
  CutHole c = cut_hole(s);
  Topology t = compute_topology(c.mesh);
  EXPECT_EQ(t.mesh_class, MeshClass::kDisk);
  EXPECT_EQ(c.mesh.num_vertices(), s.num_vertices() - 1);
  // The removed star had as many faces as the vertex's degree (5 or 6 on an icosphere).
  int removed = s.num_faces() - c.mesh.num_faces();
  EXPECT_TRUE(removed == 5 || removed == 6) << removed;
  EXPECT_TRUE(validate(c.mesh).problems.empty());
  // Origins point back to the input.
  for (int i = 0; i < c.mesh.num_vertices(); ++i)
    EXPECT_EQ(c.mesh.V.row(i), s.V.row(c.vertex_origin[i]));

  CutHole chosen = cut_hole(s, 17);
  EXPECT_EQ(chosen.vertex, 17);
  EXPECT_ERROR(cut_hole(s, 100000), brenier::ErrorCode::kInvalidArgument, "hole vertex 100000 is out of range (the mesh has 162 vertices)");
  EXPECT_ERROR(cut_hole(make_grid(4)), brenier::ErrorCode::kInvalidArgument, "cutting a hole ({cut_hole}) needs a closed genus-0 surface; this mesh ");
  EXPECT_ERROR(cut_hole(make_torus(8, 6)), brenier::ErrorCode::kInvalidArgument, "cutting a hole ({cut_hole}) needs a closed genus-0 surface; this mesh ");
}

TEST(CutHole, DefaultVertexIsNearTheMiddle) {
  // On an ellipsoid three times longer along z, the default hole is not at a pole: its
  // farthest vertex is much nearer than a pole's (6, the other pole).
  TriMesh s = make_icosphere(3);
  s.V.col(2) *= 3.0;
  int v = default_hole_vertex(s);
  double farthest = (s.V.rowwise() - s.V.row(v)).rowwise().norm().maxCoeff();
  EXPECT_LT(farthest, 0.8 * 6.0) << "vertex " << v << " at z = " << s.V(v, 2);
}

// Geodesic distance fields and Riemannian optimal transport (Alg. 4) on closed forms: a flat
// patch, where geodesics are straight lines and the geodesic power diagram is the planar one;
// an icosphere with two antipodal equal masses (the two hemispheres); a surface's own area
// carried onto its vertices with their vertex areas (each vertex keeps its neighbourhood); and
// the refusals.
#include <gtest/gtest.h>

#include <cmath>

#include "expect_error.hpp"
#include "mesh/geodesics.hpp"
#include "mesh/geometry.hpp"
#include "mesh/shapes.hpp"
#include "omt/geodesic_omt.hpp"
#include "omt/omt.hpp"

using namespace brenier;

namespace {

// The surface point at vertex v (some face holding it, its corner's coordinate 1).
mesh::SurfacePoint at_vertex(const mesh::TriMesh& m, int v) {
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k)
      if (m.F(f, k) == v) {
        mesh::SurfacePoint p{f, Eigen::Vector3d::Zero()};
        p.bary[k] = 1;
        return p;
      }
  return {};
}

int vertex_at(const mesh::TriMesh& m, const Eigen::Vector3d& x) {
  Eigen::Index v = 0;
  (m.V.rowwise() - x.transpose()).rowwise().squaredNorm().minCoeff(&v);
  return static_cast<int>(v);
}

Eigen::Vector3d face_centroid(const mesh::TriMesh& m, int f) {
  return (m.V.row(m.F(f, 0)) + m.V.row(m.F(f, 1)) + m.V.row(m.F(f, 2))).transpose() / 3;
}

}  // namespace

TEST(Geodesics, ExactOnAFlatGridAreStraightLines) {
  const mesh::TriMesh g = mesh::make_grid(9);
  const int v = vertex_at(g, {0.25, 0.5, 0});
  const Eigen::VectorXd d = mesh::exact_distances(g, at_vertex(g, v));
  for (int i = 0; i < g.num_vertices(); ++i) EXPECT_NEAR(d[i], (g.V.row(i) - g.V.row(v)).norm(), 1e-9) << i;
}

TEST(Geodesics, HeatMethodOnAPlaneAndASphere) {
  // On a flat disk of 30 rings the heat method's distances from the centre are within a few
  // percent of the straight lines beyond the first rings (Crane et al. report about 1 % on
  // good meshes; the grid of make_grid, whose diagonals all run one way, is worse: 5.5 %).
  const mesh::TriMesh g = mesh::make_disk(30);
  const int c = vertex_at(g, {0, 0, 0});
  const Eigen::MatrixXd d = mesh::HeatGeodesics(g).distances({at_vertex(g, c)});
  double worst = 0;
  for (int i = 0; i < g.num_vertices(); ++i) {
    const double r = (g.V.row(i) - g.V.row(c)).norm();
    if (r > 0.1) worst = std::max(worst, std::abs(d(i, 0) - r) / r);
  }
  EXPECT_LT(worst, 0.04);  // measured 0.032
  // On the unit sphere the distance from the north pole is the colatitude.
  const mesh::TriMesh s = mesh::make_icosphere(4);
  const int n = vertex_at(s, {0, 0, 1});
  const Eigen::MatrixXd ds = mesh::HeatGeodesics(s).distances({at_vertex(s, n)});
  double err = 0;
  for (int i = 0; i < s.num_vertices(); ++i) err = std::max(err, std::abs(ds(i, 0) - std::acos(std::clamp(s.V(i, 2), -1.0, 1.0))));
  EXPECT_LT(err, 0.04);  // measured 0.033
}

TEST(Geodesics, EachSourcesFieldIsTheSameInAnyBatch) {
  // distances() solves its sources in blocks spread over the threads, each thread with its
  // own solve workspace and one shared factor: 21 sources in one call (three blocks) give
  // each source the field it gets alone, and again on a second call (the workspaces reused).
  const mesh::TriMesh s = mesh::make_icosphere(4);
  std::vector<mesh::SurfacePoint> from;
  for (int k = 0; k < 21; ++k) from.push_back(at_vertex(s, (k * 97) % s.num_vertices()));
  mesh::HeatGeodesics heat(s);
  const Eigen::MatrixXd all = heat.distances(from), again = heat.distances(from);
  ASSERT_EQ(all.cols(), 21);
  for (int k = 0; k < 21; ++k) {
    const Eigen::MatrixXd alone = mesh::HeatGeodesics(s).distances({from[static_cast<size_t>(k)]});
    EXPECT_LT((all.col(k) - alone.col(0)).cwiseAbs().maxCoeff(), 1e-12) << k;
    EXPECT_EQ(all.col(k), again.col(k)) << k;
    EXPECT_NEAR(all((k * 97) % s.num_vertices(), k), 0, 0.05);  // zero at the source, up to the smoothing
  }
}

TEST(GeodesicOmt, FlatPatchMatchesThePlanarPowerDiagram) {
  // Exact geodesics on a flat square: d_i^2 - d_j^2 is affine, so the geodesic power diagram
  // is the planar one and the heights agree with the planar solver's (w_i = |y_i|^2 + 2 h_i
  // there, d^2 - h here: the same cells for h = w up to a constant).
  const mesh::TriMesh g = mesh::make_grid(13);
  const std::vector<Eigen::Vector3d> y = {{0.2, 0.3, 0}, {0.75, 0.25, 0}, {0.5, 0.55, 0}, {0.3, 0.8, 0}, {0.85, 0.8, 0}};
  std::vector<mesh::SurfacePoint> sites;
  omt::Points planar(static_cast<Eigen::Index>(y.size()), 2);
  for (size_t i = 0; i < y.size(); ++i) {
    sites.push_back(at_vertex(g, vertex_at(g, y[i])));
    const Eigen::Vector3d at = g.V.row(vertex_at(g, y[i])).transpose();
    planar.row(static_cast<Eigen::Index>(i)) << 2 * at.x() - 1, 2 * at.y() - 1;  // onto [-1, 1]^2
  }
  const Eigen::VectorXd nu = (Eigen::VectorXd(5) << 1, 2, 3, 1.5, 2.5).finished();
  omt::GeodesicOmtOptions o;
  o.geodesics = omt::GeodesicMethod::kExact;
  o.subdivisions = 1;
  o.tolerance = 1e-9;
  const omt::GeodesicOmtResult r = omt::solve_geodesic_omt(g, sites, nu, {}, o);
  ASSERT_TRUE(r.converged) << r.max_relative_error;
  EXPECT_NEAR(r.mass.sum(), 1.0, 1e-12);
  for (int i = 0; i < 5; ++i) EXPECT_NEAR(r.mass[i], nu[i] / nu.sum(), 1e-9);
  omt::OmtOptions po;
  po.tolerance = 1e-10;
  const omt::OmtResult p = omt::solve_omt(omt::Domain::square(), planar, nu, po);
  ASSERT_TRUE(p.converged);
  Eigen::VectorXd w(5);
  for (int i = 0; i < 5; ++i) w[i] = (planar.row(i).squaredNorm() + 2 * p.h[i]) / 4;  // [-1, 1]^2 has 4x the squares
  w.array() -= w.mean();
  EXPECT_LT((w - r.h).cwiseAbs().maxCoeff(), 1e-7) << w.transpose() << " | " << r.h.transpose();
}

TEST(GeodesicOmt, TwoAntipodalMassesOnASphereTakeTheHemispheres) {
  const mesh::TriMesh s = mesh::make_icosphere(3);
  const std::vector<mesh::SurfacePoint> sites = {at_vertex(s, vertex_at(s, {0, 0, 1})), at_vertex(s, vertex_at(s, {0, 0, -1}))};
  omt::GeodesicOmtOptions o;
  o.subdivisions = 1;
  const omt::GeodesicOmtResult r = omt::solve_geodesic_omt(s, sites, {}, {}, o);
  ASSERT_TRUE(r.converged);
  const double total = mesh::total_area(r.mesh);
  EXPECT_NEAR(r.mass[0], total / 2, 1e-6 * total);
  EXPECT_NEAR(r.mass[1], total / 2, 1e-6 * total);
  // Every face away from the equator belongs wholly to its hemisphere's site.
  const Eigen::VectorXd area = mesh::face_areas(r.mesh);
  double wrong = 0;
  for (int f = 0; f < r.mesh.num_faces(); ++f) {
    const double z = face_centroid(r.mesh, f).z();
    if (std::abs(z) > 0.05) wrong += (r.face_cell[static_cast<size_t>(f)] != (z > 0 ? 0 : 1)) * area[f];
  }
  EXPECT_EQ(wrong, 0.0);
  // W2^2 of the sphere's area onto its poles: 2 * 2 pi * int_0^{pi/2} theta^2 sin theta = 4 pi (pi - 2).
  EXPECT_NEAR(r.transport_cost, 4 * M_PI * (M_PI - 2), 0.03 * 4 * M_PI * (M_PI - 2));
}

TEST(GeodesicOmt, OwnVertexAreasGiveEachVertexItsNeighbourhood) {
  const mesh::TriMesh s = mesh::make_icosphere(2);  // 162 vertices
  std::vector<mesh::SurfacePoint> sites;
  for (int v = 0; v < s.num_vertices(); ++v) sites.push_back(at_vertex(s, v));
  omt::GeodesicOmtOptions o;
  o.subdivisions = 2;
  const omt::GeodesicOmtResult r = omt::solve_geodesic_omt(s, sites, mesh::vertex_areas(s), {}, o);
  ASSERT_TRUE(r.converged) << r.max_relative_error;
  // Each cell lies in its vertex's star: a face of the subdivided mesh (its input face
  // f / 16) goes to a corner of that input face.
  const Eigen::VectorXd area = mesh::face_areas(r.mesh);
  double outside = 0;
  for (int f = 0; f < r.mesh.num_faces(); ++f) {
    const int parent = f / 16, cell = r.face_cell[static_cast<size_t>(f)];
    const bool corner = s.F(parent, 0) == cell || s.F(parent, 1) == cell || s.F(parent, 2) == cell;
    if (!corner) outside += area[f];
  }
  EXPECT_EQ(outside, 0.0);
}

TEST(GeodesicOmt, WeightedSourceOnAFlatSquare) {
  // One site at a corner of the unit square takes everything: W2^2 = int |x|^2 = 2/3 for the
  // area, and with the density 2x (mass 1) int 2x (x^2 + y^2) = 1/2 + 1/3 = 5/6.
  const mesh::TriMesh g = mesh::make_grid(9);
  const std::vector<mesh::SurfacePoint> corner = {at_vertex(g, vertex_at(g, {0, 0, 0}))};
  omt::GeodesicOmtOptions o;
  o.geodesics = omt::GeodesicMethod::kExact;
  o.subdivisions = 2;
  const omt::GeodesicOmtResult plain = omt::solve_geodesic_omt(g, corner, {}, {}, o);
  EXPECT_NEAR(plain.transport_cost, 2.0 / 3, 2e-3);
  const Eigen::VectorXd rho = 2 * g.V.col(0);
  const omt::GeodesicOmtResult weighted = omt::solve_geodesic_omt(g, corner, {}, rho, o);
  EXPECT_NEAR(weighted.mass[0], 1.0, 1e-12);
  EXPECT_NEAR(weighted.transport_cost, 5.0 / 6, 5e-3);
}

TEST(GeodesicOmt, Refusals) {
  const mesh::TriMesh g = mesh::make_grid(5);
  const auto a = at_vertex(g, 0), b = at_vertex(g, 7);
  EXPECT_ERROR(omt::solve_geodesic_omt(g, {}, {}, {}), ErrorCode::kInvalidArgument, "no sites");
  EXPECT_ERROR(omt::solve_geodesic_omt(g, {a}, Eigen::Vector2d(1, 1), {}), ErrorCode::kInvalidArgument, "2 masses for 1 sites");
  EXPECT_ERROR(omt::solve_geodesic_omt(g, {a, b}, Eigen::Vector2d(1, -1), {}), ErrorCode::kInvalidArgument, "positive");
  EXPECT_ERROR(omt::solve_geodesic_omt(g, {a}, {}, Eigen::VectorXd::Ones(3)), ErrorCode::kInvalidArgument, "density values");
  EXPECT_ERROR(omt::solve_geodesic_omt(g, {a, a}, {}, {}), ErrorCode::kInvalidArgument, "at one point");
  EXPECT_ERROR(omt::solve_geodesic_omt(g, {a, b}, Eigen::Vector2d(1e308, 1e308), {}), ErrorCode::kInvalidArgument, "finite sum");
  EXPECT_ERROR(omt::solve_geodesic_omt(g, {a}, {}, Eigen::VectorXd::Constant(g.num_vertices(), 1e308)),
               ErrorCode::kInvalidArgument, "total mass is not finite");
  omt::GeodesicOmtOptions deep;
  deep.subdivisions = 6;
  EXPECT_ERROR(omt::solve_geodesic_omt(mesh::make_grid(200), {a}, {}, {}, deep), ErrorCode::kInvalidArgument, "16M faces");
  const mesh::SurfacePoint off{g.num_faces(), Eigen::Vector3d(1, 0, 0)};
  EXPECT_ERROR(omt::solve_geodesic_omt(g, {a, off}, {}, {}), ErrorCode::kInvalidArgument, "site 1 is not a point");
}

// Conformal maps: the Yamabe machinery (curvature, its Jacobian, flips) and maps with known
// answers (hemisphere -> stereographic projection, planar disk -> identity, icosphere ->
// itself, long cylinder).
#include <gtest/gtest.h>

#include "expect_error.hpp"
#include "scrambled_cap.hpp"

#include <Eigen/Geometry>

#include <cmath>
#include <complex>
#include <numbers>
#include <random>

#include "common/error.hpp"
#include "conformal/conformal_map.hpp"
#include "conformal/intrinsic.hpp"
#include "conformal/mobius.hpp"
#include "conformal/yamabe.hpp"
#include "mesh/geometry.hpp"
#include "mesh/shapes.hpp"
#include "mesh/topology.hpp"
#include "quality/quality.hpp"

using namespace brenier;
using namespace brenier::conformal;
using mesh::TriMesh;

namespace {

ConformalOptions markers(int centre, int boundary) {
  ConformalOptions o;
  o.center_vertex = centre;
  o.boundary_vertex = boundary;
  return o;
}

double max_radius_error_on_boundary(const TriMesh& m, const mesh::Vertices& pos) {
  double e = 0;
  const auto loops = mesh::boundary_loops(m);
  for (int v : loops[0]) e = std::max(e, std::abs(pos.row(v).head<2>().norm() - 1.0));
  return e;
}

}  // namespace

TEST(Yamabe, GaussBonnetHoldsForCurvature) {
  for (const TriMesh& m : {mesh::make_icosphere(2), mesh::make_hemisphere(5), mesh::make_torus(9, 7)}) {
    IntrinsicTriangulation T(m);
    Eigen::VectorXd u = Eigen::VectorXd::Zero(m.num_vertices());
    double chi = mesh::compute_topology(m).euler;
    EXPECT_NEAR(curvature(T, u).sum(), 2 * std::numbers::pi * chi, 1e-9);
  }
}

TEST(Yamabe, JacobianMatchesFiniteDifferences) {
  TriMesh m = mesh::make_hemisphere(4);
  IntrinsicTriangulation T(m);
  T.make_delaunay_isometric();
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> d(-0.1, 0.1);
  Eigen::VectorXd u(m.num_vertices());
  for (auto& x : u) x = d(rng);
  ASSERT_GE(T.make_delaunay(u), 0);
  Eigen::MatrixXd H = Eigen::MatrixXd(curvature_jacobian(T, u));
  const double eps = 1e-6;
  for (int j : {0, 5, 17, m.num_vertices() - 1}) {
    Eigen::VectorXd up = u, um = u;
    up[j] += eps;
    um[j] -= eps;
    Eigen::VectorXd fd = (curvature(T, up) - curvature(T, um)) / (2 * eps);
    EXPECT_LT((fd - H.col(j)).cwiseAbs().maxCoeff(), 1e-6) << "column " << j;
  }
  // Constants are its null space.
  EXPECT_LT((H * Eigen::VectorXd::Ones(u.size())).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(Yamabe, IsometricFlipsKeepTheMetric) {
  // A flat grid with a sheared row is not Delaunay; isometric flips must keep it flat.
  TriMesh m = mesh::make_grid(6);
  m.V.col(0) += 0.8 * m.V.col(1);
  IntrinsicTriangulation T(m);
  EXPECT_GT(T.make_delaunay_isometric(), 0);
  Eigen::VectorXd K = curvature(T, Eigen::VectorXd::Zero(m.num_vertices()));
  for (int v = 0; v < m.num_vertices(); ++v)
    if (!T.boundary_vertex()[v]) {
      EXPECT_NEAR(K[v], 0.0, 1e-12) << v;
    }
}

TEST(DiskMap, PlanarDiskMapsNearTheIdentity) {
  TriMesh m = mesh::make_disk(8);
  ConformalMap c = map_to_disk(m, markers(0, mesh::boundary_loops(m)[0][0]));
  ASSERT_TRUE(c.converged);
  EXPECT_LT(max_radius_error_on_boundary(m, c.positions), 1e-14);
  // The discrete map differs from the identity only by the polygonal boundary's effect.
  double err = (c.positions.leftCols(2) - m.V.leftCols(2)).rowwise().norm().maxCoeff();
  EXPECT_LT(err, 2e-2);
  EXPECT_EQ(quality::measure(m, c.positions, quality::Target::kPlane).flipped_faces, 0);
}

TEST(DiskMap, HemisphereIsTheStereographicProjection) {
  // The upper hemisphere's conformal map onto the disk with the pole at 0 is, up to a
  // rotation, the stereographic projection from the south pole: (x, y) / (1 + z). For a mesh
  // whose vertices lie on the sphere the discrete map is this projection *exactly* (up to
  // the solver tolerance): vertex-scaling conformal equivalence is invariant under Moebius
  // transformations of space, and the stereographic projection is one. So instead of an
  // O(h^2) decay we can demand agreement to round-off at every resolution. (The O(h^2)
  // decay of a true discretization error is tested on the half-disk below.)
  for (int rings : {8, 16, 32}) {
    TriMesh m = mesh::make_hemisphere(rings);
    int b = mesh::boundary_loops(m)[0][0];
    ConformalOptions o = markers(0, b);
    o.tolerance = 1e-9;
    ConformalMap c = map_to_disk(m, o);
    ASSERT_TRUE(c.converged) << c.max_curvature_error;
    EXPECT_LE(c.max_curvature_error, 1e-9);
    EXPECT_LT(max_radius_error_on_boundary(m, c.positions), 1e-14);
    // Rotation: the boundary marker b goes to 1, and stereographic sends it to (x_b, y_b).
    std::complex<double> rot = std::conj(std::complex<double>(m.V(b, 0), m.V(b, 1)));
    double e = 0;
    for (int v = 0; v < m.num_vertices(); ++v) {
      std::complex<double> s(m.V(v, 0) / (1 + m.V(v, 2)), m.V(v, 1) / (1 + m.V(v, 2)));
      e = std::max(e, std::abs(rot * s - std::complex<double>(c.positions(v, 0), c.positions(v, 1))));
    }
    EXPECT_LT(e, 1e-8) << rings << " rings";
    // The conformal factor is the stereographic one: the sphere's metric is
    // 4 |dz|^2 / (1 + |z|^2)^2, so lambda = log 2 - log(1 + |z|^2), exactly again.
    double le = 0;
    for (int v = 0; v < m.num_vertices(); ++v) {
      double z2 = c.positions.row(v).head<2>().squaredNorm();
      le = std::max(le, std::abs(c.lambda[v] - (std::log(2.0) - std::log1p(z2))));
    }
    EXPECT_LT(le, 1e-7) << rings << " rings";
    EXPECT_EQ(quality::measure(m, c.positions, quality::Target::kPlane).flipped_faces, 0);
  }
}

TEST(DiskMap, PolynomialDomainConvergesAsHSquared) {
  // Omega = g(D) for g(w) = w + c w^2 (univalent for |c| < 1/2) has the conformal map
  // g^{-1}: Omega -> D, with g(0) = 0 and g(1) = 1 + c. Meshing Omega as g(disk mesh), the
  // discrete map with centre vertex 0 -> 0 and boundary vertex (1 + c) -> 1 must return the
  // disk mesh's own vertex positions, with an error decaying like h^2 (a smooth domain, so
  // no corner singularity pollutes the rate).
  const double c = 0.3;
  double errs[2];
  int rings[2] = {10, 20};
  for (int r = 0; r < 2; ++r) {
    TriMesh disk = mesh::make_disk(rings[r]);
    TriMesh m = disk;
    for (int v = 0; v < m.num_vertices(); ++v) {
      std::complex<double> w(disk.V(v, 0), disk.V(v, 1)), z = w + c * w * w;
      m.V(v, 0) = z.real();
      m.V(v, 1) = z.imag();
    }
    int b = -1;
    for (int v = 0; v < m.num_vertices(); ++v)
      if (std::abs(disk.V(v, 0) - 1.0) < 1e-12 && std::abs(disk.V(v, 1)) < 1e-12) b = v;
    ASSERT_GE(b, 0);
    ConformalMap cm = map_to_disk(m, markers(0, b));
    ASSERT_TRUE(cm.converged);
    EXPECT_EQ(quality::measure(m, cm.positions, quality::Target::kPlane).flipped_faces, 0);
    errs[r] = (cm.positions.leftCols(2) - disk.V.leftCols(2)).rowwise().norm().maxCoeff();
  }
  EXPECT_LT(errs[0], 0.05);
  EXPECT_LT(errs[1], errs[0] / 3.0) << "expected O(h^2): " << errs[0] << " -> " << errs[1];
}

TEST(DiskMap, LongCylinderSurvivesHugeConformalFactors) {
  // Height 12 x radius, bottom capped, top open: the conformal map squeezes the cap end by
  // about e^{-12} in length, so vertex area factors span far more than 10^6. Naive code
  // (no flips, no trust region) loses the triangle inequality here.
  TriMesh m = mesh::make_cylinder(24, 97, 1.0, 12.0, true);
  ConformalMap c = map_to_disk(m);
  ASSERT_TRUE(c.converged) << c.max_curvature_error;
  EXPECT_LE(c.max_curvature_error, 1e-7);  // the default tolerance
  EXPECT_EQ(quality::measure(m, c.positions, quality::Target::kPlane).flipped_faces, 0);
  double span = std::exp(2 * (c.lambda.maxCoeff() - c.lambda.minCoeff()));
  EXPECT_GT(span, 1e6) << "area factors span only " << span;
  EXPECT_LT(max_radius_error_on_boundary(m, c.positions), 1e-14);
  // Every point is inside the closed unit disk.
  EXPECT_LE(c.positions.leftCols(2).rowwise().norm().maxCoeff(), 1.0 + 1e-15);
}

TEST(DiskMap, BadMarkersAreRefused) {
  TriMesh m = mesh::make_disk(3);
  int b = mesh::boundary_loops(m)[0][0];
  EXPECT_ERROR(map_to_disk(m, markers(b, b)), ErrorCode::kInvalidArgument, "center vertex 19 is on the boundary; it must be interior");      // centre on the boundary
  EXPECT_ERROR(map_to_disk(m, markers(0, 0)), ErrorCode::kInvalidArgument, "boundary marker 0 is not on the boundary");      // boundary marker inside
  EXPECT_ERROR(map_to_disk(m, markers(0, 10000)), ErrorCode::kInvalidArgument, "boundary marker 10000 is out of range");  // out of range
  EXPECT_ERROR(map_to_disk(mesh::make_icosphere(1)), ErrorCode::kInvalidArgument, "the disk domain needs a topological disk but the mesh is a closed genu");  // not a disk
}

TEST(SphereMap, IcosphereMapsOntoItself) {
  // The round sphere's conformal self-maps are Moebius transformations; after centring the
  // area the map must be a rotation of the identity, so every inner product is preserved.
  // For vertices on a sphere the discrete map is exact, not just close: sending the puncture
  // to infinity with the Dirichlet link condition is the stereographic projection from it
  // (vertex scaling is Moebius invariant), so agreement is to round-off at every level.
  for (int level : {2, 3, 4}) {
    TriMesh m = mesh::make_icosphere(level);
    ConformalMap c = map_to_sphere(m);
    ASSERT_TRUE(c.converged) << c.max_curvature_error;
    EXPECT_EQ(quality::measure(m, c.positions, quality::Target::kSphere).flipped_faces, 0);
    EXPECT_LT((c.positions.rowwise().norm().array() - 1.0).abs().maxCoeff(), 1e-12);
    double w = 0;
    for (int i = 0; i < m.num_vertices(); i += 37)
      for (int j = 0; j < m.num_vertices(); j += 41)
        w = std::max(w, std::abs(m.V.row(i).dot(m.V.row(j)) - c.positions.row(i).dot(c.positions.row(j))));
    EXPECT_LT(w, 1e-9) << "level " << level;
    // A rotation of the round sphere: the conformal factor is 0 (up to round-off), except
    // at the puncture, whose factor is only estimated.
    int big = 0;
    for (int v = 0; v < m.num_vertices(); ++v) big += std::abs(c.lambda[v]) > 1e-7;
    EXPECT_LE(big, 1) << "level " << level;
  }
}

TEST(SphereMap, MarkersGoToZeroOneInfinity) {
  TriMesh m = mesh::make_icosphere(2);
  ConformalOptions o;
  o.sphere_markers = std::array<int, 3>{5, 17, 40};
  ConformalMap c = map_to_sphere(m, o);
  ASSERT_TRUE(c.converged);
  EXPECT_NEAR(std::abs(stereographic(c.positions.row(5).transpose())), 0.0, 1e-9);
  std::complex<double> one = stereographic(c.positions.row(17).transpose());
  EXPECT_NEAR(one.real(), 1.0, 1e-9);
  EXPECT_NEAR(one.imag(), 0.0, 1e-9);
  EXPECT_NEAR(c.positions(40, 2), 1.0, 1e-12);  // infinity is the north pole
  EXPECT_EQ(quality::measure(m, c.positions, quality::Target::kSphere).flipped_faces, 0);
}

TEST(Quality, IdentityHasNoDistortionAndBeltramiIsZero) {
  TriMesh m = mesh::make_grid(6);
  auto q = quality::measure(m, m.V, quality::Target::kPlane);
  EXPECT_EQ(q.flipped_faces, 0);
  EXPECT_NEAR(q.angle_distortion_deg.max, 0.0, 1e-12);
  EXPECT_NEAR(q.area_distortion_log_abs.max, 0.0, 1e-12);
  EXPECT_NEAR(q.quasi_conformal.max, 1.0, 1e-12);
  // A similarity has mu = 0; the affine stretch (x, y) -> (2x, y) has mu = 1/3 everywhere.
  mesh::Vertices sim = m.V * 3.0, stretch = m.V;
  stretch.col(0) *= 2.0;
  EXPECT_LT(quality::beltrami(m.F, m.V, sim).cwiseAbs().maxCoeff(), 1e-12);
  Eigen::VectorXcd mu = quality::beltrami(m.F, m.V, stretch);
  for (int f = 0; f < mu.size(); ++f) EXPECT_NEAR(std::abs(mu[f]), 1.0 / 3.0, 1e-12);
  auto qs = quality::measure(m, stretch, quality::Target::kPlane);
  EXPECT_NEAR(qs.quasi_conformal.max, 2.0, 1e-12);
  // Mirrored: every face flips.
  mesh::Vertices mirror = m.V;
  mirror.col(0) *= -1.0;
  EXPECT_EQ(quality::measure(m, mirror, quality::Target::kPlane).flipped_faces, m.num_faces());
}

TEST(Quality, SphereDegreeCountsHowOftenAMapCoversTheSphere) {
  // Identity: degree 1. Mirrored: every face turns inward, degree -1. The longitude doubled
  // (z -> z^2 on the Riemann sphere, branched at the poles): every face still turns
  // outward, yet the map covers the sphere twice -- no flipped face does not make a
  // bijection, and the degree is what tells.
  TriMesh m = mesh::make_icosphere(3);
  // Vertex 0 (and its antipode: the icosphere is symmetric) onto the poles, the branch points.
  const Eigen::Matrix3d turn =
      Eigen::Quaterniond::FromTwoVectors(m.V.row(0).transpose(), Eigen::Vector3d::UnitZ()).toRotationMatrix();
  m.V = (m.V * turn.transpose()).eval();
  auto q = quality::measure(m, m.V, quality::Target::kSphere);
  EXPECT_EQ(q.flipped_faces, 0);
  EXPECT_NEAR(q.degree, 1.0, 1e-12);
  mesh::Vertices mirror = m.V;
  mirror.col(0) *= -1.0;
  q = quality::measure(m, mirror, quality::Target::kSphere);
  EXPECT_EQ(q.flipped_faces, m.num_faces());
  EXPECT_NEAR(q.degree, -1.0, 1e-12);
  mesh::Vertices twice = m.V;
  for (int v = 0; v < m.num_vertices(); ++v) {
    const double r = std::hypot(m.V(v, 0), m.V(v, 1)), phi = 2 * std::atan2(m.V(v, 1), m.V(v, 0));
    twice.row(v) << r * std::cos(phi), r * std::sin(phi), m.V(v, 2);
  }
  twice.rowwise().normalize();
  q = quality::measure(m, twice, quality::Target::kSphere);
  EXPECT_EQ(q.flipped_faces, 0);
  EXPECT_NEAR(q.degree, 2.0, 1e-9);
  // One geodesic triangle: the octant has area 4 pi / 8, with the sign of its turn.
  const Eigen::Vector3d x = Eigen::Vector3d::UnitX(), y = Eigen::Vector3d::UnitY(), z = Eigen::Vector3d::UnitZ();
  EXPECT_NEAR(quality::geodesic_triangle_area(x, y, z), std::numbers::pi / 2, 1e-14);
  EXPECT_NEAR(quality::geodesic_triangle_area(x, z, y), -std::numbers::pi / 2, 1e-14);
}

TEST(DiskTargets, InscribedPolygonTurningAnglesAndGaussBonnet) {
  // Random points on a circle of radius 2.5: the targets computed from the chord lengths
  // alone must be the polygon's own turning angles (pi minus its interior angles), and sum
  // to 2 pi (Gauss-Bonnet for the disk, chi = 1).
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> gap(0.05, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    std::vector<double> ang;
    double a = 0;
    for (int i = 0; i < 12; ++i) ang.push_back(a += gap(rng));
    const double scale = 2 * std::numbers::pi / (a + gap(rng));  // all inside [0, 2 pi)
    for (double& x : ang) x *= scale;
    const int m = static_cast<int>(ang.size());
    std::vector<std::complex<double>> p;
    for (double x : ang) p.push_back(2.5 * std::polar(1.0, x));
    std::vector<double> L(m), turning, tau;
    for (int i = 0; i < m; ++i) L[i] = std::abs(p[(i + 1) % m] - p[i]);
    inscribed_targets(L, turning, tau);
    double sum = 0;
    for (int i = 0; i < m; ++i) {
      std::complex<double> in = p[i] - p[(i + m - 1) % m], out = p[(i + 1) % m] - p[i];
      double exterior = std::arg(out / in);  // turning angle at vertex i
      EXPECT_NEAR(turning[i], exterior, 1e-10) << "trial " << trial << " vertex " << i;
      sum += turning[i];
    }
    EXPECT_NEAR(sum, 2 * std::numbers::pi, 1e-12);
  }
  // A polygon whose circle centre lies outside it (one long edge: the major-arc case).
  std::vector<std::complex<double>> q = {std::polar(1.0, 0.0), std::polar(1.0, 0.4), std::polar(1.0, 0.9),
                                         std::polar(1.0, 1.3)};
  std::vector<double> L(4), turning, tau;
  for (int i = 0; i < 4; ++i) L[i] = std::abs(q[(i + 1) % 4] - q[i]);
  inscribed_targets(L, turning, tau);
  for (int i = 0; i < 4; ++i)
    EXPECT_NEAR(turning[i], std::arg((q[(i + 1) % 4] - q[i]) / (q[i] - q[(i + 3) % 4])), 1e-10) << i;
  EXPECT_LT(tau[3], 0.0) << "the long edge subtends the major arc";
}

TEST(Untangle, KeepingLongestEdgesNeverLengthensTheMapsLongestEdge) {
  // conformal::untangle's local moves (a corner mirrored across its opposite edge, or a Tutte
  // step) repeated over many rounds can carry a vertex far from a crowded cluster: on camel's
  // centroid maps they threw vertices across the sphere (faces with chords over 0.9,
  // bench/RESULTS.md, session 70). With keep_longest_edges no move lengthens the moving
  // vertex's longest edge, so no edge can grow past the longest there was: the map's longest
  // edge never grows. A cluster of an icosphere scrambled inside a small cap, on the sphere.
  const test::ScrambledCap s = test::scrambled_icosphere_cap(3, 7, 0.6, 0.3);  // about four rings
  const mesh::TriMesh& m = s.mesh;
  const mesh::Vertices& X = s.map;
  auto longest_edge = [&](const mesh::Vertices& Y) {
    double l = 0;
    for (int f = 0; f < m.num_faces(); ++f)
      for (int k = 0; k < 3; ++k) l = std::max(l, (Y.row(m.F(f, k)) - Y.row(m.F(f, (k + 1) % 3))).norm());
    return l;
  };
  const int before = quality::measure(m, X, quality::Target::kSphere).flipped_faces;
  ASSERT_GT(before, 40) << "the scrambled cap folds";
  const double longest = longest_edge(X);
  const std::vector<char> fixed(m.num_vertices(), 0);
  mesh::Vertices kept = X, loose = X;
  int left_kept = 0, left_loose = 0;
  untangle(m, kept, true, fixed, left_kept, 100, /*keep_longest_edges=*/true);
  untangle(m, loose, true, fixed, left_loose, 100, /*keep_longest_edges=*/false);
  // Measured (gcc): 51 folds -> 9 kept, 7 free; longest edge 0.927 -> 0.792 kept, 1.967 free.
  // Both compilers now draw the same case (scrambled_cap.hpp); before, clang's other draw order
  // gave another, whose free moves reached 1.335.
  EXPECT_LE(longest_edge(kept), longest * (1 + 1e-12));
  EXPECT_LT(left_kept, before);
  EXPECT_GT(longest_edge(loose), 1.2 * longest) << "here the free moves lengthen the longest edge, which the rule prevents";
}

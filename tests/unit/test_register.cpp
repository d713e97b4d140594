// Surface registration (Alg. 7): the domain bijection g hits every landmark and folds nothing,
// even where landmarks must pass each other; the location of points in a domain mesh; the
// whole registration of a surface onto a remeshed copy of itself (the analytic case: a flat
// disk, whose maps are the identity up to a turn); and the refusals.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <complex>
#include <filesystem>
#include <fstream>

#include "conformal/conformal_map.hpp"
#include "conformal/mobius.hpp"
#include "expect_error.hpp"
#include "jobs/jobs.hpp"
#include "mesh/geometry.hpp"
#include "mesh/shapes.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"
#include "quality/quality.hpp"
#include "register/correspondence.hpp"
#include "register/domain_match.hpp"
#include "register/evaluation.hpp"
#include "register/isometric_refine.hpp"

using namespace brenier;
using namespace brenier::registration;

namespace {

int folds(const mesh::TriMesh& m, const mesh::Vertices& X, bool sphere) {
  int n = 0;
  for (int f = 0; f < m.num_faces(); ++f) n += conformal::face_folded(m, X, f, sphere);
  return n;
}

// The vertex of the mesh nearest x.
int vertex_at(const mesh::TriMesh& m, const Eigen::Vector3d& x) {
  Eigen::Index v = 0;
  (m.V.rowwise() - x.transpose()).rowwise().squaredNorm().minCoeff(&v);
  return static_cast<int>(v);
}

LandmarkPair pair(const mesh::TriMesh& m, Eigen::Vector3d p, Eigen::Vector3d q, const std::string& name) {
  LandmarkPair l;
  l.vertex = vertex_at(m, p);
  l.q = q;
  l.name = name;
  return l;
}

mesh::CleanMesh as_clean(const mesh::TriMesh& m) { return mesh::clean(m); }

TEST(DomainMatch, WithoutLandmarksTheDiskIsLeftAlone) {
  const mesh::TriMesh d = mesh::make_disk(8);
  const DomainMatch g = match_disks(d.V, d.F, {});
  EXPECT_EQ(g.steps, 0);
  EXPECT_LT((g.mapped - d.V).norm(), 1e-15);
}

TEST(DomainMatch, OneTurnOfTheLandmarksIsARotation) {
  // Landmarks turned by 0.7 rad: g is that rotation; the harmonic step with the mean value
  // weights of the turned mesh reproduces it (they reproduce linear maps).
  const mesh::TriMesh d = mesh::make_disk(10);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  std::vector<LandmarkPair> l;
  for (int v : {5, 40, 77, 120}) l.push_back(pair(d, d.V.row(v).transpose(), R * d.V.row(v).transpose(), std::to_string(v)));
  const DomainMatch g = match_disks(d.V, d.F, l);
  EXPECT_NEAR(g.rotation_angle, 0.7, 1e-12);
  EXPECT_LT((g.mapped - d.V * R.transpose()).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT(g.max_landmark_error, 1e-12);
}

TEST(DomainMatch, LandmarksTurnedAgainstTheirNeighboursAreMatchedWithoutFolds) {
  // Two landmarks turn 1.2 rad about the centre while their neighbours above and below stay
  // put, and a fifth moves toward the rim: the one-shot harmonic map is not needed to be
  // unfolded, the continuation must come out unfolded with every landmark hit.
  const mesh::TriMesh d = mesh::make_disk(24);
  const double c = std::cos(1.2), s = std::sin(1.2);
  std::vector<LandmarkPair> l = {pair(d, {0.3, 0, 0}, {0.3 * c, 0.3 * s, 0}, "a"), pair(d, {-0.3, 0, 0}, {-0.3 * c, -0.3 * s, 0}, "b"),
                                 pair(d, {0, 0.6, 0}, {0, 0.6, 0}, "c"), pair(d, {0, -0.6, 0}, {0, -0.6, 0}, "d"),
                                 pair(d, {0.5, 0.5, 0}, {0.2, 0.7, 0}, "e")};
  const DomainMatch g = match_disks(d.V, d.F, l);
  EXPECT_GE(g.steps, 1);
  EXPECT_LT(g.max_landmark_error, 1e-9);
  EXPECT_EQ(folds(d, g.mapped, false), 0);
  // Still onto the disk: the boundary on the circle, the area of the image that of the disk.
  for (int i = 0; i < d.num_vertices(); ++i) EXPECT_LE(g.mapped.row(i).norm(), 1 + 1e-12);
  const Eigen::VectorXd a = mesh::face_areas(d.F, g.mapped);
  EXPECT_NEAR(a.sum(), mesh::total_area(d), 1e-9);
}

TEST(DomainMatch, ASliverInTheDomainMeshDoesNotBlockTheLandmarks) {
  // One face of a vertex's star made a sliver (the vertex moved to 1e-6 of the face's height
  // above the opposite edge, as three OMT cell centroids can fall nearly in line), and a
  // landmark at one end of that edge moved 0.05 across its line. The smooth landmark steps
  // turn such a sliver over long before the mesh around it folds; without the sliver rule,
  // each of these four cases was refused. The match must hit every landmark and come out
  // with no face folded, the sliver's included.
  for (int star = 2; star < 6; ++star) {
    mesh::TriMesh d = mesh::make_disk(12);
    const int v = vertex_at(d, {0.45, 0.1, 0});
    int sliver = -1, seen = 0;
    for (int f = 0; f < d.num_faces() && sliver < 0; ++f)
      for (int k = 0; k < 3; ++k)
        if (d.F(f, k) == v && seen++ == star) sliver = f;
    ASSERT_GE(sliver, 0);
    int k = 0;
    while (d.F(sliver, k) != v) ++k;
    const Eigen::RowVector3d a = d.V.row(d.F(sliver, (k + 1) % 3)), b = d.V.row(d.F(sliver, (k + 2) % 3));
    const Eigen::RowVector3d mid = (a + b) / 2;
    d.V.row(v) = mid + 1e-6 * (d.V.row(v) - mid);
    ASSERT_EQ(folds(d, d.V, false), 0);
    const Eigen::Vector3d n = Eigen::Vector3d(-(b - a).y(), (b - a).x(), 0).normalized();
    const Eigen::Vector3d pa = a.transpose();
    const std::vector<LandmarkPair> l = {pair(d, pa, pa - 0.05 * n, "a"), pair(d, {-0.5, 0, 0}, {-0.5, 0, 0}, "c"),
                                         pair(d, {0, -0.6, 0}, {0, -0.6, 0}, "d")};
    const DomainMatch g = match_disks(d.V, d.F, l);
    EXPECT_LT(g.max_landmark_error, 1e-9) << "star face " << star;
    EXPECT_EQ(folds(d, g.mapped, false), 0) << "star face " << star;
  }
}

TEST(DomainMatch, LandmarksThatSwapPlacesThroughOneAnotherAreRefusedByName) {
  // Straight paths through each other squeeze the mesh between them flat: refused, naming
  // both, rather than a folded map.
  const mesh::TriMesh d = mesh::make_disk(24);
  std::vector<LandmarkPair> l = {pair(d, {0.3, 0, 0}, {-0.3, 0.005, 0}, "a"), pair(d, {-0.3, 0, 0}, {0.3, -0.005, 0}, "b"),
                                 pair(d, {0, 0.6, 0}, {0, 0.6, 0}, "c")};
  EXPECT_ERROR(match_disks(d.V, d.F, l), ErrorCode::kInvalidArgument, "cannot be matched without folding the mesh");
}

TEST(DomainMatch, BoundaryLandmarksSlideAlongTheCircle) {
  const mesh::TriMesh d = mesh::make_disk(16);
  LandmarkPair b1 = pair(d, {1, 0, 0}, {std::cos(0.5), std::sin(0.5), 0}, "b1");
  LandmarkPair b2 = pair(d, {-1, 0, 0}, {-1, 0, 0}, "b2");
  b1.q_on_boundary = b2.q_on_boundary = true;
  const DomainMatch g = match_disks(d.V, d.F, {b1, b2, pair(d, {0.1, 0.2, 0}, {-0.2, 0.1, 0}, "i")});
  EXPECT_LT(g.max_landmark_error, 1e-9);
  EXPECT_EQ(folds(d, g.mapped, false), 0);
  for (int i = 0; i < d.num_vertices(); ++i) {
    if (std::abs(d.V.row(i).norm() - 1) < 1e-12) {
      EXPECT_NEAR(g.mapped.row(i).norm(), 1, 1e-12);
    }
  }
}

TEST(DomainMatch, LandmarksNoHomeomorphismMatchesAreRefusedByName) {
  const mesh::TriMesh d = mesh::make_disk(4);
  LandmarkPair b = pair(d, {1, 0, 0}, {0.5, 0, 0}, "7 (3 -> 9)");
  EXPECT_ERROR(match_disks(d.V, d.F, {b}), ErrorCode::kInvalidArgument, "landmark 7 (3 -> 9) lies on the source's boundary");
  EXPECT_ERROR(match_disks(d.V, d.F, {pair(d, {0, 0, 0}, {0.1, 0, 0}, "x"), pair(d, {0.5, 0, 0}, {0.1, 0, 0}, "y")}),
               ErrorCode::kInvalidArgument, "landmarks x and y are at one place on the target");
  // Three boundary landmarks in the opposite order around the circle.
  std::vector<LandmarkPair> l;
  for (int k = 0; k < 3; ++k) {
    const double a = 2 * M_PI * k / 3;
    LandmarkPair p = pair(d, {std::cos(a), std::sin(a), 0}, {std::cos(-a), std::sin(-a), 0}, "b" + std::to_string(k));
    p.q_on_boundary = true;
    l.push_back(p);
  }
  EXPECT_ERROR(match_disks(d.V, d.F, l), ErrorCode::kInvalidArgument, "in a different order around the target's boundary");
}

TEST(DomainMatch, SphereLandmarksAreHitWithoutFoldsAndTheSphereCoveredOnce) {
  const mesh::TriMesh s = mesh::make_icosphere(4);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(1.1, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  std::vector<LandmarkPair> l;
  int k = 0;
  for (int v : {0, 1, 7, 50, 300, 1000}) {
    Eigen::Vector3d q = R * s.V.row(v).transpose();
    if (k % 2) q = (q + Eigen::Vector3d(0.15, -0.1, 0.05)).normalized();  // not a rigid motion
    l.push_back(pair(s, s.V.row(v).transpose(), q, std::to_string(k++)));
  }
  const DomainMatch g = match_spheres(s.V, s.F, l);
  EXPECT_GE(g.steps, 1);
  EXPECT_LT(g.max_landmark_error, 1e-9);
  EXPECT_EQ(folds(s, g.mapped, true), 0);
  EXPECT_TRUE(quality::covers_once(quality::sphere_degree(s.F, g.mapped)));
  for (int i = 0; i < s.num_vertices(); ++i) EXPECT_NEAR(g.mapped.row(i).norm(), 1, 1e-9);
}

TEST(DomainMatch, LandmarksMovedByAMoebiusMapOfTheDiskAreMatchedByThatMap) {
  // q_k = M(p_k), M(z) = e^{0.4 i} (z - a) / (1 - conj(a) z): the Moebius start recovers M
  // at every vertex, not only at the landmarks; the turn alone leaves a spline's guess
  // between them.
  const mesh::TriMesh d = mesh::make_disk(16);
  const std::complex<double> a(0.25, -0.15);
  auto M = [&](const Eigen::Vector3d& x) {
    const std::complex<double> w = std::polar(1.0, 0.4) * conformal::disk_automorphism({x.x(), x.y()}, a);
    return Eigen::Vector3d(w.real(), w.imag(), 0);
  };
  std::vector<LandmarkPair> l;
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(0.3, 0.1, 0), Eigen::Vector3d(-0.4, 0.3, 0), Eigen::Vector3d(0.1, -0.6, 0),
                                   Eigen::Vector3d(-0.2, -0.3, 0), Eigen::Vector3d(0.6, 0.5, 0), Eigen::Vector3d(-0.7, -0.1, 0)})
    l.push_back(pair(d, p, M(d.V.row(vertex_at(d, p)).transpose()), "p"));
  double worst = 0;
  const DomainMatch g = match_disks(d.V, d.F, l, MatchStart::kMobius);
  for (int i = 0; i < d.num_vertices(); ++i) worst = std::max(worst, (g.mapped.row(i).transpose() - M(d.V.row(i).transpose())).norm());
  EXPECT_EQ(g.start, MatchStart::kMobius);
  EXPECT_LT(worst, 1e-6);
  EXPECT_NEAR(g.mobius_a.x(), a.real(), 1e-7);
  EXPECT_NEAR(g.mobius_a.y(), a.imag(), 1e-7);
  EXPECT_LT(g.start_rms, 1e-7);
  EXPECT_EQ(folds(d, g.mapped, false), 0);

  const DomainMatch turn = match_disks(d.V, d.F, l, MatchStart::kRotation);
  double turn_worst = 0;
  for (int i = 0; i < d.num_vertices(); ++i)
    turn_worst = std::max(turn_worst, (turn.mapped.row(i).transpose() - M(d.V.row(i).transpose())).norm());
  EXPECT_LT(turn.max_landmark_error, 1e-9);
  EXPECT_GT(turn_worst, 0.02);
}

TEST(DomainMatch, LandmarksTheTurnCannotCarryAreCarriedFromTheMoebiusStart) {
  // On a coarse disk a strong Moebius map (a = 0.6 + 0.1i) moves six landmarks along paths
  // the turn's spline steps cannot follow unfolded; the match falls back to the Moebius
  // start and says so, rather than refusing.
  const mesh::TriMesh d = mesh::make_disk(6);
  const std::complex<double> a(0.6, 0.1);
  std::vector<LandmarkPair> l;
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(0.3, 0.1, 0), Eigen::Vector3d(-0.4, 0.3, 0), Eigen::Vector3d(0.1, -0.6, 0),
                                   Eigen::Vector3d(-0.2, -0.3, 0), Eigen::Vector3d(0.6, 0.5, 0), Eigen::Vector3d(-0.7, -0.1, 0)}) {
    const int v = vertex_at(d, p);
    const std::complex<double> w = std::polar(1.0, 0.4) * conformal::disk_automorphism({d.V(v, 0), d.V(v, 1)}, a);
    l.push_back(pair(d, d.V.row(v).transpose(), {w.real(), w.imag(), 0}, std::to_string(v)));
  }
  const DomainMatch g = match_disks(d.V, d.F, l, MatchStart::kRotation);
  EXPECT_EQ(g.start, MatchStart::kMobius);
  EXPECT_LT(g.max_landmark_error, 1e-9);
  EXPECT_EQ(folds(d, g.mapped, false), 0);
}

TEST(DomainMatch, LandmarksMovedByAMoebiusMapOfTheSphereAreMatchedByThatMap) {
  // q_k = R T_a(p_k), T_a the ball's automorphism sending a to 0: the Moebius start recovers
  // it at every vertex; a rotation alone does not.
  const mesh::TriMesh s = mesh::make_icosphere(3);
  const Eigen::Vector3d a(0.2, -0.1, 0.15);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.8, Eigen::Vector3d(1, -1, 2).normalized()).toRotationMatrix();
  auto M = [&](const Eigen::Vector3d& x) -> Eigen::Vector3d { return R * conformal::sphere_automorphism(x.normalized(), a); };
  std::vector<LandmarkPair> l;
  for (int v : {0, 5, 40, 100, 300, 600}) l.push_back(pair(s, s.V.row(v).transpose(), M(s.V.row(v).transpose()), std::to_string(v)));
  const DomainMatch g = match_spheres(s.V, s.F, l, MatchStart::kMobius);
  double worst = 0;
  for (int i = 0; i < s.num_vertices(); ++i) worst = std::max(worst, (g.mapped.row(i).transpose() - M(s.V.row(i).transpose())).norm());
  EXPECT_LT(worst, 1e-6);
  EXPECT_LT((g.mobius_a - a).norm(), 1e-6);
  EXPECT_EQ(folds(s, g.mapped, true), 0);
  EXPECT_TRUE(quality::covers_once(quality::sphere_degree(s.F, g.mapped)));

  const DomainMatch turn = match_spheres(s.V, s.F, l, MatchStart::kRotation);
  double turn_worst = 0;
  for (int i = 0; i < s.num_vertices(); ++i)
    turn_worst = std::max(turn_worst, (turn.mapped.row(i).transpose() - M(s.V.row(i).transpose())).norm());
  EXPECT_GT(turn_worst, 0.02);
}

TEST(Correspondence, LocatesPointsInThePlaneAndOnTheSphere) {
  const mesh::TriMesh d = mesh::make_disk(6);
  const auto at = locate(d.F, d.V, d.V, false);
  EXPECT_LT((positions(d, at) - d.V).norm(), 1e-12);
  const mesh::TriMesh s = mesh::make_icosphere(3);
  mesh::Vertices P(50, 3);
  for (int i = 0; i < 50; ++i) P.row(i) = Eigen::Vector3d(std::sin(i * 1.3), std::cos(i * 0.7), std::sin(i * 0.31 + 1)).normalized();
  const auto on = locate(s.F, s.V, P, true);
  // Each found point is the chord point under P: parallel to it.
  const mesh::Vertices Q = positions(s, on);
  for (int i = 0; i < 50; ++i) {
    EXPECT_LT(Q.row(i).normalized().cross(P.row(i)).norm(), 1e-9);
    EXPECT_GE(on[static_cast<size_t>(i)].bary.minCoeff(), 0);
  }
}

// The walk finds the triangle the tree finds, from any start face, for points spread over the
// disk; a point outside the disk's polygon is left to the tree (the walk reaches the boundary).
TEST(Correspondence, TheWalkFromAnyFaceFindsTheTrianglesTheTreeFinds) {
  const mesh::TriMesh d = mesh::make_disk(12);
  const DomainLocator locator(d.F, d.V, false);
  mesh::Vertices P(200, 3);
  for (int i = 0; i < 200; ++i) {
    const double r = 0.98 * std::sqrt((i + 0.5) / 200), t = i * 2.399963;
    P.row(i) << r * std::cos(t), r * std::sin(t), 0;
  }
  const std::vector<SurfacePoint> tree = locator(P);
  int far_walks = 0;
  for (int i = 0; i < 200; ++i) {
    const int from = (i * 37) % d.num_faces();
    SurfacePoint w;
    if (!locator.walk(from, P.row(i).transpose(), w)) continue;  // more than 64 faces away
    ++far_walks;
    EXPECT_GE(w.bary.minCoeff(), 0);
    EXPECT_NEAR(w.bary.sum(), 1, 1e-12);
    EXPECT_LT((positions(d, {w}).row(0) - P.row(i)).norm(), 1e-12) << i;
    EXPECT_LT((positions(d, {tree[static_cast<size_t>(i)]}).row(0) - P.row(i)).norm(), 1e-12) << i;
  }
  EXPECT_GT(far_walks, 100);  // most walks across a 12-ring disk end within 64 faces
  // From the face holding it, the walk ends at once; outside the disk it fails.
  SurfacePoint w;
  EXPECT_TRUE(locator.walk(tree[0].face, P.row(0).transpose(), w));
  EXPECT_EQ(w.face, tree[0].face);
  EXPECT_FALSE(locator.walk(tree[0].face, Eigen::Vector3d(1.5, 0.2, 0), w));
}

// On the sphere the walk follows the ray from the centre: it ends on the chord triangle the
// tree's ray query finds, at the same point, from any start face.
TEST(Correspondence, TheSphereWalkEndsOnTheChordTriangleTheRayCrosses) {
  const mesh::TriMesh s = mesh::make_icosphere(3);
  const DomainLocator locator(s.F, s.V, true);
  mesh::Vertices P(200, 3);
  for (int i = 0; i < 200; ++i) {  // a Fibonacci spiral of directions, at several radii
    const double z = 1 - (2 * i + 1) / 200.0, r = std::sqrt(1 - z * z), t = i * 2.399963;
    P.row(i) = (0.5 + (i % 3) * 0.5) * Eigen::RowVector3d(r * std::cos(t), r * std::sin(t), z);
  }
  const std::vector<SurfacePoint> tree = locator(P);
  int ended = 0;
  for (int i = 0; i < 200; ++i) {
    SurfacePoint w;
    if (!locator.walk((i * 53) % s.num_faces(), P.row(i).transpose(), w)) continue;
    ++ended;
    EXPECT_GE(w.bary.minCoeff(), 0);
    EXPECT_NEAR(w.bary.sum(), 1, 1e-12);
    const Eigen::Vector3d at = positions(s, {w}).row(0).transpose(), hit = positions(s, {tree[static_cast<size_t>(i)]}).row(0).transpose();
    EXPECT_LT(at.normalized().cross(P.row(i).transpose().normalized()).norm(), 1e-12) << i;
    EXPECT_LT((at - hit).norm(), 1e-12) << i;
  }
  EXPECT_GT(ended, 100);
  // From the opposite side of the sphere the ray misses the start face's front: no walk.
  SurfacePoint w;
  EXPECT_FALSE(locator.walk(tree[0].face, -P.row(0).transpose(), w));
}

// chart_flipped_faces: a correspondence placed exactly (every vertex on itself) turns nothing
// over in any orientation-preserving chart nor in a mirrored one; two neighbours swapped turn
// over faces on the plane and on the sphere.
TEST(Correspondence, ChartFlipsCountFacesTurnedOverInTheTargetsChartOnly) {
  const mesh::TriMesh d = mesh::make_disk(6);
  const std::vector<SurfacePoint> self = locate(d.F, d.V, d.V, false);
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_EQ(chart_flipped_faces(d.F, self, d.F, (2.5 * d.V * turn.transpose()).eval(), false), 0);
  mesh::Vertices mirrored = d.V;
  mirrored.col(0) *= -1;
  EXPECT_EQ(chart_flipped_faces(d.F, self, d.F, mirrored, false), 0);
  auto swapped = [](std::vector<SurfacePoint> p, int a, int b) {
    std::swap(p[static_cast<size_t>(a)], p[static_cast<size_t>(b)]);
    return p;
  };
  // Two corners of one face swapped reverse that face and every face around the two.
  const int a = d.F(0, 0), b = d.F(0, 1);
  const int turned = chart_flipped_faces(d.F, swapped(self, a, b), d.F, d.V, false);
  EXPECT_GE(turned, 1);
  EXPECT_LT(turned, d.num_faces());
  const mesh::TriMesh s = mesh::make_icosphere(3);
  const std::vector<SurfacePoint> on = locate(s.F, s.V, s.V, true);
  EXPECT_EQ(chart_flipped_faces(s.F, on, s.F, s.V, true), 0);
  EXPECT_GE(chart_flipped_faces(s.F, swapped(on, s.F(5, 0), s.F(5, 2)), s.F, s.V, true), 1);
  std::vector<SurfacePoint> off = self;
  off[0].face = d.num_faces();
  EXPECT_ERROR(chart_flipped_faces(d.F, off, d.F, d.V, false), ErrorCode::kInvalidArgument, "a face the chart does not have");
}

TEST(IsometricRefine, AWarpedMapOfAnEllipseReturnsToTheIsometryThroughTheTargetsChart) {
  // The target is the ellipse x^2/4 + y^2 = 1 in the plane, charted onto the unit disk by
  // (x, y) -> (x / 2, y): its metric in the chart is diag(4, 1) everywhere. The source is the
  // same ellipse triangulated otherwise, so its one isometry onto the target fixing the centre
  // and the point (2, 0) sends (x, y) to (x / 2, y) in the chart. g starts from that map
  // warped by a bijection of the disk that fixes the centre and (1, 0): r -> r^1.3 and a turn
  // of the circles that varies with the angle and the radius. The refinement must bring every
  // vertex back to its isometric place, hold the two landmarks, keep the boundary on the
  // circle and turn no face over.
  const mesh::TriMesh chart = mesh::make_disk(14);
  mesh::TriMesh target = chart;
  target.V.col(0) *= 2;
  const mesh::TriMesh unit = mesh::make_disk(11);
  mesh::TriMesh source = unit;
  source.V.col(0) *= 2;
  mesh::Vertices start = unit.V;
  for (int v = 0; v < start.rows(); ++v) {
    const double r = std::hypot(unit.V(v, 0), unit.V(v, 1)), th = std::atan2(unit.V(v, 1), unit.V(v, 0));
    const double r2 = std::pow(r, 1.3), th2 = th + r * r * 0.15 * std::sin(2 * th) + 0.4 * r * r * (1 - r * r);
    start(v, 0) = r2 * std::cos(th2);
    start(v, 1) = r2 * std::sin(th2);
  }
  ASSERT_EQ(folds(source, start, false), 0);
  const int centre = vertex_at(unit, Eigen::Vector3d(0, 0, 0)), east = vertex_at(unit, Eigen::Vector3d(1, 0, 0));
  auto worst_error = [&](const mesh::Vertices& X) { return (X - unit.V).rowwise().norm().maxCoeff(); };
  const double before = worst_error(start);
  ASSERT_GT(before, 0.1);

  const IsometricRefineResult r = refine_isometric(source, start, target, chart.V, {centre, east}, false);
  EXPECT_TRUE(r.converged) << r.iterations << " iterations";
  EXPECT_LT(r.energy_after, 0.01 * r.energy_before);
  EXPECT_LT(worst_error(r.mapped), 0.02) << "from " << before;
  EXPECT_EQ(folds(source, r.mapped, false), 0);
  EXPECT_EQ(r.mapped.row(centre), start.row(centre));
  EXPECT_EQ(r.mapped.row(east), start.row(east));
  const std::vector<char> boundary = mesh::boundary_flags(source);
  for (int v = 0; v < source.num_vertices(); ++v) {
    if (!boundary[static_cast<size_t>(v)]) continue;
    EXPECT_NEAR(std::hypot(r.mapped(v, 0), r.mapped(v, 1)), 1.0, 1e-12) << v;
  }
  // The places it hands back are locate()'s: inside the chart's polygon the points themselves,
  // outside it (on the circle, between two boundary vertices) the polygon's nearest point.
  ASSERT_EQ(r.located.size(), static_cast<size_t>(r.mapped.rows()));
  const mesh::Vertices found = positions(chart, r.located);
  EXPECT_LT((found - positions(chart, locate(chart.F, chart.V, r.mapped, false))).rowwise().norm().maxCoeff(), 1e-12);
  for (int v = 0; v < source.num_vertices(); ++v) {
    if (boundary[static_cast<size_t>(v)]) continue;
    EXPECT_LT((found.row(v) - r.mapped.row(v)).norm(), 1e-12) << v;
  }
  // A caller's cancel stops it between steps.
  IsometricRefineOptions cancel;
  int asked = 0;
  cancel.keep_going = [&](int step, double) { return ++asked, step < 2; };
  EXPECT_ERROR(refine_isometric(source, start, target, chart.V, {centre, east}, false, cancel), ErrorCode::kCancelled, "cancelled");
  EXPECT_EQ(asked, 3);
}

TEST(IsometricRefine, AWarpedMapOfAnEllipsoidReturnsToTheIsometryOnTheSphere) {
  // The target is the ellipsoid x^2/4 + y^2 + z^2 = 1, an icosphere stretched along x, charted
  // onto the unit sphere by its icosphere (the chart (x, y, z) -> (x / 2, y, z) on the
  // vertices). The source is the same ellipsoid from a turned, coarser icosphere, so its
  // isometry onto the target that fixes three points sends each vertex to its own unit vector
  // in the chart (to the chords' resolution). g starts from that map warped by turns about
  // the z axis that vary with the height, 0.5 z (1 - z^2), and one about the x axis varying
  // with x; three landmarks are held at their places. The refinement must bring every vertex
  // back near its place, hold the landmarks, keep every point on the sphere and fold nothing.
  const mesh::TriMesh chart = mesh::make_icosphere(4);
  mesh::TriMesh target = chart;
  target.V.col(0) *= 2;
  mesh::TriMesh unit = mesh::make_icosphere(3);
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.5, Eigen::Vector3d(1, 2, 2).normalized()).toRotationMatrix();
  unit.V = unit.V * turn.transpose();
  mesh::TriMesh source = unit;
  source.V.col(0) *= 2;
  mesh::Vertices start = unit.V;
  for (int v = 0; v < start.rows(); ++v) {
    const Eigen::Vector3d u = unit.V.row(v).transpose();
    const Eigen::Vector3d w = Eigen::AngleAxisd(0.5 * u.z() * (1 - u.z() * u.z()), Eigen::Vector3d::UnitZ()) *
                              (Eigen::AngleAxisd(0.3 * u.x() * (1 - u.x() * u.x()), Eigen::Vector3d::UnitX()) * u);
    start.row(v) = w.normalized().transpose();
  }
  const std::vector<int> fixed = {vertex_at(unit, {0, 0, 1}), vertex_at(unit, {0, 0, -1}), vertex_at(unit, {1, 0, 0})};
  for (int v : fixed) start.row(v) = unit.V.row(v);
  ASSERT_EQ(folds(source, start, true), 0);
  auto worst_error = [&](const mesh::Vertices& X) { return (X - unit.V).rowwise().norm().maxCoeff(); };
  const double before = worst_error(start);
  ASSERT_GT(before, 0.1);

  const IsometricRefineResult r = refine_isometric(source, start, target, chart.V, fixed, true);
  EXPECT_TRUE(r.converged) << r.iterations << " iterations";
  EXPECT_LT(r.energy_after, 1e-3 * r.energy_before);
  EXPECT_LT(worst_error(r.mapped), 0.005) << "from " << before;  // 0.0011 here, in 5 full Newton steps
  EXPECT_EQ(folds(source, r.mapped, true), 0);
  for (int v : fixed) EXPECT_EQ(r.mapped.row(v), start.row(v));
  for (int v = 0; v < source.num_vertices(); ++v) EXPECT_NEAR(r.mapped.row(v).norm(), 1.0, 1e-12) << v;
  // The places it hands back are locate()'s: the points where the rays cross the chart's chords.
  ASSERT_EQ(r.located.size(), static_cast<size_t>(r.mapped.rows()));
  const mesh::Vertices found = positions(chart, r.located);
  EXPECT_LT((found - positions(chart, locate(chart.F, chart.V, r.mapped, true))).rowwise().norm().maxCoeff(), 1e-12);
}

TEST(Register, AFlatDiskOntoARemeshedCopyOfItselfErrsOnlyAtTheRemeshingsResolution) {
  // The flat unit disk's conformal and area-preserving maps are the identity up to a turn,
  // which the landmarks fix: every source vertex must land where it is, to the resolution
  // of interpolating over the remeshed triangles (the plane: exact).
  const mesh::TriMesh a = mesh::make_disk(12);
  const mesh::TriMesh b = remesh(a, 1.3);
  ASSERT_GT(b.num_vertices(), 50);
  const auto near = nearest_points(b, a.V);
  jobs::RegisterRequest r;
  for (int v : spread_vertices(a.V, 5)) {
    r.source_landmarks.push_back(v);
    Eigen::Index j = 0;
    (b.V.rowwise() - a.V.row(v)).rowwise().squaredNorm().minCoeff(&j);
    r.target_landmarks.push_back(static_cast<int>(j));
  }
  for (jobs::MapMethod m : {jobs::MapMethod::kAreaPreserving, jobs::MapMethod::kConformal}) {
    r.method = m;
    const jobs::RegisterOutcome out = jobs::run_register(as_clean(a), as_clean(b), "a", "b", r);
    ASSERT_EQ(out.rows.size(), static_cast<size_t>(a.num_vertices()));
    double worst = 0;
    for (int i = 0; i < a.num_vertices(); ++i) worst = std::max(worst, (out.morph.V.row(i) - a.V.row(i)).norm());
    // A landmark pair is off by the distance between a vertex and the nearest remeshed one.
    EXPECT_LT(worst, 0.12) << jobs::map_method_name(m);
    EXPECT_EQ(out.report["domain_folded_faces"], 0);
    EXPECT_EQ(out.report["morph_flipped_faces"], 0);
    (void)near;
  }
}

TEST(Register, CorrespondingPolesMakeTheSphereOmtMapsOfTwoMeshingsAgree) {
  // An ellipsoid (1, 1.5, 3) and a remeshed copy of it. The sphere's OMT map solves its
  // transport in the stereographic plane, which commutes only with turns about the pole
  // (sec. 3.2.5): mapped from the poles their own meshes suggest, the two maps differ by far
  // more than a rotation (0.35 median chord measured); with the target's pole the source's
  // carried over by the conformal landmarks' best rotation (as run_register does), they agree
  // to the meshes' resolution (0.004). And the registration by that route errs by little more
  // than the conformal route's.
  mesh::TriMesh m = mesh::make_icosphere(4);
  m.V = m.V * Eigen::Vector3d(1, 1.5, 3).asDiagonal();
  const TruthPair p = make_truth_pair(m, Deformation::kNone, 0, 1.0, 6);
  jobs::MapRequest r;
  r.domain = jobs::Domain::kSphere;
  r.method = jobs::MapMethod::kAreaPreserving;
  r.refine = false;
  mesh::Vertices source_conformal;
  Eigen::Vector3d source_pole;
  const jobs::MapOutcome a = jobs::run_map(as_clean(p.source), "source", r, {}, [&](const mesh::Vertices& X, const Eigen::Vector3d& own) {
    source_conformal = X;
    return source_pole = own;
  });
  const jobs::MapOutcome own = jobs::run_map(as_clean(p.target), "target", r);
  const jobs::MapOutcome carried = jobs::run_map(as_clean(p.target), "target", r, {}, [&](const mesh::Vertices& X, const Eigen::Vector3d&) {
    return Eigen::Vector3d(landmark_rotation(source_conformal, p.source_landmarks, X, p.target_landmarks) * source_pole);
  });
  auto disagreement = [&](const jobs::MapOutcome& b) {
    std::vector<double> e = domain_disagreement(p, a.positions, b.positions, true);
    std::nth_element(e.begin(), e.begin() + static_cast<long>(e.size() / 2), e.end());
    return e[e.size() / 2];
  };
  EXPECT_GT(disagreement(own), 0.1);
  EXPECT_LT(disagreement(carried), 0.01);

  jobs::RegisterRequest rr;
  rr.domain = jobs::Domain::kSphere;
  rr.method = jobs::MapMethod::kAreaPreserving;
  rr.source_landmarks = p.source_landmarks;
  rr.target_landmarks = p.target_landmarks;
  rr.isometric = false;  // g alone (--harmonic-only)
  const jobs::RegisterOutcome out = jobs::run_register(as_clean(p.source), as_clean(p.target), "source", "target", rr);
  EXPECT_EQ(out.report["domain_folded_faces"], 0);
  std::vector<SurfacePoint> found;
  for (const auto& [f, w] : out.target_points) found.push_back({f, w});
  std::vector<double> e = registration_errors(p, found, 300);
  std::nth_element(e.begin(), e.begin() + static_cast<long>(e.size() / 2), e.end());
  EXPECT_LT(e[e.size() / 2], 0.015);  // 0.0087 measured; the conformal route 0.0074
  EXPECT_FALSE(out.report["isometric"]["applied"].get<bool>());

  // The sphere's conformal route leaves g alone unless asked.
  jobs::RegisterRequest conformal = rr;
  conformal.method = jobs::MapMethod::kConformal;
  conformal.isometric = true;
  EXPECT_FALSE(jobs::run_register(as_clean(p.source), as_clean(p.target), "source", "target", conformal)
                   .report["isometric"]["applied"]
                   .get<bool>());

  // By default the area-preserving route refines g: it lowers its energy, folds nothing and
  // keeps the error.
  rr.isometric = true;
  const jobs::RegisterOutcome refined = jobs::run_register(as_clean(p.source), as_clean(p.target), "source", "target", rr);
  const nlohmann::json& iso = refined.report["isometric"];
  ASSERT_TRUE(iso["applied"].get<bool>());
  EXPECT_LT(iso["energy_after"].get<double>(), iso["energy_before"].get<double>());
  EXPECT_EQ(refined.report["domain_folded_faces"], 0);
  found.clear();
  for (const auto& [f, w] : refined.target_points) found.push_back({f, w});
  std::vector<double> e2 = registration_errors(p, found, 300);
  std::nth_element(e2.begin(), e2.begin() + static_cast<long>(e2.size() / 2), e2.end());
  EXPECT_LT(e2[e2.size() / 2], 0.015) << "g alone " << e[e.size() / 2];
}

TEST(Register, RefusesMeshesOfDifferentTopologyAndBadLandmarks) {
  const mesh::TriMesh disk = mesh::make_disk(5), sphere = mesh::make_icosphere(2);
  jobs::RegisterRequest r;
  EXPECT_ERROR(jobs::run_register(as_clean(disk), as_clean(sphere), "a.off", "b.off", r), ErrorCode::kInvalidArgument,
               "meshes of different topology cannot be registered");
  r.source_landmarks = {1, 2};
  r.target_landmarks = {1};
  EXPECT_ERROR(jobs::run_register(as_clean(disk), as_clean(disk), "a.off", "b.off", r), ErrorCode::kInvalidArgument,
               "the source has 2 landmarks and the target 1");
  r.target_landmarks = {1, 5000};
  EXPECT_ERROR(jobs::run_register(as_clean(disk), as_clean(disk), "a.off", "b.off", r), ErrorCode::kInvalidArgument,
               "b.off: landmark 2 is vertex 5000, but the mesh has 91 vertices");
  r.target_landmarks = {3, 3};
  EXPECT_ERROR(jobs::run_register(as_clean(disk), as_clean(disk), "a.off", "b.off", r), ErrorCode::kInvalidArgument,
               "target landmarks 1 and 2 are the same vertex 3");
  r.target_landmarks = {1, 3};
  r.isometric = false;  // --harmonic-only
  r.isometric_sphere = true;
  EXPECT_ERROR(jobs::run_register(as_clean(sphere), as_clean(sphere), "a.off", "b.off", r), ErrorCode::kInvalidArgument,
               "{harmonic_only} keeps g without the isometric refinement and {isometric_sphere} asks for it");
}

TEST(Register, LandmarksFilesAreReadWithLineNumbers) {
  const std::string path = (std::filesystem::temp_directory_path() / "brenier-landmarks.txt").string();
  std::ofstream(path) << "# nose\n12\n\n 7 \n";
  EXPECT_EQ(jobs::read_landmarks_file(path), (std::vector<int>{12, 7}));
  std::ofstream(path) << "12\nseven\n";
  EXPECT_ERROR(jobs::read_landmarks_file(path), ErrorCode::kInvalidArgument, ":2: 'seven' is not a vertex number");
  EXPECT_ERROR(jobs::read_landmarks_file(path + ".missing"), ErrorCode::kInvalidArgument, "cannot read the landmarks file");
}

TEST(Evaluation, GeodesicsOnAFlatGridAreStraightLines) {
  const mesh::TriMesh g = mesh::make_grid(9);
  const auto from = nearest_points(g, (mesh::Vertices(2, 3) << 0.1, 0.1, 0, 0.33, 0.71, 0).finished());
  const auto to = nearest_points(g, (mesh::Vertices(2, 3) << 0.9, 0.8, 0, 0.35, 0.2, 0).finished());
  const auto d = geodesic_distances(g, from, to);
  EXPECT_NEAR(d[0], std::hypot(0.8, 0.7), 1e-9);
  EXPECT_NEAR(d[1], std::hypot(0.02, 0.51), 1e-9);
  const auto c = cumulative_curve({0.1, 0.2, 0.3, 0.4}, {0.05, 0.2, 1});
  EXPECT_EQ(c, (std::vector<double>{0, 0.5, 1}));
}

}  // namespace

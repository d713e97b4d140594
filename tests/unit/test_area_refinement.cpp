// The face-by-face area refinement (omt/area_refinement.hpp) on closed forms: a start whose
// targets a similarity meets exactly comes back to it (the energy's unique minimum); the
// area-preserving maps of a square and an ellipsoid reach their stated tolerances with no
// flipped face, the disk's boundary on the circle in its order and the sphere covered once;
// an open cube's map, whose boundary slides, reaches equal areas; region weights move the
// faces' areas to their weighted targets; phi_t, --no-refine and a folded start are left
// alone.
#include <gtest/gtest.h>

#include "expect_error.hpp"
#include "random_draws.hpp"

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <numbers>
#include <random>

#include "common/error.hpp"
#include "mesh/geometry.hpp"
#include "mesh/shapes.hpp"
#include "mesh/topology.hpp"
#include "omt/area_preserving.hpp"
#include "omt/area_refinement.hpp"
#include "omt/barrier_energy.hpp"
#include "quality/quality.hpp"

using namespace brenier;

namespace {

std::vector<char> boundary_of(const mesh::TriMesh& m) {
  std::vector<char> b(m.num_vertices(), 0);
  for (const auto& loop : mesh::boundary_loops(m))
    for (int v : loop) b[v] = 1;
  return b;
}

// The disk's vertices pulled radially, r -> r^1.6 (the boundary unchanged).
mesh::Vertices pulled_radially(const mesh::Vertices& V) {
  mesh::Vertices X = V;
  for (Eigen::Index v = 0; v < X.rows(); ++v)
    if (const double r = X.row(v).head<2>().norm(); r > 0) X.row(v).head<2>() *= std::pow(r, 0.6);
  return X;
}

// The unit sphere's vertices slid toward the north pole: x + push e_z, normalized.
mesh::Vertices pushed_north(const mesh::Vertices& V, double push) {
  mesh::Vertices X = V;
  for (Eigen::Index v = 0; v < X.rows(); ++v) X.row(v) = (X.row(v) + Eigen::RowVector3d(0, 0, push)).normalized();
  return X;
}

// The unit icosphere of `level` (its own chord triangles are the targets) with every vertex
// slid toward the north pole (x + push e_z, normalized), refined to mean 1e-4 / p95 1e-3.
struct PushedIcosphere {
  mesh::TriMesh m;
  mesh::Vertices X;
  omt::AreaRefinement r;
  quality::MapQuality q;
};
PushedIcosphere refine_pushed_icosphere(int level, double push) {
  PushedIcosphere p;
  p.m = mesh::make_icosphere(level);
  for (int v = 0; v < p.m.num_vertices(); ++v) p.m.V.row(v).normalize();
  p.X = pushed_north(p.m.V, push);
  omt::AreaRefineOptions o;
  o.mean_tolerance = 1e-4;
  o.p95_tolerance = 1e-3;
  p.r = omt::refine_sphere_areas(p.m, mesh::face_areas(p.m), p.X, o);
  p.q = quality::measure(p.m, p.X, quality::Target::kSphere);
  return p;
}

// A cube's eight corners (+-1 each, corner v at the signs of its bits) and its twelve
// triangles, turned outward; with open_top the two of the face z = 1 are left out.
mesh::TriMesh make_cube(bool open_top) {
  mesh::TriMesh m;
  m.V.resize(8, 3);
  for (int v = 0; v < 8; ++v) m.V.row(v) << (v & 1 ? 1 : -1), (v & 2 ? 1 : -1), (v & 4 ? 1 : -1);
  m.F.resize(open_top ? 10 : 12, 3);
  m.F.topRows(10) << 0, 2, 1, 1, 2, 3,  // z = -1
      0, 1, 4, 1, 5, 4,                 // y = -1
      2, 6, 3, 3, 6, 7,                 // y = 1
      0, 4, 2, 2, 4, 6,                 // x = -1
      1, 3, 5, 3, 7, 5;                 // x = 1
  if (!open_top) m.F.bottomRows(2) << 4, 5, 6, 5, 7, 6;  // z = 1
  return m;
}

}  // namespace

TEST(AreaRefinement, AFlatDiskPulledRadiallyComesBackToItself) {
  // The flat unit disk's own triangles are the targets, so the identity meets every one
  // exactly (D = 1) and is conformal (the MIPS term least): the energy's unique minimum with
  // the boundary held. The start pulls every vertex radially, r -> r^1.6 (areas off by up to
  // a factor 2.5 near the centre, boundary unchanged).
  mesh::TriMesh m = mesh::make_disk(12);
  mesh::Vertices X = pulled_radially(m.V);
  const std::vector<char> fixed = boundary_of(m);
  omt::AreaRefineOptions o;
  o.slide_boundary = false;  // held: the minimum is the identity itself, not a turn of it
  o.mean_tolerance = 1e-5;
  o.p95_tolerance = 1e-4;
  const omt::AreaRefinement r = omt::refine_disk_areas(m, mesh::face_areas(m), X, fixed, o);
  EXPECT_TRUE(r.ran);
  EXPECT_TRUE(r.converged) << r.after.mean << " " << r.after.p95 << " after " << r.iterations;
  EXPECT_GT(r.before.mean, 0.1);
  EXPECT_LE(r.after.p95, 1e-4);
  EXPECT_LT((X - m.V).rowwise().norm().maxCoeff(), 1e-3);
  for (int v = 0; v < m.num_vertices(); ++v)
    if (fixed[v]) {
      EXPECT_LT((X.row(v) - m.V.row(v)).norm(), 1e-15) << v;  // held (r^0.6 at r = 1 is 1 to an ulp)
    }
  EXPECT_EQ(quality::measure(m, X, quality::Target::kPlane).flipped_faces, 0);
  // A caller's cancel stops it after the step that asked, the mean it is told falling.
  X = pulled_radially(m.V);
  std::vector<double> told;
  o.keep_going = [&](int step, double mean) { return told.push_back(mean), step < 3; };
  EXPECT_ERROR(omt::refine_disk_areas(m, mesh::face_areas(m), X, fixed, o), ErrorCode::kCancelled, "cancelled");
  ASSERT_EQ(told.size(), 3u);
  EXPECT_LT(told[0], r.before.mean);
  EXPECT_LT(told[2], told[0]);
}

TEST(AreaRefinement, AnIcospherePushedTowardAPoleComesBackToAnIsometry) {
  // The unit icosphere's own chord triangles are the targets; the start slides every vertex
  // toward the north pole (x + 0.4 e_z, normalized: caps crowded, the south spread). The
  // minimum is a rotation of the icosphere: equal areas and angles.
  const PushedIcosphere p = refine_pushed_icosphere(2, 0.4);
  const omt::AreaRefinement& r = p.r;
  EXPECT_TRUE(r.ran);
  EXPECT_TRUE(r.converged) << r.after.mean << " " << r.after.p95 << " after " << r.iterations;
  EXPECT_GT(r.before.mean, 0.1);
  const quality::MapQuality& q = p.q;
  EXPECT_EQ(q.flipped_faces, 0);
  EXPECT_TRUE(quality::covers_once(q.degree));
  EXPECT_LT(q.angle_distortion_deg.max, 2.0);
  EXPECT_LT((p.X.rowwise().norm().array() - 1).abs().maxCoeff(), 1e-12);
  // A caller's cancel reaches the sphere's steps too.
  mesh::Vertices X = pushed_north(p.m.V, 0.4);
  omt::AreaRefineOptions o;
  int asked = 0;
  o.keep_going = [&](int, double) { return ++asked < 2; };
  EXPECT_ERROR(omt::refine_sphere_areas(p.m, mesh::face_areas(p.m), X, o), ErrorCode::kCancelled, "cancelled");
  EXPECT_EQ(asked, 2);
}

TEST(AreaRefinement, ACoarsePolyhedronComesBackThoughItsVolumeChanged) {
  // The same on the icosahedron (12 vertices), pushed toward the pole (x + 0.2 e_z,
  // normalized): its inscribed polyhedron holds a different volume than the regular one, so
  // a target scale fixed at the start cannot be met by equal areas (with it, the refinement
  // ended worse than its start and kept it); the scale refitted before every step
  // (area_refinement.cpp) finds the regular icosahedron again. (A push of 0.4 with a tilt is
  // not recovered: 0.18 after 100 steps; bench/RESULTS.md.)
  const PushedIcosphere p = refine_pushed_icosphere(0, 0.2);
  const omt::AreaRefinement& r = p.r;
  EXPECT_TRUE(r.ran);
  EXPECT_GT(r.before.mean, 0.1);
  EXPECT_TRUE(r.converged) << r.after.mean << " " << r.after.p95 << " after " << r.iterations;
  EXPECT_FALSE(r.kept_start);
  EXPECT_EQ(p.q.flipped_faces, 0);
  EXPECT_TRUE(quality::covers_once(p.q.degree));
}

TEST(AreaRefinement, ACubeSlidTowardAPoleComesBackToEqualAreas) {
  // A cube's eight corners on the unit sphere, its twelve triangles the targets (all equal),
  // every corner slid toward the north pole and a little sideways (x + (0.1, 0, 0.3),
  // normalized). The inscribed cube meets the targets exactly. The volume measure's minimum is
  // elsewhere (its planes' distances change with the shape: its result came out worse than the
  // start, which was kept, mean 0.24 after 100 steps); the chord stage after it
  // (area_refinement.cpp) reaches equal areas, to within what its energy's own minimum allows:
  // both of its theta stages end at mean |log area ratio| ~4e-4 here, with the Newton
  // decrement below 1e-7 of the energy. The tolerance was 1e-4 until session 55, met only where
  // the steps happened to pass below it on the way (the stages now go on to their minimum
  // unless the tolerance stops them, and return their best map: 2e-4).
  mesh::TriMesh m = make_cube(false);
  m.V /= std::sqrt(3.0);
  const quality::MapQuality cube = quality::measure(m, m.V, quality::Target::kSphere);
  ASSERT_EQ(cube.flipped_faces, 0);  // the faces as written turn outward
  mesh::Vertices X = m.V;
  for (int v = 0; v < 8; ++v) X.row(v) = (X.row(v) + Eigen::RowVector3d(0.1, 0, 0.3)).normalized();
  omt::AreaRefineOptions o;
  o.mean_tolerance = 1e-3;
  o.p95_tolerance = 1e-3;
  const omt::AreaRefinement r = omt::refine_sphere_areas(m, mesh::face_areas(m), X, o);
  EXPECT_GT(r.before.mean, 0.1);
  EXPECT_TRUE(r.converged) << r.after.mean << " " << r.after.p95 << " after " << r.iterations;
  EXPECT_FALSE(r.kept_start);
  const quality::MapQuality q = quality::measure(m, X, quality::Target::kSphere);
  EXPECT_EQ(q.flipped_faces, 0);
  EXPECT_TRUE(quality::covers_once(q.degree));
}

TEST(AreaRefinement, ABeamsMapSlidTowardAPoleComesBackToItsInscribedBox) {
  // A beam, the box 2 x 2 x 18 (data/meshes/beam.off's proportions), its corners on the unit
  // sphere slid toward the north pole as in the cube's test above. Every box has a
  // circumsphere about its centre, so the inscribed box meets the targets exactly, but its four
  // long sides' planes lie only 0.11 from the centre. Without the chord measure's plane barrier
  // (SphereGeometry) the steps pressed a face's plane against the centre, the line search cut
  // them to nothing and the map stalled at mean |log area ratio| 0.039 after 15 steps (beam.off
  // itself at 0.13); with it, the default tolerances are met.
  mesh::TriMesh m = make_cube(false);
  m.V.col(2) *= 9;
  mesh::Vertices X = m.V;
  for (int v = 0; v < 8; ++v) X.row(v) = (X.row(v).normalized() + Eigen::RowVector3d(0.1, 0, 0.3)).normalized();
  const omt::AreaRefinement r = omt::refine_sphere_areas(m, mesh::face_areas(m), X, omt::AreaRefineOptions{});
  EXPECT_GT(r.before.mean, 0.15);
  EXPECT_TRUE(r.converged) << r.after.mean << " " << r.after.p95 << " after " << r.iterations;
  const quality::MapQuality q = quality::measure(m, X, quality::Target::kSphere);
  EXPECT_EQ(q.flipped_faces, 0);
  EXPECT_TRUE(quality::covers_once(q.degree));
}

TEST(AreaRefinement, TheSquaresAreaPreservingDiskMapPreservesAreaFaceByFace) {
  // A flat square's disk map: the seed's centroid map leaves the faces near the corners off
  // their areas (mean |log ratio| ~0.03). The refinement brings the faces within the issue's
  // bar (mean <= 0.02, p95 <= 0.1) with no flipped face, the boundary vertices on the circle
  // in their order, the cells untouched. (Per face, exact areas are out of reach on a fixed
  // triangulation: #faces - 1 area equations against 2 #interior + #boundary unknowns leave
  // almost no freedom; what is left shrinks with the mesh size: 0.019 at 25 x 25, 0.012 at
  // 40 x 40.) converged says whether the stated tolerances were met.
  mesh::TriMesh m = mesh::make_grid(40);
  omt::AreaPreservingOptions plain;
  plain.refine.enabled = false;
  const omt::AreaPreservingMap seed = omt::area_preserving_disk(m, plain);
  EXPECT_FALSE(seed.refinement.ran);
  const omt::AreaPreservingMap ap = omt::area_preserving_disk(m);
  const omt::AreaRefinement& r = ap.refinement;
  ASSERT_TRUE(r.ran);
  const quality::MapQuality q0 = quality::measure(m, seed.positions, quality::Target::kPlane);
  const quality::MapQuality q = quality::measure(m, ap.positions, quality::Target::kPlane);
  EXPECT_NEAR(r.before.mean, q0.area_distortion_log_abs.mean, 1e-12);
  EXPECT_NEAR(r.after.mean, q.area_distortion_log_abs.mean, 1e-12);
  EXPECT_EQ(r.converged, r.after.mean <= r.mean_tolerance && r.after.p95 <= r.p95_tolerance);
  EXPECT_GT(q0.area_distortion_log_abs.mean, 0.02);
  EXPECT_LE(q.area_distortion_log_abs.mean, 0.02);
  EXPECT_LE(q.area_distortion_log_abs.p95, 0.05);
  EXPECT_LT(q.area_distortion_log_abs.mean, 0.5 * q0.area_distortion_log_abs.mean);
  EXPECT_EQ(q.flipped_faces, 0);
  for (const auto& loop : mesh::boundary_loops(m)) {
    double turned = 0;  // the boundary's winding: once around
    for (size_t i = 0; i < loop.size(); ++i) {
      const Eigen::Vector2d a = ap.positions.row(loop[i]).head<2>(), b = ap.positions.row(loop[(i + 1) % loop.size()]).head<2>();
      EXPECT_NEAR(a.norm(), 1.0, 1e-12) << loop[i];
      turned += std::atan2(a.x() * b.y() - a.y() * b.x(), a.dot(b));
    }
    EXPECT_NEAR(std::abs(turned), 2 * std::numbers::pi, 1e-9);
  }
  EXPECT_EQ(ap.omt.cells.mass, seed.omt.cells.mass);
}

TEST(AreaRefinement, AnOpenCubesDiskMapReachesEqualAreasWithItsBoundarySliding) {
  // A cube with one face left open (the top four corners the boundary, the bottom four
  // inside): ten triangles of equal area. Its disk map's boundary vertices slide along the
  // circle, and so the inscribed polygon's area, the map's total, changes as they move. With
  // the targets' scale set once at the start the energy's minimum sat where the total
  // matched that scale, not at equal areas (mean |log area ratio| 0.067, p95 0.20); refitted
  // before every step (area_refinement.cpp) it meets the default tolerances.
  const mesh::TriMesh m = make_cube(true);  // the open face is z = 1 (corners 4..7)
  ASSERT_EQ(mesh::boundary_loops(m).size(), 1u);
  const omt::AreaPreservingMap ap = omt::area_preserving_disk(m);
  const omt::AreaRefinement& r = ap.refinement;
  ASSERT_TRUE(r.ran);
  EXPECT_GT(r.before.mean, 0.1);
  EXPECT_TRUE(r.converged) << r.after.mean << " " << r.after.p95 << " after " << r.iterations;
  const quality::MapQuality q = quality::measure(m, ap.positions, quality::Target::kPlane);
  EXPECT_LE(q.area_distortion_log_abs.mean, 0.01);
  EXPECT_LE(q.area_distortion_log_abs.p95, 0.05);
  EXPECT_EQ(q.flipped_faces, 0);
}

TEST(AreaRefinement, TheEllipsoidsSphereMapPreservesAreaFaceByFaceAndCoversOnce) {
  mesh::TriMesh m = mesh::make_icosphere(3);
  m.V.col(2) *= 3.0;
  const omt::AreaPreservingMap ap = omt::area_preserving_sphere(m);
  ASSERT_TRUE(ap.refinement.ran);
  EXPECT_TRUE(ap.refinement.converged) << ap.refinement.after.mean << " " << ap.refinement.after.p95;
  const quality::MapQuality q = quality::measure(m, ap.positions, quality::Target::kSphere);
  EXPECT_LE(q.area_distortion_log_abs.mean, 0.01);
  EXPECT_LE(q.area_distortion_log_abs.p95, 0.05);
  EXPECT_LT(ap.refinement.after.mean, 0.5 * ap.refinement.before.mean);
  EXPECT_EQ(q.flipped_faces, 0);
  EXPECT_TRUE(quality::covers_once(q.degree));
  EXPECT_LT((ap.positions.rowwise().norm().array() - 1).abs().maxCoeff(), 1e-12);
}

TEST(AreaRefinement, RegionWeightsSetTheFacesTargets) {
  // Weight 4 on the vertices with x > 0: each face's target is its area times its corners'
  // mean weight, and the refined map gives the faces those shares of the disk.
  mesh::TriMesh m = mesh::make_hemisphere(16);
  omt::AreaPreservingOptions o;
  o.weights = Eigen::VectorXd::Ones(m.num_vertices());
  for (int v = 0; v < m.num_vertices(); ++v)
    if (m.V(v, 0) > 0) o.weights[v] = 4;
  const omt::AreaPreservingMap ap = omt::area_preserving_disk(m, o);
  ASSERT_TRUE(ap.refinement.ran);
  EXPECT_TRUE(ap.refinement.converged);
  Eigen::VectorXd target = mesh::face_areas(m);
  for (int f = 0; f < m.num_faces(); ++f)
    target[f] *= (o.weights[m.F(f, 0)] + o.weights[m.F(f, 1)] + o.weights[m.F(f, 2)]) / 3;
  const Eigen::VectorXd r = omt::abs_log_area_ratios(m.F, ap.positions, target);
  EXPECT_LE(r.mean(), 0.01);
  EXPECT_NEAR(r.mean(), ap.refinement.after.mean, 1e-12);
  // Against the unweighted areas the map is far off: the weights are what it follows.
  EXPECT_GT(quality::measure(m, ap.positions, quality::Target::kPlane).area_distortion_log_abs.mean, 0.3);
}

TEST(AreaRefinement, PhiTAFoldedStartAndNoRefineAreLeftAlone) {
  mesh::TriMesh m = mesh::make_hemisphere(12);
  omt::AreaPreservingOptions o;
  o.t = 0.5;  // phi_t is between the area-preserving and the conformal map by design
  EXPECT_FALSE(omt::area_preserving_disk(m, o).refinement.ran);
  // A folded start: vertex 0 (the centre) pushed across its ring.
  mesh::TriMesh d = mesh::make_disk(6);
  mesh::Vertices X = d.V;
  X.row(0) << 0.9, 0.0, 0.0;
  ASSERT_GT(quality::measure(d, X, quality::Target::kPlane).flipped_faces, 0);
  const mesh::Vertices before = X;
  const omt::AreaRefinement r = omt::refine_disk_areas(d, mesh::face_areas(d), X, boundary_of(d), {});
  EXPECT_FALSE(r.ran);
  EXPECT_EQ(X, before);
  omt::AreaRefineOptions off;
  off.enabled = false;
  X = d.V;
  EXPECT_FALSE(omt::refine_disk_areas(d, mesh::face_areas(d), X, boundary_of(d), off).ran);
  EXPECT_EQ(X, d.V);
}

TEST(AreaRefinement, APlanMadeAheadGivesTheSameMapAndServesOnlyItsOwnMesh) {
  // The plan (unknowns, pattern and CHOLMOD's analysis) made ahead, as the maps make it on a
  // second thread, and reused for a second refinement: the same map to the last bit as a
  // refinement that makes its own. The pulled disk of AFlatDiskPulledRadially..., boundary sliding.
  const mesh::TriMesh m = mesh::make_disk(12);
  const mesh::Vertices start = pulled_radially(m.V);
  const std::vector<char> fixed = boundary_of(m);
  const omt::AreaRefineOptions o;
  mesh::Vertices own = start;
  const omt::AreaRefinement r0 = omt::refine_disk_areas(m, mesh::face_areas(m), own, fixed, o);
  ASSERT_TRUE(r0.ran);
  ASSERT_GT(r0.iterations, 1);
  const std::shared_ptr<omt::RefinementPlan> plan = omt::plan_disk_refinement(m, fixed, o);
  for (int run = 0; run < 2; ++run) {
    mesh::Vertices X = start;
    const omt::AreaRefinement r = omt::refine_disk_areas(m, mesh::face_areas(m), X, fixed, o, plan);
    EXPECT_EQ(X, own) << "run " << run;
    EXPECT_EQ(r.iterations, r0.iterations);
  }
  // Another mesh, or the boundary held where the plan slides it: refused, not misused.
  const mesh::TriMesh other = mesh::make_disk(10);
  mesh::Vertices Y = other.V;
  EXPECT_THROW(omt::refine_disk_areas(other, mesh::face_areas(other), Y, boundary_of(other), o, plan), Error);
  omt::AreaRefineOptions held = o;
  held.slide_boundary = false;
  mesh::Vertices X = start;
  EXPECT_THROW(omt::refine_disk_areas(m, mesh::face_areas(m), X, fixed, held, plan), Error);
  // The sphere's: one plan through its volume and chord stages, the same map as without.
  const mesh::TriMesh s = [] {
    mesh::TriMesh ico = mesh::make_icosphere(2);
    for (int v = 0; v < ico.num_vertices(); ++v) ico.V.row(v).normalize();
    return ico;
  }();
  mesh::Vertices A = pushed_north(s.V, 0.5);
  mesh::Vertices B = A;
  omt::refine_sphere_areas(s, mesh::face_areas(s), A, o);
  omt::refine_sphere_areas(s, mesh::face_areas(s), B, o, omt::plan_sphere_refinement(s));
  EXPECT_EQ(A, B);
  EXPECT_THROW(omt::refine_sphere_areas(s, mesh::face_areas(s), B, o, plan), Error);
}

TEST(AreaRefinement, TheSphereStepStopsAtTheFirstFaceThatTurns) {
  // detail::first_turn_on_sphere, the bound of the sphere's Newton steps, against the sign of
  // det(a, b, c) sampled along the move itself (each corner x + t dx put back on the sphere):
  // small and large faces with steps from a tenth of their size to ten times it, so that
  // some never turn, some turn once, and some turn, come back and turn again within the limit,
  // where the first crossing must be the one returned.
  std::mt19937 rng(26);
  std::normal_distribution<double> normal;
  auto unit = [&] { return test::draw3(normal, rng).normalized(); };
  auto tangent = [&](const Eigen::Vector3d& x, double size) {
    Eigen::Vector3d v = test::draw3(normal, rng);
    return (size * (v - v.dot(x) * x)).eval();
  };
  const double limit = 2;
  const int samples = 20000;
  int turned = 0, never = 0, twice = 0;
  for (int trial = 0; trial < 600; ++trial) {
    const double size = std::pow(10.0, -3 + 2.5 * (trial % 7) / 6.0);  // 1e-3 .. 0.3
    const Eigen::Vector3d a = unit();
    Eigen::Vector3d b = (a + size * tangent(a, 1).normalized()).normalized();
    Eigen::Vector3d c = (a + size * tangent(a, 1).normalized()).normalized();
    if (a.dot((b - a).cross(c - a)) < 0) std::swap(b, c);
    const double reach = size * std::pow(10.0, -1 + 2.0 * (trial % 5) / 4.0);  // 0.1 .. 10 face sizes
    const Eigen::Vector3d da = tangent(a, reach), db = tangent(b, reach), dc = tangent(c, reach);
    auto det = [&](double t) {
      const Eigen::Vector3d A = (a + t * da).normalized(), B = (b + t * db).normalized(), C = (c + t * dc).normalized();
      return A.dot((B - A).cross(C - A));
    };
    double sampled = std::numeric_limits<double>::infinity();
    int crossings = 0;
    for (int k = 1; k <= samples; ++k) {
      const double t = limit * k / samples;
      if ((det(t) > 0) != (det(limit * (k - 1) / samples) > 0)) {
        if (crossings++ == 0) sampled = t;
      }
    }
    const double root = omt::detail::first_turn_on_sphere(a, b, c, da, db, dc, limit);
    if (!std::isfinite(sampled)) {
      ++never;
      EXPECT_TRUE(std::isinf(root)) << "trial " << trial << ": a root at " << root << " where det keeps its sign";
      continue;
    }
    ++turned;
    twice += crossings >= 2;
    EXPECT_LE(root, sampled + 1e-9) << "trial " << trial;
    EXPECT_GE(root, sampled - limit / samples - 1e-6 * limit) << "trial " << trial;  // the bisection: 1e-6 relative
    EXPECT_GT(det(root), 0) << "trial " << trial;                     // still outward at the bound
    EXPECT_LE(det(root * (1 + 2e-6) + 1e-12), 0) << "trial " << trial;  // and turned just past it
  }
  // The draw covers every case.
  EXPECT_GT(turned, 50);
  EXPECT_GT(never, 50);
  EXPECT_GT(twice, 5);
}

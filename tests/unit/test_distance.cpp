// Shape distances (core/distance): analytic radial cases, metric properties, the rotation
// search against brute force, cache files, tiles, MDS and k-NN.
#include <gtest/gtest.h>

#include "expect_error.hpp"
#include "random_draws.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <random>
#include <set>

#include "common/error.hpp"
#include "distance/analysis.hpp"
#include "distance/distance.hpp"
#include "distance/matrix.hpp"
#include "distance/shape.hpp"
#include "mesh/geometry.hpp"
#include "mesh/shapes.hpp"
#include "omt/omt.hpp"

using namespace brenier;
using distance::Shape;
using distance::ShapeOptions;

namespace {

constexpr double kPi = std::numbers::pi;

// Simpson's rule on [0, 1].
template <class F>
double integrate01(F f, int n = 2000) {
  double s = f(0.0) + f(1.0);
  for (int k = 1; k < n; ++k) s += (k % 2 ? 4 : 2) * f(static_cast<double>(k) / n);
  return s / (3.0 * n);
}

// A disk mesh lifted by a bump off the centre: not radially symmetric.
mesh::TriMesh bumped_disk(int rings, double x0, double y0, double height) {
  mesh::TriMesh m = mesh::make_disk(rings);
  for (int v = 0; v < m.num_vertices(); ++v) {
    const double dx = m.V(v, 0) - x0, dy = m.V(v, 1) - y0;
    m.V(v, 2) = height * std::exp(-(dx * dx + dy * dy) / 0.08);
  }
  return m;
}

ShapeOptions small_quadrature() {
  ShapeOptions o;
  o.quadrature.rings = 24;
  o.quadrature.angles = 64;
  return o;
}

}  // namespace

// The planar disk against the hemisphere: both radially symmetric, so every distance has a
// closed form. The hemisphere's conformal image is its stereographic projection, whose
// area (scaled to pi) has density rho(s) = 2 / (1 + s^2)^2 on the unit disk; the planar disk's
// is uniform. Matching cumulative masses, pi r^2 = 2 pi (1 - 1 / (1 + s^2)), gives the radial
// optimal map s -> r(s) = s sqrt(2 / (1 + s^2)) from rho to uniform, hence
//   W2^2 = int_0^1 rho(s) (s - r(s))^2 2 pi s ds,
// and the OMT map of Def. 2.24 from the uniform disk onto rho is its inverse
// r -> s(r) = r / sqrt(2 - r^2), hence the OMT-map distance^2 = int_0^1 (r - s(r))^2 2 pi r dr
// (the planar disk's own map is the identity).
TEST(Distance, DiskAgainstHemisphereMatchesTheRadialClosedForms) {
  const double w2 = std::sqrt(integrate01([](double s) {
    const double r = s * std::sqrt(2 / (1 + s * s));
    return 2 / ((1 + s * s) * (1 + s * s)) * (s - r) * (s - r) * 2 * kPi * s;
  }));
  const double lin = std::sqrt(integrate01([](double r) {
    const double s = r / std::sqrt(2 - r * r);
    return (r - s) * (r - s) * 2 * kPi * r;
  }));
  ShapeOptions opt = small_quadrature();
  opt.quadrature.rings = 64;
  opt.quadrature.angles = 128;
  const Shape disk = distance::prepare_shape(mesh::make_disk(24), "disk", opt);
  const Shape cap = distance::prepare_shape(mesh::make_hemisphere(24), "hemisphere", opt);
  const distance::PairResult w = distance::wasserstein(disk, cap);
  ASSERT_TRUE(w.converged);
  EXPECT_NEAR(w.distance, w2, 0.03 * w2) << "closed form " << w2;
  EXPECT_NEAR(w.forward, w.backward, 0.03 * w2);
  const distance::PairResult l = distance::omt_linear(disk, cap);
  EXPECT_NEAR(l.distance, lin, 0.05 * lin) << "closed form " << lin;
  // The debiased estimate is closer to the closed form than eq. 3.31 as it stands.
  EXPECT_LT(std::abs(w.distance - w2), std::abs(0.5 * (w.raw_forward + w.raw_backward) - w2));
}

TEST(Distance, AShapeIsAtDistanceZeroFromItselfAndFromARigidScaledCopy) {
  const mesh::TriMesh a = bumped_disk(12, 0.3, 0.1, 0.5);
  mesh::TriMesh b = a;
  const double c = std::cos(0.4), s = std::sin(0.4);
  for (int v = 0; v < b.num_vertices(); ++v) {
    const Eigen::Vector3d p = b.V.row(v);
    b.V.row(v) << 3 * (c * p.x() - s * p.z()) + 1, 3 * p.y() - 2, 3 * (s * p.x() + c * p.z());
  }
  const Shape A = distance::prepare_shape(a, "a", small_quadrature());
  const Shape B = distance::prepare_shape(b, "b", small_quadrature());
  EXPECT_EQ(distance::wasserstein(A, A).distance, 0.0);
  EXPECT_EQ(distance::omt_linear(A, A).distance, 0.0);
  EXPECT_LT(distance::wasserstein(A, B).distance, 1e-6);
  EXPECT_LT(distance::omt_linear(A, B).distance, 1e-6);
  EXPECT_NE(A.key, B.key);
}

TEST(Distance, IsSymmetricAndObeysTheTriangleInequality) {
  std::vector<Shape> s;
  const double bumps[4][3] = {{0.3, 0.1, 0.5}, {-0.2, 0.3, 0.8}, {0.0, -0.4, 0.3}, {0.1, 0.1, -0.6}};
  for (int k = 0; k < 4; ++k) {
    std::string name = "s";  // (not "s" + to_string: GCC 12 warns falsely of overlapping copies)
    name += std::to_string(k);
    s.push_back(distance::prepare_shape(bumped_disk(10, bumps[k][0], bumps[k][1], bumps[k][2]), name,
                                        small_quadrature()));
  }
  double w[4][4], l[4][4];
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      w[i][j] = distance::wasserstein(s[i], s[j]).distance;
      l[i][j] = distance::omt_linear(s[i], s[j]).distance;
    }
  distance::WassersteinOptions side_by_side;
  side_by_side.parallel_directions = true;
  EXPECT_EQ(distance::wasserstein(s[0], s[1], side_by_side).distance, w[0][1]) << "bit-identical on two threads";
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      EXPECT_NEAR(w[i][j], w[j][i], 1e-9);
      EXPECT_NEAR(l[i][j], l[j][i], 1e-12);
      if (i != j) {
        EXPECT_GT(w[i][j], 1e-3);
      }
      for (int k = 0; k < 4; ++k) {
        EXPECT_LE(l[i][k], l[i][j] + l[j][k] + 1e-12);
        EXPECT_LE(w[i][k], w[i][j] + w[j][k] + 1e-3);
      }
    }
}

// The FFT scoring of all turns agrees with trying each turn: the minimum over the cyclic
// shifts s of sum_{r,k} |a_{r,k} - e^{2 pi i s / A} b_{r,k-s}|^2.
TEST(Distance, TheRotationSearchFindsTheBruteForceMinimum) {
  const Shape a = distance::prepare_shape(bumped_disk(10, 0.3, 0.1, 0.7), "a", small_quadrature());
  const Shape b = distance::prepare_shape(bumped_disk(10, -0.25, 0.2, 0.6), "b", small_quadrature());
  const int R = static_cast<int>(a.samples.rows()), A = static_cast<int>(a.samples.cols());
  double best = INFINITY;
  int best_shift = -1;
  for (int s = 0; s < A; ++s) {
    const std::complex<double> turn = std::polar(1.0, 2 * kPi * s / A);
    double sum = 0;
    for (int r = 0; r < R; ++r)
      for (int k = 0; k < A; ++k) sum += std::norm(a.samples(r, k) - turn * b.samples(r, ((k - s) % A + A) % A));
    sum *= kPi / (R * A);
    if (sum < best) best = sum, best_shift = s;
  }
  const distance::PairResult r = distance::omt_linear(a, b);
  EXPECT_NEAR(r.distance, std::sqrt(best), 1e-12);
  EXPECT_NEAR(r.rotation, 2 * kPi * best_shift / A, 1e-12);
  EXPECT_GT(best_shift, 0) << "a test where the turn matters";
}

namespace {

// The exact distance of one candidate (both directions solved to the end), debiased.
double candidate_distance(const Shape& a, const Shape& b, const distance::PairResult::Candidate& c, bool sphere) {
  const Eigen::Vector3d flips[4] = {{1, 1, 1}, {1, -1, -1}, {-1, 1, -1}, {-1, -1, 1}};
  Eigen::VectorXd h1, h2;
  const distance::TransportCost f = sphere ? distance::transport_cost_sphere(a, b, flips[c.frame], {}, h1)
                                           : distance::transport_cost(a, b, c.rotation, {}, h1);
  const distance::TransportCost g = sphere ? distance::transport_cost_sphere(b, a, flips[c.frame], {}, h2)
                                           : distance::transport_cost(b, a, -c.rotation, {}, h2);
  EXPECT_TRUE(f.converged && g.converged);
  return 0.5 * (std::sqrt(std::max(0.0, f.w2_squared - b.quantization)) +
                std::sqrt(std::max(0.0, g.w2_squared - a.quantization)));
}

// The certificate of WassersteinOptions::exact_rotation, checked: the search did not do worse
// than the OMT-map's choice; every other candidate either converged above the chosen distance
// less the tolerance or was abandoned with a lower bound above it, and that lower bound is
// below the candidate's own exact distance (weak duality: it is a bound, not a guess).
void expect_certified_search(const Shape& a, const Shape& b, bool sphere, size_t min_candidates) {
  distance::WassersteinOptions o;
  o.exact_rotation = true;
  const distance::PairResult search = distance::wasserstein(a, b, o), plain = distance::wasserstein(a, b);
  ASSERT_TRUE(search.converged && plain.converged);
  EXPECT_TRUE(search.rotation_certified);
  EXPECT_FALSE(plain.rotation_certified);
  ASSERT_GE(search.candidates.size(), min_candidates);
  EXPECT_LE(search.distance, plain.distance * (1 + 1e-12));
  const double floor = search.distance * (1 - 0.5 * a.cost_tolerance);
  int abandoned = 0;
  for (const distance::PairResult::Candidate& c : search.candidates) {
    if (!c.abandoned) {
      ASSERT_TRUE(std::isfinite(c.distance));
      EXPECT_GE(c.distance, floor);
      continue;
    }
    ++abandoned;
    EXPECT_GT(c.lower_bound, floor);
    const double exact = candidate_distance(a, b, c, sphere);
    EXPECT_LE(c.lower_bound, exact * (1 + 1e-9)) << "frame " << c.frame << ", turn " << c.rotation;
  }
  EXPECT_GT(abandoned, 0) << "a test where some candidate is dropped by its bound";
}

}  // namespace

TEST(Distance, TheExactTurnSearchIsCertifiedByLowerBoundsThatHold) {
  const Shape a = distance::prepare_shape(bumped_disk(10, 0.3, 0.1, 0.7), "a", small_quadrature());
  const Shape b = distance::prepare_shape(bumped_disk(10, -0.25, 0.2, 0.6), "b", small_quadrature());
  expect_certified_search(a, b, false, 2);
}

TEST(Distance, TheExactFrameSearchOnTheSphereIsCertifiedByLowerBoundsThatHold) {
  ShapeOptions o = small_quadrature();
  o.sphere = true;
  // Two ellipsoids with a bump each, placed off their axes: no symmetry makes the frame's
  // sign choices tie.
  mesh::TriMesh p = mesh::make_icosphere(3), q = p;
  const Eigen::RowVector3d at_p = Eigen::RowVector3d(1, 0.6, 0.8).normalized(), at_q = Eigen::RowVector3d(-0.5, 1, 0.3).normalized();
  for (int v = 0; v < p.num_vertices(); ++v) {
    const Eigen::RowVector3d x = p.V.row(v), e = x.cwiseProduct(Eigen::RowVector3d(1.6, 1.0, 0.7));
    p.V.row(v) = e * (1 + 0.3 * std::exp(-8 * (1 - x.dot(at_p))));
    q.V.row(v) = e * (1 + 0.3 * std::exp(-8 * (1 - x.dot(at_q))));
  }
  const Shape P = distance::prepare_shape(p, "p", o), Q = distance::prepare_shape(q, "q", o);
  expect_certified_search(P, Q, true, 4);
}

TEST(Distance, MarkersFixTheTurnAndMustBeGivenForBoth) {
  ShapeOptions marked = small_quadrature();
  const mesh::TriMesh m = bumped_disk(8, 0.3, 0.1, 0.5);
  marked.center_vertex = 0;
  marked.boundary_vertex = m.num_vertices() - 1;  // the outer ring is the boundary
  const Shape a = distance::prepare_shape(m, "a", marked);
  const Shape b = distance::prepare_shape(bumped_disk(8, -0.2, 0.1, 0.5), "b", marked);
  const Shape c = distance::prepare_shape(m, "c", small_quadrature());
  EXPECT_TRUE(a.markers);
  const distance::PairResult r = distance::wasserstein(a, b);
  EXPECT_EQ(r.rotation, 0.0);
  EXPECT_NE(r.normalization.find("markers"), std::string::npos);
  EXPECT_ERROR(distance::omt_linear(a, c), ErrorCode::kInvalidArgument, "'a' and 'c': give markers for both shapes or for neither");
  ShapeOptions half = small_quadrature();
  half.center_vertex = 0;
  EXPECT_ERROR(distance::prepare_shape(m, "d", half), ErrorCode::kInvalidArgument, "d: give both markers (an interior and a boundary vertex) or neither");
}

TEST(Distance, HalfTurnsPermuteTheSphereQuadrature) {
  distance::Quadrature q;
  q.rings = 7;
  q.angles = 10;
  const auto X = q.sphere_points();
  const Eigen::Vector3d flips[4] = {{1, 1, 1}, {1, -1, -1}, {-1, 1, -1}, {-1, -1, 1}};
  EXPECT_NEAR(X.rowwise().norm().maxCoeff(), 1.0, 1e-15);
  for (int g = 0; g < 4; ++g) {
    const std::vector<int> to = distance::sphere_half_turn(g, q);
    std::set<int> image(to.begin(), to.end());
    EXPECT_EQ(image.size(), to.size()) << "a permutation";
    for (int k = 0; k < static_cast<int>(to.size()); ++k)
      EXPECT_LT((X.row(to[k]).transpose() - flips[g].cwiseProduct(X.row(k).transpose())).norm(), 1e-12) << g << " " << k;
  }
  q.angles = 9;
  EXPECT_ERROR(distance::sphere_half_turn(1, q), ErrorCode::kInvalidArgument, "sphere_half_turn: axis 0..3 and an even number of angles");
}

TEST(Distance, OnTheSphereARotatedCopyIsAtDistanceZero) {
  ShapeOptions o = small_quadrature();
  o.sphere = true;
  mesh::TriMesh a = mesh::make_icosphere(3);
  for (int v = 0; v < a.num_vertices(); ++v) a.V.row(v) = a.V.row(v).cwiseProduct(Eigen::RowVector3d(1.6, 1.0, 0.7));
  mesh::TriMesh b = a;
  const Eigen::Matrix3d R = Eigen::AngleAxisd(2.0, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  b.V = (a.V * R.transpose()).eval();
  const Shape A = distance::prepare_shape(a, "a", o), B = distance::prepare_shape(b, "b", o);
  EXPECT_LT(distance::omt_linear(A, B).distance, 1e-6);
  EXPECT_EQ(distance::omt_linear(A, A).distance, 0.0);
  // The exact distance (squared chordal cost): 0 to itself exactly (the quantization is the
  // same transport), near 0 to its turned copy, the same both ways round.
  const distance::PairResult self = distance::wasserstein(A, A);
  ASSERT_TRUE(self.converged);
  EXPECT_EQ(self.distance, 0.0);
  const distance::PairResult ab = distance::wasserstein(A, B), ba = distance::wasserstein(B, A);
  ASSERT_TRUE(ab.converged && ba.converged);
  EXPECT_LT(ab.distance, 1e-3);
  EXPECT_NEAR(ab.distance, ba.distance, 1e-9);
  EXPECT_TRUE(ab.normalization.find("chordal") != std::string::npos) << ab.normalization;
  EXPECT_ERROR(distance::prepare_shape(mesh::make_disk(6), "disk", o), ErrorCode::kInvalidArgument, "the sphere domain needs a closed genus-0 surface but the mesh is a sur");
}

TEST(Distance, OnTheSphereTheExactDistanceSeparatesShapes) {
  // An ellipsoid, a copy with a bump, and a sphere: the bumped copy is nearer the ellipsoid
  // than the sphere is, the distance is symmetric to round-off, and the triangle inequality
  // holds on the three.
  ShapeOptions o = small_quadrature();
  o.sphere = true;
  mesh::TriMesh e = mesh::make_icosphere(3), bump = e, ball = e;
  for (int v = 0; v < e.num_vertices(); ++v) {
    e.V.row(v) = e.V.row(v).cwiseProduct(Eigen::RowVector3d(1.6, 1.0, 0.7));
    const double z = ball.V(v, 2);
    bump.V.row(v) = e.V.row(v) * (1 + 0.25 * std::exp(-8 * (1 - z)));
  }
  const Shape E = distance::prepare_shape(e, "ellipsoid", o), P = distance::prepare_shape(bump, "bumped", o),
              S = distance::prepare_shape(ball, "ball", o);
  const double ep = distance::wasserstein(E, P).distance, es = distance::wasserstein(E, S).distance,
               ps = distance::wasserstein(P, S).distance;
  EXPECT_GT(ep, 1e-3);
  EXPECT_LT(ep, es);
  EXPECT_NEAR(distance::wasserstein(S, E).distance, es, 1e-9);
  EXPECT_LE(es, ep + ps + 1e-9);
  EXPECT_LE(ep, es + ps + 1e-9);
  EXPECT_LE(ps, ep + es + 1e-9);
}

TEST(Distance, ClosedSurfacesAreRefusedOnTheDisk) {
  EXPECT_ERROR(distance::prepare_shape(mesh::make_icosphere(2), "ball", small_quadrature()), ErrorCode::kInvalidArgument, "the disk domain needs a topological disk but the mesh is a closed genu");
}

TEST(Distance, CacheFilesReadBackExactlyAndRejectDamage) {
  const Shape a = distance::prepare_shape(bumped_disk(8, 0.3, 0.1, 0.5), "a", small_quadrature());
  const std::string dir = ::testing::TempDir() + "brenier-cache-test";
  std::filesystem::create_directories(dir);
  const std::string path = dir + "/" + a.key + ".shape";
  distance::save_shape(a, path);
  Shape b;
  ASSERT_TRUE(distance::load_shape(path, b));
  EXPECT_EQ(b.key, a.key);
  EXPECT_EQ(b.quantization, a.quantization);
  EXPECT_EQ(b.quantization_h.size(), a.sites.rows());  // the disk's quantization heights
  EXPECT_TRUE(b.quantization_h == a.quantization_h);
  EXPECT_TRUE(b.sites == a.sites && b.mass == a.mass && b.tri == a.tri && b.density == a.density && b.h == a.h &&
              b.samples == a.samples && b.spectrum == a.spectrum);
  // Truncated, or not a cache file at all: not loaded (the shape is then computed again).
  const auto size = std::filesystem::file_size(path);
  std::filesystem::resize_file(path, size - 5);
  EXPECT_FALSE(distance::load_shape(path, b));
  std::ofstream(path) << "OFF\n";
  EXPECT_FALSE(distance::load_shape(path, b));
  EXPECT_FALSE(distance::load_shape(dir + "/missing.shape", b));
  std::filesystem::remove_all(dir);
}

TEST(Distance, MergedSphereSitesAreRadiusApartAndEveryVertexWithinRadiusOfItsSite) {
  // Points on the unit sphere, with clusters planted far below the radius (as a conformal
  // sphere map crowds a protrusion) and pairs straddling grid cells.
  std::mt19937 rng(23);
  std::normal_distribution<double> g;
  const double radius = 1e-5;
  std::vector<Eigen::Vector3d> p;
  for (int k = 0; k < 2000; ++k) p.push_back(test::draw3(g, rng).normalized());
  for (int c = 0; c < 50; ++c) {
    const Eigen::Vector3d centre = p[c];
    for (int k = 0; k < 20; ++k)
      p.push_back((centre + 3e-6 * test::draw3(g, rng) / std::sqrt(3.0)).normalized());
  }
  omt::Points3 X(static_cast<Eigen::Index>(p.size()), 3);
  for (size_t k = 0; k < p.size(); ++k) X.row(static_cast<Eigen::Index>(k)) = p[k].transpose();
  std::vector<int> site_of;
  const omt::Points3 S = distance::merge_sphere_sites(X, radius, site_of);
  ASSERT_EQ(site_of.size(), p.size());
  EXPECT_LT(S.rows(), X.rows() - 500);  // most planted points joined their centre's site
  EXPECT_GE(S.rows(), 2000);
  for (Eigen::Index v = 0; v < X.rows(); ++v) EXPECT_LT((X.row(v) - S.row(site_of[v])).norm(), radius);
  double closest = 1;
  for (Eigen::Index i = 0; i < S.rows(); ++i)
    for (Eigen::Index j = i + 1; j < S.rows(); ++j) closest = std::min(closest, (S.row(i) - S.row(j)).norm());
  EXPECT_GE(closest, radius);
  // Radius 0: every vertex its own site.
  EXPECT_EQ(distance::merge_sphere_sites(X, 0, site_of).rows(), X.rows());
  EXPECT_ERROR(distance::merge_sphere_sites(X, -1, site_of), ErrorCode::kInvalidArgument, "merge radius");
  EXPECT_ERROR(distance::merge_sphere_sites(X, 1e-300, site_of), ErrorCode::kInvalidArgument, "merge radius");
}

TEST(Distance, TheDensityCapSpreadsAPeaksExcessOverTheRingAroundIt) {
  // The octahedron's eight faces, each of image area a: face 0 (corners +x, +y, +z) carries
  // 3 cap a, the others 0.1 cap a. Its excess 2 cap a goes to the three faces across its
  // edges, which have 0.9 cap a of room each (2.7 cap a): each gets 2 / 2.7 of its room.
  // The bound: from face 0's first corner (+x), its own corners lie within sqrt 2, the
  // ring's within 2 (-x).
  mesh::Vertices X(6, 3);
  X << 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1;
  mesh::Faces F(8, 3);
  F << 0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5;
  const Eigen::VectorXd image = mesh::face_areas(F, X);
  const double a = image[0], cap = 10;
  Eigen::VectorXd mass = Eigen::VectorXd::Constant(8, 0.1 * cap * a);
  mass[0] = 3 * cap * a;
  const double total = mass.sum();
  const distance::DensityCap r = distance::cap_density(F, X, image, cap, mass);
  EXPECT_NEAR(mass.sum(), total, 1e-12 * total);
  EXPECT_NEAR(mass[0], cap * a, 1e-12);
  for (int f : {1, 3, 4}) EXPECT_NEAR(mass[f], (0.1 + 0.9 * 2 / 2.7) * cap * a, 1e-12) << f;  // across face 0's edges
  for (int f : {2, 5, 6, 7}) EXPECT_NEAR(mass[f], 0.1 * cap * a, 1e-12) << f;
  EXPECT_NEAR(r.moved, 2 * cap * a / total, 1e-12);
  EXPECT_NEAR(r.shift, std::sqrt(2.0) + 2, 1e-12);
  // Nothing over the cap: nothing moves.
  Eigen::VectorXd flat = Eigen::VectorXd::Constant(8, cap * a);
  const distance::DensityCap none = distance::cap_density(F, X, image, cap, flat);
  EXPECT_EQ(none.moved, 0.0);
  EXPECT_EQ(none.shift, 0.0);
  EXPECT_TRUE((flat.array() == cap * a).all());
}

TEST(Distance, SphereShapesWithMergedSitesTransportAndReadBackExactly) {
  // An icosphere merged at a radius above some of its edges: fewer sites than vertices, the
  // masses added; the shape transports onto itself at distance 0, its cache file reads back.
  ShapeOptions o = small_quadrature();
  o.sphere = true;
  o.merge_radius = 0.2;  // large enough to merge neighbours of a coarse sphere
  const mesh::TriMesh m = mesh::make_icosphere(3);
  const Shape a = distance::prepare_shape(m, "merged", o);
  EXPECT_GT(a.merged_vertices, 0);
  EXPECT_EQ(a.sphere_sites.rows() + a.merged_vertices, a.vertices);
  EXPECT_EQ(a.sphere_vertices.rows(), a.vertices);
  EXPECT_LE(a.merge_shift, 0.2);
  EXPECT_NEAR(a.mass.sum(), 4 * kPi, 1e-9);
  const distance::PairResult self = distance::wasserstein(a, a);
  EXPECT_TRUE(self.converged);
  EXPECT_EQ(self.distance, 0.0);
  const std::string dir = ::testing::TempDir() + "brenier-sphere-cache-test";
  std::filesystem::create_directories(dir);
  const std::string path = dir + "/" + a.key + ".shape";
  distance::save_shape(a, path);
  Shape b;
  ASSERT_TRUE(distance::load_shape(path, b));
  EXPECT_TRUE(b.sphere_sites == a.sphere_sites && b.sphere_vertices == a.sphere_vertices && b.mass == a.mass &&
              b.merged_vertices == a.merged_vertices && b.merge_shift == a.merge_shift);
  EXPECT_EQ(distance::wasserstein(a, b).distance, 0.0);
  std::filesystem::remove_all(dir);
}

TEST(Matrix, TilesCoverEveryPairOnceInOrder) {
  for (int n = 2; n <= 13; ++n)
    for (int k = 1; k <= 7; ++k) {
      std::vector<std::pair<int, int>> all;
      for (int t = 0; t < k; ++t) {
        const auto part = distance::tile_pairs(n, {t, k});
        all.insert(all.end(), part.begin(), part.end());
      }
      ASSERT_EQ(all.size(), static_cast<size_t>(n * (n - 1) / 2)) << n << " " << k;
      size_t at = 0;
      for (int i = 0; i < n; ++i)
        for (int j = i + 1; j < n; ++j, ++at) EXPECT_EQ(all[at], std::make_pair(i, j));
    }
  EXPECT_EQ(distance::parse_tile("2/5").index, 2);
  for (const char* bad : {"5/5", "-1/3", "1/0", "a/b", "1/2/3", "1"}) EXPECT_ERROR(distance::parse_tile(bad), ErrorCode::kInvalidArgument, "expected I/K with 0 <= I < K") << bad;
}

TEST(Matrix, TilesFromAnyThreadCountAssembleToTheSameMatrix) {
  std::vector<distance::ShapeInput> in;
  const double bumps[4][3] = {{0.3, 0.1, 0.5}, {-0.2, 0.3, 0.8}, {0.0, -0.4, 0.3}, {0.1, 0.1, -0.6}};
  for (int k = 0; k < 4; ++k)
    in.push_back({"s" + std::to_string(k), bumped_disk(8, bumps[k][0], bumps[k][1], bumps[k][2]), small_quadrature()});
  distance::MatrixOptions opt;
  opt.method = distance::Method::kWasserstein;
  opt.jobs = 2;
  const Eigen::MatrixXd whole = distance::assemble({distance::compute_tile(in, opt)});
  std::vector<distance::MatrixTile> tiles;
  opt.jobs = 1;
  for (int t = 2; t >= 0; --t) {
    opt.tile = {t, 3};
    tiles.push_back(distance::compute_tile(in, opt));
  }
  const Eigen::MatrixXd merged = distance::assemble(tiles);
  EXPECT_TRUE(merged == whole) << "bit-identical";
  EXPECT_TRUE(whole == whole.transpose());
  EXPECT_TRUE((whole.diagonal().array() == 0).all());
  tiles.pop_back();
  EXPECT_ERROR(distance::assemble(tiles), ErrorCode::kInvalidArgument, "tile 0/3 is missing");
}

TEST(Analysis, MdsRecoversPlanarPointsUpToARigidMotion) {
  std::mt19937 rng(3);
  std::normal_distribution<double> N(0, 1);
  const int n = 9;
  Eigen::MatrixXd X(n, 2);
  for (int i = 0; i < n; ++i) X.row(i) << N(rng), N(rng);
  Eigen::MatrixXd D(n, n);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) D(i, j) = (X.row(i) - X.row(j)).norm();
  const distance::Embedding e = distance::classical_mds(D, 2);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) EXPECT_NEAR((e.coordinates.row(i) - e.coordinates.row(j)).norm(), D(i, j), 1e-9);
  EXPECT_NEAR(e.captured, 1.0, 1e-12);
  EXPECT_LT(e.negative, 1e-12);
  EXPECT_ERROR(distance::classical_mds(D, 0), ErrorCode::kInvalidArgument, "MDS: dimensions must lie in [1, 9]");
}

TEST(Analysis, KnnVotesByTheNearestAndCountsFolds) {
  // Points on a line: 0, 1, 2 labelled a; 10, 11, 12 labelled b; 6.2 labelled a, nearer 10
  // (b, 3.8 away) than 2 (a, 4.2 away).
  const std::vector<double> x = {0, 1, 2, 10, 11, 12, 6.2};
  const std::vector<std::string> labels = {"a", "a", "a", "b", "b", "b", "a"};
  const int n = static_cast<int>(x.size());
  Eigen::MatrixXd D(n, n);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) D(i, j) = std::abs(x[i] - x[j]);
  const distance::KnnResult r = distance::knn_classify(D, labels, 1, 0);
  EXPECT_EQ(r.correct, 6);
  EXPECT_EQ(r.predicted[6], "b");
  // k = 2: one vote each; the tie goes to the label of the nearest.
  EXPECT_EQ(distance::knn_classify(D, labels, 2, 0).predicted[6], "b");
  EXPECT_EQ(distance::knn_classify(D, labels, 3, 0).predicted[0], "a");
  const distance::KnnResult f = distance::knn_classify(D, labels, 1, 2);
  EXPECT_EQ(f.total, n);
  EXPECT_ERROR(distance::knn_classify(D, labels, 0, 0), ErrorCode::kInvalidArgument, "k-NN: k must be at least 1");
  EXPECT_ERROR(distance::knn_classify(D, labels, 1, 1), ErrorCode::kInvalidArgument, "k-NN: folds must be 0 (leave-one-out) or in [2, n]");
}

// Sites outside a convex domain whose Voronoi cells miss it: the solver starts from the
// sites pulled toward the domain instead of refusing them.
TEST(Omt, SitesOutsideTheDomainStartFromAPulledInDiagram) {
  omt::Points sites(5, 2);
  sites << 0, 0, 1.5, 0, 3, 0, 0, 1.5, 0, 3;  // (3, 0) and (0, 3) hide behind the others
  const Eigen::VectorXd nu = Eigen::VectorXd::Constant(5, 1.0);
  const omt::OmtResult r = omt::solve_omt(omt::Domain::square(1.0), sites, nu);
  ASSERT_TRUE(r.converged);
  for (int i = 0; i < 5; ++i) EXPECT_NEAR(r.cells.mass[i], 4.0 / 5, 1e-7);
}

namespace {

// A sphere shape's exact-distance source alone: the icosphere's flat triangles with density
// `contrast` on the faces within `radius` (radians) of +z and 1 elsewhere.
Shape peaked_source(int level, double radius, double contrast) {
  const mesh::TriMesh m = mesh::make_icosphere(level);
  auto surface = std::make_shared<omt::SurfaceDensity>();
  surface->vertices = m.V;
  surface->faces = m.F;
  surface->density = Eigen::VectorXd::Ones(m.num_faces());
  for (int f = 0; f < m.num_faces(); ++f) {
    const Eigen::RowVector3d c = (m.V.row(m.F(f, 0)) + m.V.row(m.F(f, 1)) + m.V.row(m.F(f, 2))).normalized();
    if (std::acos(std::min(1.0, c.z())) < radius) surface->density[f] = contrast;
  }
  Shape s;
  s.name = "peak";
  s.sphere = true;
  s.surface = surface;
  return s;
}

// A sphere shape's sites alone: n random unit vectors of equal mass.
Shape random_sites(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g;
  Shape s;
  s.name = "sites";
  s.sphere = true;
  s.sphere_sites.resize(n, 3);
  for (int i = 0; i < n; ++i) s.sphere_sites.row(i) = test::draw3(g, rng).normalized().transpose();
  s.mass = Eigen::VectorXd::Constant(n, 4 * kPi / n);
  return s;
}

}  // namespace

// The retry of transport_cost_sphere: 1,000 sites into a density whose peak (1e4 on the
// faces within 0.1 rad of +z: 96 % of the mass on 0.25 % of the sphere) stalls the damped
// Newton steps, as bear's sites into dino's density did. The retry holds the peak to a tenth,
// converges, and says so: the cap, and a W2 shift that is the distance cap_density moved the
// mass (positive, at most the sphere's diameter). Its cost is the transport of exactly that
// lowered density, solved on its own. A transport that converges at once is not retried.
TEST(Distance, ASphereTransportThatStallsIsSolvedAgainAtALowerCapAndSaysSo) {
  const Shape src = peaked_source(3, 0.1, 1e4), dst = random_sites(1000, 7);
  Eigen::VectorXd h;
  const distance::TransportCost c = distance::transport_cost_sphere(src, dst, Eigen::Vector3d::Ones(), {}, h);
  ASSERT_TRUE(c.converged) << c.failure;
  EXPECT_DOUBLE_EQ(c.density_cap, 1e3);
  EXPECT_GT(c.density_shift, 0);
  EXPECT_LE(c.density_shift, 2);
  EXPECT_EQ(h.size(), 1000);

  const omt::SurfaceDensity& s = *src.surface;
  const Eigen::VectorXd image = mesh::face_areas(s.faces, s.vertices);
  Eigen::VectorXd mass = s.density.cwiseProduct(image);
  EXPECT_DOUBLE_EQ(distance::cap_density(s.faces, s.vertices, image, 1e3, mass).shift, c.density_shift);
  omt::SurfaceDensity lower = s;
  lower.density = mass.cwiseQuotient(image);
  omt::OmtOptions o;
  o.tolerance = 1e-8;
  o.multilevel = true;
  const omt::SurfaceOmtResult direct = omt::solve_surface_omt(lower, dst.sphere_sites, dst.mass, o);
  ASSERT_TRUE(direct.converged);
  EXPECT_NEAR(c.w2_squared, direct.dual_value, 1e-5 * direct.dual_value);

  Eigen::VectorXd h2;
  const distance::TransportCost easy =
      distance::transport_cost_sphere(peaked_source(3, 0.15, 1e2), dst, Eigen::Vector3d::Ones(), {}, h2);
  EXPECT_TRUE(easy.converged);
  EXPECT_EQ(easy.density_cap, 0);
  EXPECT_EQ(easy.density_shift, 0);
}

// OmtOptions::stall_window, which the retry above relies on to give up early: the same peak
// stops as stalled, not converged, after at least a window of fine iterations and well before
// the 200-iteration cap, and without the plain-start fallback (which crept the same way on
// dino x bear); the easy peak converges under the same window, unaffected.
TEST(Distance, ASurfaceTransportThatCreepsStopsAsStalledAfterItsWindow) {
  const Shape dst = random_sites(1000, 7);
  omt::OmtOptions o;
  o.tolerance = 1e-8;
  o.multilevel = true;
  o.stall_window = 60;
  const omt::SurfaceOmtResult r =
      omt::solve_surface_omt(*peaked_source(3, 0.1, 1e4).surface, dst.sphere_sites, dst.mass, o);
  EXPECT_TRUE(r.stalled);
  EXPECT_FALSE(r.converged);
  EXPECT_GT(r.levels, 1);  // stopped on the coarse-to-fine start: no fallback after it
  EXPECT_GE(r.iterations - r.coarse_iterations, 60);
  EXPECT_LT(r.iterations - r.coarse_iterations, 200);
  EXPECT_GT(r.max_relative_error, 1);

  const omt::SurfaceOmtResult easy =
      omt::solve_surface_omt(*peaked_source(3, 0.15, 1e2).surface, dst.sphere_sites, dst.mass, o);
  EXPECT_TRUE(easy.converged);
  EXPECT_FALSE(easy.stalled);
  EXPECT_LE(easy.max_relative_error, 1e-8);
}

namespace {

// A sphere shape with both parts of the exact distance: `density`'s source density, n random
// sites of equal mass, and `capped` as the capped mass its preparation reports
// (Shape::capped_mass); a one-point-per-band quadrature of equal samples (every frame alike).
Shape sphere_shape(const Shape& density, int n, unsigned seed, double capped, const std::string& name) {
  Shape s = random_sites(n, seed);
  s.name = name;
  s.surface = density.surface;
  s.capped_mass = capped;
  s.rings = 2;
  s.angles = 2;
  s.sphere_samples.setZero(4, 3);
  s.sphere_samples.col(2).setOnes();
  return s;
}

}  // namespace

// Issue 23: the sphere pair with one crowded density (dino x bear) is the transport from the
// other density alone, which converges at the shapes' own caps, where the crowded one
// stalls. Its value is that transport's, the other direction not solved; the order of the
// pair does not change it. Where the less crowded density stalls too, both directions are
// solved at the lowered caps, as before.
TEST(Distance, ASpherePairWithOneCrowdedDensityIsTheTransportFromTheOther) {
  const Shape peak = peaked_source(3, 0.1, 1e4), flat = peaked_source(3, 0.1, 1);
  const Shape crowded = sphere_shape(peak, 1000, 7, 0.3, "crowded"), plain = sphere_shape(flat, 1200, 8, 0, "plain");
  const distance::PairResult ab = distance::wasserstein(crowded, plain), ba = distance::wasserstein(plain, crowded);
  ASSERT_TRUE(ab.converged);
  ASSERT_TRUE(ba.converged);
  EXPECT_EQ(ab.source, 1);
  EXPECT_EQ(ba.source, 0);
  EXPECT_TRUE(std::isnan(ab.forward));
  EXPECT_EQ(ab.distance, ab.backward);
  EXPECT_EQ(ab.distance, ba.distance);
  EXPECT_EQ(ab.lowered_cap[0] + ab.lowered_cap[1], 0);
  EXPECT_NE(ab.normalization.find("one direction: plain's density onto crowded's sites"), std::string::npos)
      << ab.normalization;
  Eigen::VectorXd h;
  const distance::TransportCost direct = distance::transport_cost_sphere(plain, crowded, Eigen::Vector3d::Ones(), {}, h);
  ASSERT_TRUE(direct.converged);
  EXPECT_EQ(direct.density_cap, 0);
  EXPECT_DOUBLE_EQ(ab.distance, std::sqrt(direct.w2_squared));

  // Both crowded: the less crowded one's transport stalls at the own caps, and both
  // directions go to a tenth of the peaks side by side. The distance is the mean of those
  // that converge there, each the same transport as solved at that cap on its own (which of
  // the two converge depends on round-off: in Release only the one onto the sparser sites,
  // under the sanitizers' build both).
  const Shape other = sphere_shape(peak, 1200, 8, 0.2, "other");
  const distance::PairResult both = distance::wasserstein(crowded, other);
  ASSERT_TRUE(both.converged);
  Eigen::VectorXd h2, h3;
  const distance::TransportCost tenth[2] = {
      distance::transport_cost_sphere(crowded, other, Eigen::Vector3d::Ones(), {}, h2, {}, 1, 1),
      distance::transport_cost_sphere(other, crowded, Eigen::Vector3d::Ones(), {}, h3, {}, 1, 1)};
  ASSERT_TRUE(tenth[0].converged || tenth[1].converged);
  EXPECT_EQ(both.source, tenth[0].converged && tenth[1].converged ? -1 : tenth[0].converged ? 0 : 1);
  double mean = 0;
  const double value[2] = {both.forward, both.backward};
  for (int k = 0; k < 2; ++k) {
    EXPECT_EQ(std::isnan(value[k]), !tenth[k].converged);
    if (!tenth[k].converged) continue;
    EXPECT_DOUBLE_EQ(both.lowered_cap[k], 1e3);
    EXPECT_DOUBLE_EQ(value[k], std::sqrt(tenth[k].w2_squared));
    mean += std::sqrt(tenth[k].w2_squared) / (tenth[0].converged + tenth[1].converged);
  }
  EXPECT_DOUBLE_EQ(both.distance, mean);
  if (both.source >= 0) {
    EXPECT_NE(both.normalization.find("the other did not converge at that lowered cap"), std::string::npos);
  }
}

namespace {

// A sphere density like a conformal map's crowded protrusion: the icosphere's vertices within
// `radius` of +z pulled towards it (angles times `squeeze`), the faces among them at
// `contrast` times the density elsewhere, scaled to mean 1.
Shape pinched_source(double radius, double squeeze, double contrast) {
  mesh::TriMesh m = mesh::make_icosphere(3);
  std::vector<bool> inside(m.V.rows());
  for (int v = 0; v < m.V.rows(); ++v) {
    const double t = std::acos(std::min(1.0, m.V(v, 2))), u = t * squeeze, p = std::atan2(m.V(v, 1), m.V(v, 0));
    inside[v] = t < radius;
    if (inside[v]) m.V.row(v) << std::sin(u) * std::cos(p), std::sin(u) * std::sin(p), std::cos(u);
  }
  Shape s = peaked_source(3, 0, 1);
  s.name = "pinched";
  auto surface = std::make_shared<omt::SurfaceDensity>(*s.surface);
  surface->vertices = m.V;
  for (int f = 0; f < m.num_faces(); ++f)
    if (inside[m.F(f, 0)] && inside[m.F(f, 1)] && inside[m.F(f, 2)]) surface->density[f] = contrast;
  const Eigen::VectorXd image = mesh::face_areas(m.F, m.V);
  surface->density /= surface->density.dot(image) / image.sum();
  s.surface = surface;
  return s;
}

}  // namespace

// Issue 23's third cap (sphere_cap): a density whose peak is over 1e4 times its mean (man-
// deformed's is 62,157 times) still stalls at a hundredth of its peak: here contrast 1e8 on the
// pinched faces (1.2e-6 of the image's area), a peak 794,000 times the mean, whose hundredth is
// 79 times the mean cap. Its transport converges only at 100 times the mean, and says so
// (measured: at the own density, the tenth and the hundredth the worst cell ends 219-496x off). A uniform density has
// no cap below its peak that leaves room for its mass: no level runs, and none throws.
TEST(Distance, ASphereDensityFarAboveItsMeanIsSolvedAtAHundredTimesTheMean) {
  const Shape src = pinched_source(0.3, 0.01, 1e8), dst = random_sites(1000, 7);
  const Eigen::VectorXd& density = src.surface->density;
  const Eigen::VectorXd image = mesh::face_areas(src.surface->faces, src.surface->vertices);
  const double mean = density.dot(image) / image.sum();
  ASSERT_NEAR(mean, 1, 1e-12);
  ASSERT_GT(density.maxCoeff(), 1e4 * mean);
  EXPECT_DOUBLE_EQ(distance::sphere_cap(src, 2), density.maxCoeff() / 100);
  EXPECT_DOUBLE_EQ(distance::sphere_cap(src, 3), 100 * mean);
  Eigen::VectorXd h;
  const distance::TransportCost c = distance::transport_cost_sphere(src, dst, Eigen::Vector3d::Ones(), {}, h);
  ASSERT_TRUE(c.converged) << c.failure;
  EXPECT_DOUBLE_EQ(c.density_cap, 100 * mean);  // levels 0-2 did not converge
  EXPECT_GT(c.density_shift, 0);
  EXPECT_LE(c.density_shift, 2);
  EXPECT_EQ(h.size(), 1000);

  const Shape flat = peaked_source(3, 0, 1);
  for (int level = 1; level <= distance::kLowestCapLevel; ++level) EXPECT_EQ(distance::sphere_cap(flat, level), 0);
  Eigen::VectorXd h2;
  const distance::TransportCost none =
      distance::transport_cost_sphere(flat, dst, Eigen::Vector3d::Ones(), {}, h2, {}, 1, distance::kLowestCapLevel);
  EXPECT_FALSE(none.converged);
  EXPECT_EQ(none.iterations, 0);
}

// A pair that converges at no cap still reports both directions (PairSolver::sphere): where a
// level runs one direction only (the other's density has no cap below its peak that leaves
// room for its mass, sphere_cap 0), the one left out keeps its dual from the level before,
// and the pair's lower bound is the mean of the two. Here a flat density (no cap at any
// level) and the pinched one, with a transport tolerance that round-off cannot reach and no
// dual-gap stop: the
// flat density's direction runs at its own density only (the less crowded one goes first),
// the pinched one's alone at each lowered cap.
TEST(Distance, ASpherePairConvergingAtNoCapReportsBothDirectionsDuals) {
  Shape plain = sphere_shape(peaked_source(3, 0, 1), 300, 8, 0, "plain");
  Shape crowded = sphere_shape(pinched_source(0.3, 0.01, 1e8), 250, 7, 0.3, "crowded");
  plain.transport_tolerance = crowded.transport_tolerance = 1e-300;
  plain.cost_tolerance = crowded.cost_tolerance = 0;  // (nor the dual gap's stop)
  distance::WassersteinOptions o;
  o.debias = false;
  const distance::PairResult r = distance::wasserstein(plain, crowded, o);
  EXPECT_FALSE(r.converged);
  EXPECT_TRUE(std::isnan(r.distance));
  EXPECT_EQ(r.source, -1);
  ASSERT_FALSE(std::isnan(r.forward));
  ASSERT_FALSE(std::isnan(r.backward));
  // The flat density's dual is its own transport's at its own density, as solved alone.
  Eigen::VectorXd h;
  const distance::TransportCost alone = distance::transport_cost_sphere(plain, crowded, Eigen::Vector3d::Ones(), {}, h,
                                                                        {}, 0, 0);
  EXPECT_FALSE(alone.converged);
  EXPECT_DOUBLE_EQ(r.forward, std::sqrt(std::max(0.0, alone.w2_squared)));
  EXPECT_EQ(r.lowered_cap[0], 0);
  EXPECT_NEAR(r.lowered_cap[1], 100, 1e-9);  // the pinched density's last cap: 100 times its mean 1
  ASSERT_EQ(r.candidates.size(), 1u);
  EXPECT_DOUBLE_EQ(r.candidates[0].lower_bound, (r.forward + r.backward) / 2);
}

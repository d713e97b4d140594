// The bijection g between parameter domains (Alg. 7 step 2) by continuation of constrained
// harmonic maps; see domain_match.hpp for the construction.
#include "register/domain_match.hpp"

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <Eigen/SparseCore>
#include <Eigen/SparseLU>
#include <algorithm>
#include <cmath>
#include <complex>
#include <functional>

#include "common/error.hpp"
#include "conformal/conformal_map.hpp"
#include "conformal/mobius.hpp"
#include "mesh/topology.hpp"
#include "omt/fold_repair.hpp"

namespace brenier::registration {

Eigen::Matrix3d best_rotation(const std::vector<Eigen::Vector3d>& p, const std::vector<Eigen::Vector3d>& q) {
  if (p.empty()) return Eigen::Matrix3d::Identity();
  if (p.size() == 1) return Eigen::Quaterniond::FromTwoVectors(p[0], q[0]).toRotationMatrix();
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < p.size(); ++i) H += p[i] * q[i].transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1 : 1;
  return svd.matrixV() * D * svd.matrixU().transpose();
}

Eigen::Matrix3d landmark_rotation(const mesh::Vertices& source, const std::vector<int>& source_landmarks,
                                  const mesh::Vertices& target, const std::vector<int>& target_landmarks) {
  std::vector<Eigen::Vector3d> p, q;
  for (size_t k = 0; k < source_landmarks.size() && k < target_landmarks.size(); ++k) {
    p.push_back(source.row(source_landmarks[k]).transpose());
    q.push_back(target.row(target_landmarks[k]).transpose());
  }
  return best_rotation(p, q);
}

namespace {

using V2 = Eigen::Vector2d;
constexpr double kTwoPi = 2 * M_PI;

double cross(const V2& a, const V2& b) { return a.x() * b.y() - a.y() * b.x(); }

// Angle wrapped into (-pi, pi].
double wrap_pi(double a) {
  a = std::fmod(a + M_PI, kTwoPi);
  if (a < 0) a += kTwoPi;
  return a - M_PI;
}

// A monotone piecewise-linear map of the circle's angle through (source, target) knots,
// increasing, covering one turn from knots[0].first; no knots: the identity.
struct CircleMap {
  std::vector<std::pair<double, double>> knots;
  double operator()(double x) const {
    if (knots.empty()) return x;
    const double x0 = knots[0].first;
    const double xr = x0 + std::fmod(std::fmod(x - x0, kTwoPi) + kTwoPi, kTwoPi);
    for (size_t i = 0; i < knots.size(); ++i) {
      const auto& a = knots[i];
      const std::pair<double, double> b =
          i + 1 < knots.size() ? knots[i + 1] : std::make_pair(knots[0].first + kTwoPi, knots[0].second + kTwoPi);
      if (xr <= b.first) {
        const double f = (xr - a.first) / std::max(1e-300, b.first - a.first);
        return a.second + f * (b.second - a.second) - (xr - x);
      }
    }
    return x;
  }
};

// Landmarks the continuation cannot carry unfolded from one start (the message names them).
struct Refused {
  std::string message;
};

// Refuses the landmarks nearest a fold (`distance` from it, one per name).
[[noreturn]] void refuse_nearest(const std::vector<std::string>& names, const std::vector<double>& distance) {
  if (names.size() < 2)
    throw Refused{"landmark " + (names.empty() ? std::string("?") : names[0]) +
                  " cannot be moved onto its target without folding the mesh"};
  std::vector<size_t> order(names.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return distance[a] < distance[b]; });
  throw Refused{"landmarks " + names[order[0]] + " and " + names[order[1]] +
                " cannot be matched without folding the mesh between them (they pass each other or move too far "
                "for the mesh's resolution); drop or move one of them"};
}

// The continuation of harmonic maps on a planar mesh: `moving` vertices follow `path`
// (landmarks and, on the disk, the boundary), the other fixed ones stay, the free ones are
// the discrete harmonic map of each step with the mean value weights of the last.
struct Continuation {
  const mesh::Faces& F;
  std::vector<V2> X;
  std::vector<char> fixed;     // Dirichlet vertices
  std::vector<char> skip_face; // faces left out of the fold check (a corner at the pole)
  std::vector<int> moving;     // fixed vertices that move with t
  std::function<V2(int v, double t)> path;
  std::vector<int> landmark_vertex;  // the interior landmarks' vertices
  std::vector<std::string> landmark_name;
  std::vector<char> skip_vertex;     // never moved (the pole)
  double radius = 1;                 // the spline steps vanish on and beyond this circle
  bool squared_cut = false;
  // Faces that become slivers on the way may turn over (mended afterwards; see spheres_from).
  bool let_slivers_turn = false;
  static constexpr double kSliver = 1e-2;

  double sign(const std::vector<V2>& Y, Eigen::Index f) const {
    const V2 &a = Y[static_cast<size_t>(F(f, 0))], &b = Y[static_cast<size_t>(F(f, 1))], &c = Y[static_cast<size_t>(F(f, 2))];
    return cross(b - a, c - a);
  }

  // The harmonic map with the fixed vertices at Y's places, weights from X. False when the
  // solve fails.
  bool harmonic(std::vector<V2>& Y) const {
    const size_t n = X.size();
    std::vector<int> index(n, -1);
    int m = 0;
    for (size_t v = 0; v < n; ++v)
      if (!fixed[v]) index[v] = m++;
    if (m == 0) return true;
    std::vector<Eigen::Triplet<double>> trip;
    Eigen::MatrixX2d rhs = Eigen::MatrixX2d::Zero(m, 2);
    Eigen::VectorXd diag = Eigen::VectorXd::Zero(m);
    for (Eigen::Index f = 0; f < F.rows(); ++f) {
      for (int k = 0; k < 3; ++k) {
        const int i = F(f, k), j = F(f, (k + 1) % 3), l = F(f, (k + 2) % 3);
        if (index[static_cast<size_t>(i)] < 0) continue;
        const V2 e1 = X[static_cast<size_t>(j)] - X[static_cast<size_t>(i)], e2 = X[static_cast<size_t>(l)] - X[static_cast<size_t>(i)];
        const double angle = std::atan2(std::abs(cross(e1, e2)), e1.dot(e2));
        const double tn = std::tan(angle / 2);
        for (const auto& [o, len] : {std::make_pair(j, e1.norm()), std::make_pair(l, e2.norm())}) {
          const double w = tn / std::max(len, 1e-300);
          const int row = index[static_cast<size_t>(i)], col = index[static_cast<size_t>(o)];
          diag[row] += w;
          if (col >= 0) trip.emplace_back(row, col, -w);
          else rhs.row(row) += w * Y[static_cast<size_t>(o)].transpose();
        }
      }
    }
    for (int r = 0; r < m; ++r) trip.emplace_back(r, r, diag[r]);
    Eigen::SparseMatrix<double> A(m, m);
    A.setFromTriplets(trip.begin(), trip.end());
    Eigen::SparseLU<Eigen::SparseMatrix<double>> lu;
    lu.compute(A);
    if (lu.info() != Eigen::Success) return false;
    const Eigen::MatrixX2d x = lu.solve(rhs);
    if (lu.info() != Eigen::Success || !x.allFinite()) return false;
    for (size_t v = 0; v < n; ++v)
      if (index[v] >= 0) Y[v] = x.row(index[v]).transpose();
    return true;
  }

  [[noreturn]] void refuse(Eigen::Index bad_face) const {
    const V2 y = bad_face >= 0 ? X[static_cast<size_t>(F(bad_face, 0))] : V2::Zero();
    std::vector<double> distance;
    for (int v : landmark_vertex) distance.push_back((X[static_cast<size_t>(v)] - y).norm());
    refuse_nearest(landmark_name, distance);
  }

  // The landmarks' current places.
  std::vector<V2> landmark_places(const std::vector<V2>& Y) const {
    std::vector<V2> c;
    for (int v : landmark_vertex) c.push_back(Y[static_cast<size_t>(v)]);
    return c;
  }

  // One step of the interior landmarks from their places in X to `goal`: the displacement
  // d(x) = cut(x) s(x), s the thin-plate spline (r^2 log r plus an affine part) through the
  // landmarks' displacements over cut, cut = 1 - |x|^2 / radius^2 (squared on the sphere's
  // plane for a C1 join) vanishing on the circle: smooth, exact at the landmarks, zero on and
  // beyond the circle.
  void spline_step(const std::vector<V2>& goal, std::vector<V2>& Y) const {
    const std::vector<V2> c = landmark_places(X);
    const size_t L = c.size();
    auto cut = [&](const V2& x) {
      const double u = 1 - x.squaredNorm() / (radius * radius);
      if (u <= 0) return 0.0;
      return squared_cut ? u * u : u;
    };
    auto phi = [](double r) { return r > 0 ? r * r * std::log(r) : 0.0; };
    Eigen::MatrixXd A = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(L + 3), static_cast<Eigen::Index>(L + 3));
    Eigen::MatrixX2d b = Eigen::MatrixX2d::Zero(static_cast<Eigen::Index>(L + 3), 2);
    for (size_t i = 0; i < L; ++i) {
      for (size_t j = 0; j < L; ++j) A(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(j)) = phi((c[i] - c[j]).norm());
      const auto r = static_cast<Eigen::Index>(i), e = static_cast<Eigen::Index>(L);
      A(r, e) = A(e, r) = 1;
      A(r, e + 1) = A(e + 1, r) = c[i].x();
      A(r, e + 2) = A(e + 2, r) = c[i].y();
      b.row(r) = ((goal[i] - c[i]) / cut(c[i])).transpose();
    }
    const Eigen::MatrixX2d w = A.fullPivLu().solve(b);
    Y = X;
#pragma omp parallel for schedule(static)
    for (long v = 0; v < static_cast<long>(X.size()); ++v) {
      const V2 x = X[static_cast<size_t>(v)];
      const double k = cut(x);
      if (k <= 0 || skip_vertex[static_cast<size_t>(v)]) continue;
      V2 s = w.row(static_cast<Eigen::Index>(L)).transpose() + w(static_cast<Eigen::Index>(L + 1), 0) * V2(x.x(), 0) +
             w(static_cast<Eigen::Index>(L + 1), 1) * V2(0, x.x()) + w(static_cast<Eigen::Index>(L + 2), 0) * V2(x.y(), 0) +
             w(static_cast<Eigen::Index>(L + 2), 1) * V2(0, x.y());
      for (size_t i = 0; i < L; ++i) s += phi((x - c[i]).norm()) * w.row(static_cast<Eigen::Index>(i)).transpose();
      Y[static_cast<size_t>(v)] = x + k * s;
    }
    for (size_t i = 0; i < L; ++i) Y[static_cast<size_t>(landmark_vertex[i])] = goal[i];  // exact
  }

  // Whether face f is thinner than kSliver of its longest edge at the places Y (twice its
  // area below kSliver times the longest edge squared).
  bool sliver(const std::vector<V2>& Y, Eigen::Index f) const {
    double longest = 0;
    for (int k = 0; k < 3; ++k)
      longest = std::max(longest, (Y[static_cast<size_t>(F(f, k))] - Y[static_cast<size_t>(F(f, (k + 1) % 3))]).squaredNorm());
    return std::abs(sign(Y, f)) < kSliver * longest;
  }

  // The first face that a step from X to Y turns over, -1 for none. Faces whose sign0 is 0
  // (slivers at the start, a corner at the pole) are not checked; with let_slivers_turn, nor
  // are faces that are slivers at X or already turned there.
  Eigen::Index first_fold(const std::vector<double>& sign0, const std::vector<V2>& Y) const {
    for (Eigen::Index f = 0; f < F.rows(); ++f) {
      const double s0 = sign0[static_cast<size_t>(f)];
      if (s0 == 0 || s0 * sign(Y, f) > 0) continue;
      if (let_slivers_turn && (!(s0 * sign(X, f) > 0) || sliver(X, f))) continue;
      return f;
    }
    return -1;
  }

  // Moves the boundary (`moving_boundary`, to path(v, 1)) with the interior following as a
  // Tutte embedding with the mesh's mean value weights (Floater: no fold, the boundary being
  // convex), then the interior landmarks from their places to `targets` by spline steps,
  // halved until no face folds. Returns the steps taken.
  int run(const std::vector<V2>& targets) {
    std::vector<double> sign0(static_cast<size_t>(F.rows()));
    for (Eigen::Index f = 0; f < F.rows(); ++f) sign0[static_cast<size_t>(f)] = skip_face[static_cast<size_t>(f)] ? 0 : sign(X, f);
    // Slivers (height below kSliver of the longest edge) are left out of the fold test of the
    // landmark steps: any displacement that is not affine across one turns it over long
    // before the mesh around it folds. The OMT centroid maps have them where three cell
    // centroids fall nearly in line (bear's sphere map: edges 0.07, 0.11, 0.18, height 1e-4;
    // every one of its pairs was refused for such a face, with the landmarks 0.02 from their
    // targets). The caller mends the ones that turned (mend_folds) or refuses.
    for (Eigen::Index f = 0; f < F.rows(); ++f)
      if (sliver(X, f)) sign0[static_cast<size_t>(f)] = 0;
    int steps = 0;
    if (!moving.empty()) {
      std::vector<V2> Y = X;
      for (int v : moving) Y[static_cast<size_t>(v)] = path(v, 1);
      if (!harmonic(Y) || first_fold(sign0, Y) >= 0)
        fail(ErrorCode::kInternal, "the boundary landmarks' Tutte step folded the mesh");
      X.swap(Y);
      ++steps;
    }
    if (landmark_vertex.empty()) return steps;
    const std::vector<V2> start = landmark_places(X);
    double t = 0, dt = 1;
    std::vector<V2> Y, goal(start.size());
    while (t < 1) {
      const double t1 = std::min(1.0, t + dt);
      for (size_t i = 0; i < start.size(); ++i) goal[i] = (1 - t1) * start[i] + t1 * targets[i];
      spline_step(goal, Y);
      const Eigen::Index bad = first_fold(sign0, Y);
      if (bad < 0) {
        X.swap(Y);
        t = t1;
        ++steps;
        dt = std::min(1.0, 2 * dt);
        continue;
      }
      dt /= 2;
      if (dt < 1e-6) refuse(bad);
    }
    return steps;
  }
};

// The folds of g's map after its continuation (Continuation::run let slivers turn over, or
// the steps left some), unfolded with the landmarks and `fixed` held: on the disk by local
// moves (conformal::untangle: a corner mirrored across its opposite edge, or a Tutte step);
// on the sphere by omt::unfold_sphere_map, whose barrier untangling runs against the faces'
// own shapes before the mend. On cow's area-preserving domains the local moves left 2-4
// folds that the barrier mended (bench/RESULTS.md, session 68). A fold that stays is
// refused, naming the landmarks nearest it. Returns the faces that were folded before.
int mend_folds(const mesh::Faces& faces, mesh::Vertices& mapped, bool sphere, std::vector<char> fixed,
               const std::vector<LandmarkPair>& landmarks) {
  const mesh::TriMesh m{mapped, faces};
  int before = 0;
  for (int f = 0; f < m.num_faces(); ++f) before += conformal::face_folded(m, mapped, f, sphere);
  if (before == 0) return 0;
  for (const auto& l : landmarks) fixed[static_cast<size_t>(l.vertex)] = 1;
  int left = 0;
  if (sphere) {
    omt::SphereUnfold how;
    how.scope = {fixed, /*bound_distortion=*/false};
    left = omt::unfold_sphere_map(m, mapped, how).folds;
  } else {
    conformal::untangle(m, mapped, false, fixed, left);
  }
  if (left == 0) return before;
  int f = 0;
  while (f < m.num_faces() && !conformal::face_folded(m, mapped, f, sphere)) ++f;
  if (f == m.num_faces()) return before;  // the counts use the same test; kept so a change there cannot read past F
  std::vector<std::string> names;
  std::vector<double> distance;
  for (const auto& l : landmarks) {
    names.push_back(l.name);
    distance.push_back((mapped.row(l.vertex) - mapped.row(m.F(f, 0))).norm());
  }
  refuse_nearest(names, distance);
}

// Levenberg-Marquardt on a handful of parameters, the Jacobian by central differences. A trial
// point outside `feasible` counts as a failed step. Returns the best point found.
Eigen::VectorXd levenberg_marquardt(const std::function<Eigen::VectorXd(const Eigen::VectorXd&)>& residual,
                                    Eigen::VectorXd x, const std::function<bool(const Eigen::VectorXd&)>& feasible) {
  Eigen::VectorXd r = residual(x);
  double cost = r.squaredNorm(), lambda = 1e-3;
  for (int it = 0; it < 200 && cost > 0; ++it) {
    Eigen::MatrixXd J(r.size(), x.size());
    for (Eigen::Index k = 0; k < x.size(); ++k) {
      Eigen::VectorXd xp = x, xm = x;
      xp[k] += 1e-7;
      xm[k] -= 1e-7;
      J.col(k) = (residual(xp) - residual(xm)) / 2e-7;
    }
    const Eigen::MatrixXd A = J.transpose() * J;
    const Eigen::VectorXd g = J.transpose() * r;
    bool improved = false;
    for (; lambda < 1e10 && !improved; lambda *= 4) {
      Eigen::MatrixXd M = A;
      M.diagonal() += lambda * (A.diagonal().array() + 1e-12).matrix();
      const Eigen::VectorXd y = x - M.ldlt().solve(g);
      if (!y.allFinite() || !feasible(y)) continue;
      const Eigen::VectorXd ry = residual(y);
      if (ry.squaredNorm() < cost) {
        const double gain = cost - ry.squaredNorm();
        x = y, r = ry, cost = ry.squaredNorm(), improved = true;
        if (gain <= 1e-14 * (1 + cost)) return x;
      }
    }
    if (!improved) break;
    lambda = std::max(lambda / 16, 1e-12);
  }
  return x;
}

// Applies `map` (a Moebius start whose automorphism point is scaled by s) to every point,
// halving s until no face turns over (a Moebius map is a bijection of the domain, but a
// straight triangle's image can still turn over where the map bends hard). Returns s, 0 when
// only the plain turn (s = 0) leaves every face as it was. Faces are read by
// conformal::face_folded, from the edge vectors: det(a, b, c) of the points themselves is
// round-off on the tiny faces of a conformal sphere map. Faces folded before are not checked.
double unfolded_start(const mesh::Vertices& points, const mesh::Faces& F, bool sphere,
                      const std::function<mesh::Vertices(double s)>& map, mesh::Vertices& out) {
  const mesh::TriMesh faces{mesh::Vertices(), F};
  std::vector<char> was_folded(static_cast<size_t>(F.rows()));
  for (int f = 0; f < faces.num_faces(); ++f) was_folded[static_cast<size_t>(f)] = conformal::face_folded(faces, points, f, sphere);
  for (double s = 1; s > 1e-3; s /= 2) {
    out = map(s);
    bool folded = false;
    for (int f = 0; f < faces.num_faces() && !folded; ++f)
      folded = !was_folded[static_cast<size_t>(f)] && conformal::face_folded(faces, out, f, sphere);
    if (!folded) return s;
  }
  out = map(0);
  return 0;
}

double start_rms(const mesh::Vertices& X, const std::vector<LandmarkPair>& l) {
  double sum = 0;
  for (const auto& x : l) sum += (X.row(x.vertex).transpose() - x.q).squaredNorm();
  return l.empty() ? 0.0 : std::sqrt(sum / static_cast<double>(l.size()));
}

void check_distinct(const std::vector<LandmarkPair>& l, double eps) {
  for (size_t i = 0; i < l.size(); ++i)
    for (size_t j = i + 1; j < l.size(); ++j) {
      if (l[i].vertex == l[j].vertex)
        invalid("landmarks " + l[i].name + " and " + l[j].name + " are at one place on the source");
      if ((l[i].q - l[j].q).norm() <= eps)
        invalid("landmarks " + l[i].name + " and " + l[j].name + " are at one place on the target");
    }
}

void check_vertices(const std::vector<LandmarkPair>& l, Eigen::Index n) {
  for (const auto& x : l)
    if (x.vertex < 0 || x.vertex >= n) invalid("landmark " + x.name + " is not a vertex of the source's domain mesh");
}

DomainMatch disks_from(const mesh::Vertices& points, const mesh::Faces& faces, const std::vector<LandmarkPair>& landmarks,
                       MatchStart start) {
  const std::vector<char> boundary = mesh::boundary_flags(mesh::TriMesh{points, faces});
  DomainMatch out;
  using C = std::complex<double>;
  std::vector<C> p, q;
  for (const auto& l : landmarks) {
    p.emplace_back(points(l.vertex, 0), points(l.vertex, 1));
    q.emplace_back(l.q.x(), l.q.y());
  }
  // The landmarks after z -> T_a(z) = (z - a) / (1 - conj(a) z), and the least-squares turn of
  // those onto the q's: the angle of sum conj(T_a(p_k)) q_k.
  auto moved = [&](C a) {
    std::vector<C> w;
    for (const C& z : p) w.push_back(conformal::disk_automorphism(z, a));
    return w;
  };
  auto turn_of = [&](const std::vector<C>& w) {
    C sum = 0;
    for (size_t k = 0; k < w.size(); ++k) sum += std::conj(w[k]) * q[k];
    return std::abs(sum) > 1e-12 ? std::arg(sum) : 0.0;
  };
  C a = 0;
  if (start == MatchStart::kMobius && landmarks.size() >= 3) {
    // a by Levenberg-Marquardt, the turn projected out (the best one for each a).
    auto residual = [&](const Eigen::VectorXd& x) {
      const std::vector<C> w = moved(C(x[0], x[1]));
      const C rot = std::polar(1.0, turn_of(w));
      Eigen::VectorXd r(2 * static_cast<Eigen::Index>(w.size()));
      for (size_t k = 0; k < w.size(); ++k) {
        const C e = rot * w[k] - q[k];
        r[2 * static_cast<Eigen::Index>(k)] = e.real(), r[2 * static_cast<Eigen::Index>(k) + 1] = e.imag();
      }
      return r;
    };
    const Eigen::VectorXd x = levenberg_marquardt(residual, Eigen::Vector2d::Zero(), [](const Eigen::VectorXd& y) { return y.norm() <= 0.9; });
    a = C(x[0], x[1]);
  }
  mesh::Vertices started;
  const double scale = unfolded_start(points, faces, false, [&](double s) {
    mesh::UV uv = points.leftCols(2);
    conformal::apply_disk_mobius(uv, s * a, turn_of(moved(s * a)));
    mesh::Vertices y = mesh::Vertices::Zero(points.rows(), 3);
    y.leftCols(2) = uv;
    for (Eigen::Index i = 0; i < y.rows(); ++i)
      if (boundary[static_cast<size_t>(i)]) y.row(i).normalize();  // exactly on the circle
    return y;
  }, started);
  out.rotation_angle = turn_of(moved(scale * a));
  out.start = start;
  out.mobius_a = Eigen::Vector3d((scale * a).real(), (scale * a).imag(), 0);
  out.start_rms = start_rms(started, landmarks);

  Continuation c{faces, {}, {}, {}, {}, {}, {}, {}, {}, 1.0, false};
  c.X.resize(static_cast<size_t>(points.rows()));
  c.skip_vertex.assign(static_cast<size_t>(points.rows()), 0);
  for (Eigen::Index i = 0; i < points.rows(); ++i) c.X[static_cast<size_t>(i)] = started.row(i).head<2>().transpose();
  c.fixed = boundary;
  c.skip_face.assign(static_cast<size_t>(faces.rows()), 0);

  std::vector<std::pair<double, double>> knots;
  std::string boundary_names;
  std::vector<V2> from(static_cast<size_t>(points.rows())), targets;
  for (const auto& l : landmarks) {
    const bool pb = boundary[static_cast<size_t>(l.vertex)];
    if (pb != l.q_on_boundary)
      invalid("landmark " + l.name + " lies on the " + (pb ? "source's boundary and inside the target" : "target's boundary and inside the source") +
              ": a homeomorphism of the disk keeps the boundary on the boundary");
    const V2 p = c.X[static_cast<size_t>(l.vertex)], q = l.q.head<2>();
    if (pb) {
      knots.emplace_back(std::atan2(p.y(), p.x()), std::atan2(q.y(), q.x()));
      boundary_names += (boundary_names.empty() ? "" : ", ") + l.name;
      continue;
    }
    if (q.norm() >= 1 - 1e-12) invalid("landmark " + l.name + " is an interior vertex mapped onto the disk's boundary");
    targets.push_back(q);
    c.landmark_vertex.push_back(l.vertex);
    c.landmark_name.push_back(l.name);
  }
  // Boundary landmarks: psi through the knots, which must keep their order around the circle.
  CircleMap psi;
  if (!knots.empty()) {
    std::sort(knots.begin(), knots.end());
    double total = 0;
    psi.knots.emplace_back(knots[0].first, knots[0].first + wrap_pi(knots[0].second - knots[0].first));
    for (size_t i = 1; i <= knots.size(); ++i) {
      double d = std::fmod(knots[i % knots.size()].second - knots[i - 1].second, kTwoPi);
      if (d <= 0) d += kTwoPi;
      total += d;
      if (i < knots.size()) psi.knots.emplace_back(knots[i].first, psi.knots.back().second + d);
    }
    if (knots.size() > 1 && std::abs(total - kTwoPi) > 1e-6)
      invalid("boundary landmarks " + boundary_names +
              " lie in a different order around the target's boundary than around the source's: no homeomorphism of "
              "the disk matches them");
    for (Eigen::Index v = 0; v < points.rows(); ++v)
      if (boundary[static_cast<size_t>(v)]) {
        const V2 x = c.X[static_cast<size_t>(v)];
        const double a = std::atan2(x.y(), x.x());
        from[static_cast<size_t>(v)] = V2(a, psi(a));  // angles at t = 0 and 1
        c.moving.push_back(static_cast<int>(v));
      }
  }
  c.path = [&](int v, double t) {
    const V2 ang = from[static_cast<size_t>(v)];
    const double a = ang.x() + t * (ang.y() - ang.x()), r = c.X[static_cast<size_t>(v)].norm();
    return V2(r * std::cos(a), r * std::sin(a));
  };
  out.steps = c.run(targets);
  out.mapped = mesh::Vertices::Zero(points.rows(), 3);
  for (Eigen::Index i = 0; i < points.rows(); ++i) out.mapped.row(i).head<2>() = c.X[static_cast<size_t>(i)].transpose();
  out.mended_faces = mend_folds(faces, out.mapped, false, boundary, landmarks);
  for (const auto& l : landmarks)
    out.max_landmark_error = std::max(out.max_landmark_error, (out.mapped.row(l.vertex).transpose() - Eigen::Vector3d(l.q.x(), l.q.y(), 0)).norm());
  return out;
}

// A direction far from every point (the largest smallest angle among 4,000 spiral samples).
Eigen::Vector3d far_direction(const std::vector<Eigen::Vector3d>& pts) {
  const int n = 4000;
  Eigen::Vector3d best = Eigen::Vector3d::UnitZ();
  double best_d = -2;
  for (int i = 0; i < n; ++i) {
    const double z = 1 - (2 * i + 1.0) / n, r = std::sqrt(1 - z * z), ph = i * M_PI * (3 - std::sqrt(5.0));
    const Eigen::Vector3d d(r * std::cos(ph), r * std::sin(ph), z);
    double nearest = 2;
    for (const auto& p : pts) nearest = std::min(nearest, 1 - d.dot(p));
    if (nearest > best_d) best_d = nearest, best = d;
  }
  return best;
}

V2 stereo(const Eigen::Vector3d& x) { return x.head<2>() / (1 - x.z()); }
Eigen::Vector3d unstereo(const V2& y) {
  const double s = y.squaredNorm();
  return Eigen::Vector3d(2 * y.x(), 2 * y.y(), s - 1) / (s + 1);
}

DomainMatch spheres_from(const mesh::Vertices& points, const mesh::Faces& faces, const std::vector<LandmarkPair>& landmarks,
                         MatchStart start, bool let_slivers_turn) {
  DomainMatch out;
  out.slivers_let_turn = let_slivers_turn;
  std::vector<Eigen::Vector3d> p, q;
  for (const auto& l : landmarks) {
    p.push_back(points.row(l.vertex).transpose().normalized());
    q.push_back(l.q.normalized());
  }
  // The landmarks after the ball's automorphism T_a, the rotation by Kabsch after it.
  auto moved = [&](const Eigen::Vector3d& a) {
    std::vector<Eigen::Vector3d> w;
    for (const auto& x : p) w.push_back(conformal::sphere_automorphism(x, a));
    return w;
  };
  Eigen::Vector3d a = Eigen::Vector3d::Zero();
  if (start == MatchStart::kMobius && landmarks.size() >= 3) {
    auto residual = [&](const Eigen::VectorXd& x) {
      const std::vector<Eigen::Vector3d> w = moved(x);
      const Eigen::Matrix3d R = best_rotation(w, q);
      Eigen::VectorXd r(3 * static_cast<Eigen::Index>(w.size()));
      for (size_t k = 0; k < w.size(); ++k) r.segment<3>(3 * static_cast<Eigen::Index>(k)) = R * w[k] - q[k];
      return r;
    };
    a = levenberg_marquardt(residual, Eigen::Vector3d::Zero(), [](const Eigen::VectorXd& y) { return y.norm() <= 0.9; });
  }
  const double scale = unfolded_start(points, faces, true, [&](double s) {
    const Eigen::Matrix3d R = best_rotation(moved(s * a), q);
    mesh::Vertices y(points.rows(), 3);
    for (Eigen::Index i = 0; i < y.rows(); ++i)
      y.row(i) = (R * conformal::sphere_automorphism(points.row(i).transpose().normalized(), s * a)).transpose();
    return y;
  }, out.mapped);
  out.start = start;
  out.mobius_a = scale * a;
  out.start_rms = start_rms(out.mapped, landmarks);
  const std::vector<Eigen::Vector3d> p0 = moved(out.mobius_a);
  const Eigen::Matrix3d R = best_rotation(p0, q);
  out.rotation_angle = Eigen::AngleAxisd(R).angle();
  if (landmarks.size() >= 2) {
    // The steps in the stereographic plane seen from a pole far from the landmarks.
    std::vector<Eigen::Vector3d> seen;
    for (size_t k = 0; k < p.size(); ++k) seen.push_back(R * p0[k]), seen.push_back(q[k]);
    const Eigen::Vector3d pole = far_direction(seen);
    const Eigen::Matrix3d Q = Eigen::Quaterniond::FromTwoVectors(pole, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    const size_t n = static_cast<size_t>(points.rows());
    Continuation c{faces, std::vector<V2>(n), std::vector<char>(n, 1), std::vector<char>(static_cast<size_t>(faces.rows()), 0),
                   {}, {}, {}, {}, std::vector<char>(n, 0), 1.0, true};
    std::vector<char> finite(n, 0);
    std::vector<V2> targets;
    double max_r = 0;
    for (size_t k = 0; k < p.size(); ++k) {
      const V2 from = stereo(Q * R * p0[k]), to = stereo(Q * q[k]);
      max_r = std::max({max_r, from.norm(), to.norm()});
      targets.push_back(to);
      c.landmark_vertex.push_back(landmarks[k].vertex);
      c.landmark_name.push_back(landmarks[k].name);
    }
    // The steps vanish beyond a circle twice as wide as every landmark path.
    c.radius = 2 * std::max(max_r, 1e-3);
    for (size_t i = 0; i < n; ++i) {
      const Eigen::Vector3d y = Q * out.mapped.row(static_cast<Eigen::Index>(i)).transpose();
      if (1 - y.z() > 1e-9) {
        c.X[i] = stereo(y);
        finite[i] = 1;
      } else {
        c.skip_vertex[i] = 1;  // the pole: never moved
      }
    }
    for (Eigen::Index f = 0; f < faces.rows(); ++f)
      for (int k = 0; k < 3; ++k)
        if (!finite[static_cast<size_t>(faces(f, k))]) c.skip_face[static_cast<size_t>(f)] = 1;
    c.let_slivers_turn = let_slivers_turn;
    out.steps = c.run(targets);
    for (size_t i = 0; i < n; ++i)
      if (finite[i])
        out.mapped.row(static_cast<Eigen::Index>(i)) = (Q.transpose() * unstereo(c.X[i])).transpose();
    out.mended_faces = mend_folds(faces, out.mapped, true, c.skip_vertex, landmarks);
  }
  for (size_t k = 0; k < landmarks.size(); ++k)
    out.max_landmark_error = std::max(out.max_landmark_error, (out.mapped.row(landmarks[k].vertex).transpose() - q[k]).norm());
  return out;
}

// The match from `start`; where the landmarks cannot be carried unfolded from it, from the
// other start (a Moebius map fits the landmarks closer than a turn, so it can leave shorter
// paths; a turn bends the mesh less where the domains differ by more than a Moebius map).
// With `lenient`, both starts again with slivers let turn on the way (`from`'s second
// argument). Refused by every try: the first one's reason.
DomainMatch with_fallback(MatchStart start, size_t landmarks, bool lenient,
                          const std::function<DomainMatch(MatchStart, bool)>& from) {
  const MatchStart other = start == MatchStart::kMobius ? MatchStart::kRotation : MatchStart::kMobius;
  std::vector<std::pair<MatchStart, bool>> tries{{start, false}};
  if (landmarks >= 3) tries.emplace_back(other, false);  // below three landmarks both starts are the turn
  if (lenient) {
    tries.emplace_back(start, true);
    if (landmarks >= 3) tries.emplace_back(other, true);
  }
  std::string first;
  for (const auto& [s, l] : tries) {
    try {
      return from(s, l);
    } catch (const Refused& refused) {
      if (first.empty()) first = refused.message;
    }
  }
  invalid(first);
}

}  // namespace

DomainMatch match_disks(const mesh::Vertices& points, const mesh::Faces& faces, const std::vector<LandmarkPair>& landmarks,
                        MatchStart start) {
  check_vertices(landmarks, points.rows());
  check_distinct(landmarks, 1e-12);
  return with_fallback(start, landmarks.size(), false,
                       [&](MatchStart s, bool) { return disks_from(points, faces, landmarks, s); });
}

DomainMatch match_spheres(const mesh::Vertices& points, const mesh::Faces& faces, const std::vector<LandmarkPair>& landmarks,
                          MatchStart start) {
  check_vertices(landmarks, points.rows());
  check_distinct(landmarks, 1e-12);
  return with_fallback(start, landmarks.size(), true, [&](MatchStart s, bool let_slivers_turn) {
    return spheres_from(points, faces, landmarks, s, let_slivers_turn);
  });
}

}  // namespace brenier::registration

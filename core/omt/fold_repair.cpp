#include "omt/fold_repair.hpp"

#include <Eigen/Geometry>
#include <LBFGS.h>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>

#include "common/error.hpp"
#include "conformal/conformal_map.hpp"
#include "conformal/mobius.hpp"
#include "mesh/geometry.hpp"
#include "omt/barrier_energy.hpp"
#include "quality/quality.hpp"

namespace brenier::omt {
using detail::BarrierFace;
using detail::barrier_face;

namespace {

// One face's term of the energy of fold_repair.hpp, a [theta (D^2 + 1) + (1 - theta) |J|_F^2]
// / chi(D, eps), for the Jacobian J = M ref_inv of its edge matrix M (chord edges on the
// sphere, chart edges in the plane) and its area ratio D; sets its derivatives in D and in M.
template <int Rows>
double barrier_term(const BarrierFace& f, const Eigen::Matrix<double, Rows, 2>& M, double D, double theta,
                    double eps, double& dE_dD, Eigen::Matrix<double, Rows, 2>& dE_dM) {
  const Eigen::Matrix<double, Rows, 2> J = M * f.ref_inv;
  const double T = J.squaredNorm();
  const double s = std::sqrt(eps * eps + D * D), chi = 0.5 * (D + s), dchi = 0.5 * (1 + D / s);
  const double num = theta * (D * D + 1) + (1 - theta) * T;
  dE_dD = f.weight * (theta * 2 * D / chi - num * dchi / (chi * chi));
  dE_dM = f.weight * (1 - theta) * 2 / chi * J * f.ref_inv.transpose();
  return f.weight * num / chi;
}

// The energy over the free vertices on the sphere, for L-BFGS. A free vertex is x = y / |y|
// for unknowns y in R^3, so every trial point lies on the sphere. The face's signed area
// is read as det(a, b, c) / 2 (the chord triangle's area times its plane's distance from
// the centre: positive exactly when it faces outward, the fold test), so
// D = det(a, b, c) / (2 A_target); |J|_F^2 is that of the chord triangle's edges against
// the reference's.
struct SphereBarrier {
  static constexpr int kDim = 3;
  const std::vector<BarrierFace>& faces;
  mesh::Vertices& X;
  const std::vector<int>& var;   // row of X -> its first unknown, or -1 when fixed
  const std::vector<int>& rows;  // the free rows, in the unknowns' order
  double theta, eps = 1;
  double min_det = 0;

  void load(const Eigen::VectorXd& y) {
    for (int r : rows) X.row(r) = y.segment<3>(var[r]).normalized().transpose();
  }
  Eigen::Vector3d at(int r) const { return X.row(r).transpose(); }
  bool facing(const BarrierFace& f) const { return at(f.v[0]).dot(at(f.v[1]).cross(at(f.v[2]))) > 0; }
  double operator()(const Eigen::VectorXd& y, Eigen::VectorXd& grad) {
    load(y);
    grad.setZero(y.size());
    Eigen::VectorXd gx = Eigen::VectorXd::Zero(y.size());  // gradient in x
    double E = 0;
    min_det = std::numeric_limits<double>::infinity();
    for (const BarrierFace& f : faces) {
      const Eigen::Vector3d a = at(f.v[0]), b = at(f.v[1]), c = at(f.v[2]);
      Eigen::Matrix<double, 3, 2> M, dM;
      M << b - a, c - a;
      const double D = a.dot(b.cross(c)) / (2 * f.weight);
      min_det = std::min(min_det, D);
      double dD;
      E += barrier_term(f, M, D, theta, eps, dD, dM);
      dD /= 2 * f.weight;
      auto add = [&](int row, const Eigen::Vector3d& d) {
        if (var[row] >= 0) gx.segment<3>(var[row]) += d;
      };
      add(f.v[0], dD * b.cross(c) - dM.col(0) - dM.col(1));
      add(f.v[1], dD * c.cross(a) + dM.col(0));
      add(f.v[2], dD * a.cross(b) + dM.col(1));
    }
    for (int r : rows) {  // through x = y / |y|: (I - x x^T) g / |y|
      const Eigen::Vector3d x = at(r), g = gx.segment<3>(var[r]);
      grad.segment<3>(var[r]) = (g - x * x.dot(g)) / y.segment<3>(var[r]).norm();
    }
    return E;
  }
};

// The same energy in a planar chart (rows of X are chart points, z = 0): D = det M / (2 A),
// positive exactly when the face turns counter-clockwise.
struct PlaneBarrier {
  static constexpr int kDim = 2;
  const std::vector<BarrierFace>& faces;
  mesh::Vertices& X;
  const std::vector<int>& var;
  const std::vector<int>& rows;
  double theta, eps = 1;
  double min_det = 0;

  void load(const Eigen::VectorXd& y) {
    for (int r : rows) X.row(r).head<2>() = y.segment<2>(var[r]).transpose();
  }
  Eigen::Vector2d at(int r) const { return X.row(r).head<2>().transpose(); }
  static double cross(const Eigen::Vector2d& u, const Eigen::Vector2d& w) { return u.x() * w.y() - u.y() * w.x(); }
  bool facing(const BarrierFace& f) const { return cross(at(f.v[1]) - at(f.v[0]), at(f.v[2]) - at(f.v[0])) > 0; }
  double operator()(const Eigen::VectorXd& y, Eigen::VectorXd& grad) {
    load(y);
    grad.setZero(y.size());
    double E = 0;
    min_det = std::numeric_limits<double>::infinity();
    for (const BarrierFace& f : faces) {
      const Eigen::Vector2d a = at(f.v[0]), b = at(f.v[1]), c = at(f.v[2]);
      Eigen::Matrix2d M, dM;
      M << b - a, c - a;
      const double D = cross(b - a, c - a) / (2 * f.weight);
      min_det = std::min(min_det, D);
      double dD;
      E += barrier_term(f, M, D, theta, eps, dD, dM);
      dD /= 2 * f.weight;
      // d cross(b - a, c - a) / db = perp(c - a), / dc = -perp(b - a), perp(u) = (u.y, -u.x)
      const Eigen::Vector2d db(c.y() - a.y(), a.x() - c.x()), dc(a.y() - b.y(), b.x() - a.x());
      auto add = [&](int row, const Eigen::Vector2d& d) {
        if (var[row] >= 0) grad.segment<2>(var[row]) += d;
      };
      add(f.v[0], -dD * (db + dc) - dM.col(0) - dM.col(1));
      add(f.v[1], dD * db + dM.col(0));
      add(f.v[2], dD * dc + dM.col(1));
    }
    return E;
  }
};

// Moves the rows of X with free[row] != 0 to minimize the energy over `faces` (on the unit
// sphere with SphereBarrier, in a plane with PlaneBarrier); theta weighs the area term.
// Returns the number of `faces` still folded (0 on success).
template <class Energy>
int untangle_by_barrier(const std::vector<BarrierFace>& faces, mesh::Vertices& X, const std::vector<char>& free,
                        double theta = 0.9) {
  constexpr int d = Energy::kDim;
  std::vector<int> var(X.rows(), -1), rows;
  int n = 0;
  for (Eigen::Index r = 0; r < X.rows(); ++r)
    if (free[r]) var[r] = n, n += d, rows.push_back(static_cast<int>(r));
  Energy energy{faces, X, var, rows, theta};
  Eigen::VectorXd y(n), grad(n);
  for (int r : rows) y.segment<d>(var[r]) = X.row(r).head<d>().transpose();
  energy.eps = 1;
  energy(y, grad);
  // eps from the smallest det J: chi(min det, eps) = mu, i.e. eps = 2 sqrt(mu (mu - min det)),
  // mu shrinking with the energy's relative decrease (the paper's schedule).
  auto eps_for = [](double mu, double det) { return det < mu ? 2 * std::sqrt(mu * (mu - det)) : 1e-12; };
  energy.eps = eps_for(0.1, energy.min_det);
  LBFGSpp::LBFGSParam<double> param;
  // Each round's L-BFGS also stops once an iteration lowers the energy by less than 1e-6 of
  // itself (`past`, `delta`): a round only has to bring the faces near its eps's minimum
  // before eps shrinks, and the gradient test alone ran most rounds to their 400 iterations
  // (camel's 10,911-vertex copy: 4,000-9,500 energy evaluations per region tried, 12 of its
  // vertices or 800). Camel's OMT-route registration went from 10-46 s to 11-32 s a pair and
  // cow's from 5.2 s to 1.2-2.8 s, with errors no worse (bench/RESULTS.md, session 69).
  param.epsilon = 1e-9;
  param.past = 1;
  param.delta = 1e-6;
  param.max_iterations = 400;
  param.max_linesearch = 40;
  std::vector<double> deepest;  // min det J after each round
  for (int outer = 0; outer < 60; ++outer) {
    const double E_prev = energy(y, grad);
    const Eigen::VectorXd y_prev = y;
    LBFGSpp::LBFGSSolver<double> solver(param);
    double fx = E_prev;
    try {
      solver.minimize(energy, y, fx);
    } catch (const std::exception&) {
      // A line search that cannot lower the energy further throws, with y left at its last
      // trial point, which may be worse than where it started (a face turned over with eps
      // tiny makes the energy infinite, or NaN): then y goes back.
      if (!(energy(y, grad) <= E_prev)) y = y_prev;
    }
    const double E = energy(y, grad);
    if (energy.min_det > 0 && outer > 0 && energy.eps < 1e-9) break;
    deepest.push_back(energy.min_det);
    if (detail::untangling_stalled(deepest, energy.eps)) break;
    const double sigma = std::max(1 - E / E_prev, 0.1);
    const double s = std::sqrt(energy.eps * energy.eps + energy.min_det * energy.min_det);
    const double mu = (1 - sigma) * 0.5 * (energy.min_det + s);
    energy.eps = eps_for(mu, energy.min_det);
  }
  energy(y, grad);
  int folds = 0;
  for (const BarrierFace& f : faces) folds += !energy.facing(f);
  return folds;
}

}  // namespace

namespace {

// The barrier repair of a sphere map's folds (repair_sphere_folds_by_barrier): regions of
// growing rings about each folded face untangled, each kept only if it lowers the folds
// without raising the area distortion and leaves the map covering the sphere once.
class SphereFoldRepair {
 public:
  SphereFoldRepair(const mesh::TriMesh& m, BarrierSpace space)
      : m_(m), space_(space), nv_(m.num_vertices()), nf_(m.num_faces()), area_(mesh::face_areas(m)), star_(nv_),
        ring_(nv_) {
    for (int f = 0; f < nf_; ++f)
      for (int k = 0; k < 3; ++k) {
        star_[m.F(f, k)].push_back(f);
        ring_[m.F(f, k)].push_back(m.F(f, (k + 1) % 3));
      }
  }

  // Vertices no region frees (a registration's landmarks).
  void hold(const std::vector<char>* held) { held_ = held; }

  // Target areas in the energy's measure det(a, b, c) / 2, whose sum is the map's.
  void set_scale(const mesh::Vertices& X) {
    double total = 0;
    for (int f = 0; f < nf_; ++f) total += 0.5 * X.row(m_.F(f, 0)).dot(X.row(m_.F(f, 1)).cross(X.row(m_.F(f, 2))));
    scale_ = total / area_.sum();
  }

  // The distance in edges from the seed face's corners, up to `max_rings` (-1 beyond).
  std::vector<int> rings_from(int seed, int max_rings) const {
    std::vector<int> dist(nv_, -1), queue;
    for (int k = 0; k < 3; ++k) dist[m_.F(seed, k)] = 0, queue.push_back(m_.F(seed, k));
    for (size_t q = 0; q < queue.size(); ++q)
      if (dist[queue[q]] < max_rings)
        for (int w : ring_[queue[q]])
          if (dist[w] < 0) dist[w] = dist[queue[q]] + 1, queue.push_back(w);
    return dist;
  }

  // The vertices within `rings` (free) and the faces around them.
  int region(const std::vector<int>& dist, int rings, std::vector<char>& is_free, std::vector<int>& faces) const {
    is_free.assign(nv_, 0);
    faces.clear();
    std::vector<char> seen(nf_, 0);
    int nfree = 0;
    for (int v = 0; v < nv_; ++v)
      if (dist[v] >= 0 && dist[v] <= rings && !(held_ && (*held_)[v])) {
        is_free[v] = 1, ++nfree;
        for (int f : star_[v])
          if (!seen[f]) seen[f] = 1, faces.push_back(f);
      }
    return nfree;
  }

  // Moves the free rows of Z over `faces` by the barrier untangling, on the sphere or in the
  // region's chart (whose areas are the sphere's times (1 + |z|^2)^2 / 4 at the face).
  void untangle(const std::vector<int>& faces, mesh::Vertices& Z, const std::vector<char>& free) const {
    if (space_ == BarrierSpace::kSphere) {
      std::vector<BarrierFace> ref;
      ref.reserve(faces.size());
      for (int f : faces) ref.push_back(reference(f, area_[f] * scale_));
      untangle_by_barrier<SphereBarrier>(ref, Z, free);
      return;
    }
    untangle_in_chart(faces, Z, free);
  }

 private:
  // The reference triangle of face f (m's shape) with target area a in the energy's measure.
  BarrierFace reference(int f, double a) const {
    return barrier_face(m_.F(f, 0), m_.F(f, 1), m_.F(f, 2), m_.V.row(m_.F(f, 0)), m_.V.row(m_.F(f, 1)),
                        m_.V.row(m_.F(f, 2)), a);
  }

  // The chart: the stereographic projection (conformal::stereographic) from the antipode of
  // the free vertices' centre, mirrored (conjugated) so that it keeps orientation: a face
  // turned outward on the sphere turns counter-clockwise in the plane. (The vertex farthest
  // from the seed in the mesh was tried as the pole too, for regions whose image spans a
  // hemisphere: dino came out with 5 folds instead of 2.)
  void untangle_in_chart(const std::vector<int>& faces, mesh::Vertices& Z, const std::vector<char>& free) const {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    for (int v = 0; v < nv_; ++v)
      if (free[v]) centre += Z.row(v).transpose();
    const Eigen::Matrix3d R =
        Eigen::Quaterniond::FromTwoVectors(-centre.normalized(), Eigen::Vector3d::UnitZ()).toRotationMatrix();
    mesh::Vertices P = mesh::Vertices::Zero(nv_, 3);
    for (int f : faces)
      for (int k = 0; k < 3; ++k) {
        const conformal::Complex z = std::conj(conformal::stereographic(R * Z.row(m_.F(f, k)).transpose()));
        P.row(m_.F(f, k)) << z.real(), z.imag(), 0;
      }
    std::vector<BarrierFace> ref;
    ref.reserve(faces.size());
    for (int f : faces) {
      const double r2 = ((P.row(m_.F(f, 0)) + P.row(m_.F(f, 1)) + P.row(m_.F(f, 2))) / 3).squaredNorm();
      ref.push_back(reference(f, area_[f] * scale_ * (1 + r2) * (1 + r2) / 4));
    }
    untangle_by_barrier<PlaneBarrier>(ref, P, free);
    for (int v = 0; v < nv_; ++v)
      if (free[v])
        Z.row(v) = (R.transpose() * conformal::inverse_stereographic(std::conj(conformal::Complex(P(v, 0), P(v, 1)))))
                       .transpose();
  }

  const mesh::TriMesh& m_;
  BarrierSpace space_;
  int nv_, nf_;
  Eigen::VectorXd area_;
  std::vector<std::vector<int>> star_, ring_;
  double scale_ = 1;
  const std::vector<char>* held_ = nullptr;
};

// What repair_sphere_folds_by_barrier's acceptance test reads of the map, kept face by face:
// whether the face is folded, its chord area (quality::area_log_ratios' measure) and its
// signed geodesic area (quality::sphere_degree's). A region's trial moves only the faces
// around its free vertices, so the folds, the degree and the mean |log area ratio| after it
// come from those faces' new values and the totals, not from three passes over the whole map
// with a logarithm and an arctangent per face after every trial (camel's bent pair: the
// repair's time outside the untangling 0.09 -> 0.02 s and 0.14 -> 0.03 s, the maps the same
// to the byte; bench/RESULTS.md, session 72).
class FaceTally {
 public:
  FaceTally(const mesh::TriMesh& m, const mesh::Vertices& X)
      : m_(m), nf_(m.num_faces()), folded_(nf_), area_(nf_), log_area_(nf_), solid_(nf_), log_target_(nf_) {
    const Eigen::VectorXd a = mesh::face_areas(m);
    const double total = a.sum();
    for (int f = 0; f < nf_; ++f) log_target_[f] = std::log(a[f] / total);
    for (int f = 0; f < nf_; ++f) measure(X, f, folded_[f], area_[f], log_area_[f], solid_[f]);
    folds_ = static_cast<int>(std::count(folded_.begin(), folded_.end(), 1));
    total_area_ = area_.sum();
    total_solid_ = solid_.sum();
  }

  int folds() const { return folds_; }
  bool folded(int f) const { return folded_[f] != 0; }
  double distortion() const { return distortion_with(log_area_, total_area_); }

  // The map with the faces `faces` measured on Z instead (every other face unchanged): its
  // folds, degree and chord area follow from those faces alone. Its mean |log area ratio|, a
  // sum over every face, is taken only when asked (distortion below).
  struct Trial {
    int folds;
    double total_area, total_solid;
    std::vector<char> folded;
    Eigen::VectorXd area, log_area, solid;
    double degree() const { return total_solid / (4 * std::numbers::pi); }
  };
  Trial trial(const std::vector<int>& faces, const mesh::Vertices& Z) const {
    Trial t{folds_, total_area_, total_solid_, {}, {}, {}, {}};
    const size_t n = faces.size();
    t.folded.resize(n);
    t.area.resize(static_cast<Eigen::Index>(n));
    t.log_area.resize(static_cast<Eigen::Index>(n));
    t.solid.resize(static_cast<Eigen::Index>(n));
    for (size_t i = 0; i < n; ++i) {
      const int f = faces[i];
      const auto e = static_cast<Eigen::Index>(i);
      measure(Z, f, t.folded[i], t.area[e], t.log_area[e], t.solid[e]);
      t.folds += t.folded[i] - folded_[f];
      t.total_area += t.area[e] - area_[f];
      t.total_solid += t.solid[e] - solid_[f];
    }
    return t;
  }
  // The mean |log area ratio| of the map with trial t on `faces` (each face once): the trial's
  // log areas stand in for the sum and the kept ones are put back, so the faces are summed in
  // the order of a measure of the whole map, without a copy of every face's value per trial.
  double distortion(const std::vector<int>& faces, const Trial& t) {
    Eigen::VectorXd kept(static_cast<Eigen::Index>(faces.size()));
    for (size_t i = 0; i < faces.size(); ++i) {
      const auto e = static_cast<Eigen::Index>(i);
      kept[e] = log_area_[faces[i]];
      log_area_[faces[i]] = t.log_area[e];
    }
    const double d = distortion_with(log_area_, t.total_area);
    for (size_t i = 0; i < faces.size(); ++i) log_area_[faces[i]] = kept[static_cast<Eigen::Index>(i)];
    return d;
  }
  void accept(const std::vector<int>& faces, const Trial& t) {
    for (size_t i = 0; i < faces.size(); ++i) {
      const int f = faces[i];
      const auto e = static_cast<Eigen::Index>(i);
      folded_[f] = t.folded[i], area_[f] = t.area[e], log_area_[f] = t.log_area[e], solid_[f] = t.solid[e];
    }
    folds_ = t.folds;
    total_area_ = t.total_area;
    total_solid_ = t.total_solid;
  }

 private:
  void measure(const mesh::Vertices& Z, int f, char& folded, double& area, double& log_area, double& solid) const {
    const Eigen::Vector3d a = Z.row(m_.F(f, 0)), b = Z.row(m_.F(f, 1)), c = Z.row(m_.F(f, 2));
    folded = conformal::face_folded(m_, Z, f, true);
    area = 0.5 * (b - a).cross(c - a).norm();
    log_area = std::log(area);
    solid = quality::geodesic_triangle_area(a, b, c);
  }
  // Mean |log((area_f / total) / target share_f)| over the faces.
  double distortion_with(const Eigen::VectorXd& log_area, double total) const {
    const double log_total = std::log(total);
    double sum = 0;
    for (int f = 0; f < nf_; ++f) sum += std::abs(log_area[f] - log_total - log_target_[f]);
    return sum / nf_;
  }

  const mesh::TriMesh& m_;
  int nf_;
  std::vector<char> folded_;
  Eigen::VectorXd area_, log_area_, solid_, log_target_;
  int folds_ = 0;
  double total_area_ = 0, total_solid_ = 0;
};

}  // namespace

int repair_sphere_folds_by_barrier(const mesh::TriMesh& m, mesh::Vertices& X, int& folded,
                                   const std::function<bool(int round, int folds)>& keep_going, BarrierSpace space,
                                   const BarrierRepairScope& scope) {
  const int nv = m.num_vertices(), nf = m.num_faces();
  if (!scope.held.empty() && static_cast<int>(scope.held.size()) != nv) invalid("the held vertices' flags are not one per vertex");
  SphereFoldRepair repair(m, space);
  if (!scope.held.empty()) repair.hold(&scope.held);
  FaceTally tally(m, X);
  folded = tally.folds();
  const double allowed = scope.bound_distortion ? tally.distortion() : std::numeric_limits<double>::infinity();
  repair.set_scale(X);
  int moved = 0;
  long work = 0;
  bool out_of_budget = false;
  std::vector<char> tried(nf, 0), is_free;
  std::vector<int> region_faces;
  for (int round = 0; round < nf && folded > 0 && !out_of_budget; ++round) {  // each face seeds once
    int seed = -1;
    for (int f = 0; f < nf && seed < 0; ++f)
      if (!tried[f] && tally.folded(f)) seed = f;
    if (seed < 0) break;
    if (keep_going && !keep_going(round, folded)) fail(ErrorCode::kCancelled, "fold repair cancelled");
    tried[seed] = 1;
    // The regions are the vertices within 1, 2, 4, 8 or 16 rings of the seed face.
    constexpr int kMaxRings = 16;
    const std::vector<int> dist = repair.rings_from(seed, kMaxRings);
    int last_free = -1;
    for (int rings : {1, 2, 4, 8, kMaxRings}) {
      const int nfree = repair.region(dist, rings, is_free, region_faces);
      if (nfree == last_free) break;  // the whole component is free already
      last_free = nfree;
      // A budget of free vertices untangled, all clusters and tries together: a map the
      // repair can mend takes well under one pass over its vertices (bull 0.9 nv,
      // armadillo 0.4 nv, camel 0.3 nv), while one it cannot kept man's going for minutes.
      if (work + nfree > 2L * nv + 1000) {
        out_of_budget = true;
        break;
      }
      work += nfree;
      mesh::Vertices back = X;
      repair.untangle(region_faces, back, is_free);
      if (!back.allFinite()) continue;
      // Only the region's faces moved (FaceTally).
      const FaceTally::Trial t = tally.trial(region_faces, back);
      // A region untangled inside a fixed ring can still wrap around the sphere with every
      // face turned outward (cactus and u did, covering it 4 times): only a repair that
      // leaves the map's degree at 1 is a repair.
      // The distortion, a sum over every face, last and only where it is bounded.
      if (t.folds < folded && quality::covers_once(t.degree()) &&
          (!scope.bound_distortion || tally.distortion(region_faces, t) <= allowed)) {
        X = std::move(back);
        tally.accept(region_faces, t);
        folded = t.folds;
        moved += nfree;
        repair.set_scale(X);
        break;
      }
    }
  }
  return moved;
}

SphereUnfolded unfold_sphere_map(const mesh::TriMesh& m, mesh::Vertices& X, const SphereUnfold& how) {
  // Checked before the local moves, which index the flags without looking.
  if (!how.scope.held.empty() && static_cast<int>(how.scope.held.size()) != m.num_vertices())
    invalid("the held vertices' flags are not one per vertex");
  const std::vector<char> held = how.scope.held.empty() ? std::vector<char>(m.num_vertices(), 0) : how.scope.held;
  SphereUnfolded r;
  r.moved = conformal::untangle(m, X, true, held, r.folds, 100, how.keep_longest_edges);
  // The degree is an O(F) sum: taken after each step only where it gates the next, and once at
  // the end for the caller.
  auto may_repair = [&] {
    if (!how.barrier || r.folds == 0) return false;
    return !how.only_covering_once || quality::covers_once(quality::sphere_degree(m.F, X));
  };
  if (may_repair())
    r.moved += repair_sphere_folds_by_barrier(m, X, r.folds, how.keep_going, BarrierSpace::kSphere, how.scope);
  for (int pass = 0; pass < how.chart_passes && may_repair(); ++pass) {
    const int before = r.folds;
    r.moved += repair_sphere_folds_by_barrier(m, X, r.folds, how.keep_going, BarrierSpace::kChart, how.scope);
    if (r.folds == before) break;
  }
  r.degree = quality::sphere_degree(m.F, X);
  return r;
}

}  // namespace brenier::omt

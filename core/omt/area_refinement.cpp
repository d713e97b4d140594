#include "omt/area_refinement.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <span>

#include "common/check.hpp"
#include "common/error.hpp"
#include "common/parallel.hpp"
#include "mesh/geometry.hpp"
#include "numeric/face_hessian.hpp"
#include "numeric/psd.hpp"
#include "omt/barrier_energy.hpp"
#include "omt/newton_step.hpp"

namespace brenier::omt {

// See area_refinement.hpp. The Hessian's entries go straight into its values through the
// pattern's slots (numeric/face_hessian.hpp).
struct RefinementPlan {
  RefinementPlan(const mesh::Faces& F, const std::vector<char>& free) : faces(F), hessian(F, free) {}
  mesh::Faces faces;             // the mesh's faces it was made for
  numeric::FaceHessian hessian;  // the pattern, per vertex its unknowns, the analysed factor
};

namespace {

// The plan for unknowns free[v] per vertex (0, 1 or 2: Dof::count).
std::shared_ptr<RefinementPlan> plan_refinement(const mesh::Faces& F, const std::vector<char>& free) {
  return std::make_shared<RefinementPlan>(F, free);
}

// The disk's unknowns per vertex: 2 inside, 1 on the boundary (along the circle) or 0 (held).
std::vector<char> disk_unknowns(const std::vector<char>& fixed, const AreaRefineOptions& opt) {
  std::vector<char> free(fixed.size());
  for (size_t v = 0; v < fixed.size(); ++v) free[v] = !fixed[v] ? 2 : opt.slide_boundary ? 1 : 0;
  return free;
}

}  // namespace

std::shared_ptr<RefinementPlan> plan_disk_refinement(const mesh::TriMesh& m, const std::vector<char>& fixed,
                                                     const AreaRefineOptions& opt) {
  BRENIER_CHECK(static_cast<int>(fixed.size()) == m.num_vertices(),
                fixed.size() << " fixed flags for " << m.num_vertices() << " vertices");
  return plan_refinement(m.F, disk_unknowns(fixed, opt));
}

std::shared_ptr<RefinementPlan> plan_sphere_refinement(const mesh::TriMesh& m) {
  return plan_refinement(m.F, std::vector<char>(m.num_vertices(), 2));
}

Eigen::VectorXd abs_log_area_ratios(const mesh::Faces& F, const mesh::Vertices& X, const Eigen::VectorXd& target) {
  const Eigen::VectorXd a = mesh::face_areas(F, X);
  const double ta = a.sum(), tt = target.sum();
  Eigen::VectorXd out(F.rows());
  for (Eigen::Index f = 0; f < F.rows(); ++f) out[f] = std::abs(std::log((a[f] / ta) / (target[f] / tt)));
  return out;
}

namespace {

quality::Stats abs_log_stats(const mesh::Faces& F, const mesh::Vertices& X, const Eigen::VectorXd& target) {
  const Eigen::VectorXd r = abs_log_area_ratios(F, X, target);
  return quality::stats(std::vector<double>(r.data(), r.data() + r.size()));
}

using Vec6 = Eigen::Matrix<double, 6, 1>;
using Mat6 = Eigen::Matrix<double, 6, 6>;

// A face's gradient and Hessian in the two coordinates of each of its corners.
struct Local {
  Vec6 g;
  Mat6 H;
};

// The energy's derivatives in D = det J and T = |J|_F^2 (barrier_energy.hpp).
using Scalars = detail::RefinementScalars;
constexpr auto scalars = detail::refinement_scalars;

// The plane: a face's corners are rows of X (x, y), J = [b - a, c - a] R with R the
// reference's inverse edge matrix, D = det J.
struct PlaneGeometry {
  static Eigen::Matrix2d edges(const mesh::Vertices& X, const detail::BarrierFace& f) {
    Eigen::Matrix2d M;
    M << X(f.v[1], 0) - X(f.v[0], 0), X(f.v[2], 0) - X(f.v[0], 0), X(f.v[1], 1) - X(f.v[0], 1),
        X(f.v[2], 1) - X(f.v[0], 1);
    return M;
  }
  // The face's energy, or infinity when it degenerates or turns over.
  double term(const mesh::Vertices& X, const detail::BarrierFace& f, double theta) const {
    const Eigen::Matrix2d J = edges(X, f) * f.ref_inv;
    const double D = J.determinant();
    return D > 0 ? scalars(f.weight * f.scale, theta, D, J.squaredNorm()).e : std::numeric_limits<double>::infinity();
  }
  // The gradient and the Hessian projected onto the positive semi-definite cone (Teran et
  // al. 2005), in J (4x4, where the energy's invariance under rotations gives the projection
  // in closed form: numeric::clamped_isotropic_2d), pulled back through the linear x -> vec J.
  Local derivatives(const mesh::Vertices& X, const detail::BarrierFace& f, double theta) const {
    const Eigen::Matrix2d& R = f.ref_inv;
    const Eigen::Matrix2d J = edges(X, f) * R;
    const double D = J.determinant(), T = J.squaredNorm();
    const Scalars c = scalars(f.weight * f.scale, theta, D, T);
    const numeric::IsotropicDerivatives2d d = numeric::isotropic_derivatives_2d(J, c.eD, c.eT, c.eDD, c.eDT);
    const Eigen::Vector4d& gJ = d.g;
    const Eigen::Matrix4d HJ = numeric::clamped_isotropic_2d(J, d.H);
    // vec J = A x, x = (a, b, c): J(i, k) = sum_m M(i, m) R(m, k).
    Eigen::Matrix<double, 4, 6> A = Eigen::Matrix<double, 4, 6>::Zero();
    for (int i = 0; i < 2; ++i)
      for (int k = 0; k < 2; ++k) {
        A(i + 2 * k, 2 + i) = R(0, k);
        A(i + 2 * k, 4 + i) = R(1, k);
        A(i + 2 * k, i) = -(R(0, k) + R(1, k));
      }
    return {A.transpose() * gJ, A.transpose() * HJ * A};
  }
  void begin(const mesh::Vertices&) {}
  static double measure(const mesh::Vertices&, const mesh::Faces&, int) { return 1; }
  static double chord_area(const mesh::Vertices& X, const mesh::Faces& F, int f) {
    return 0.5 * edges(X, detail::BarrierFace{{F(f, 0), F(f, 1), F(f, 2)}, {}, 0}).determinant();
  }
  void move(mesh::Vertices& Y, int row, const Eigen::Vector2d& step) const { Y.row(row).head<2>() += step.transpose(); }
  bool valid(const mesh::Vertices&) const { return true; }  // the finite energy says it all

  // The largest t with det(edges) positive along X + t d for every face (Smith and Schaefer
  // 2015): the determinant is a quadratic in t.
  static double first_root(const Eigen::Matrix2d& M, const Eigen::Vector2d& e1, const Eigen::Vector2d& e2) {
    const double c0 = M.determinant();
    const double c1 = M(0, 0) * e2.y() + e1.x() * M(1, 1) - M(0, 1) * e1.y() - e2.x() * M(1, 0);
    const double c2 = e1.x() * e2.y() - e1.y() * e2.x();
    double root = std::numeric_limits<double>::infinity();
    if (std::abs(c2) < 1e-300) {
      if (c1 < 0) root = -c0 / c1;
      return root;
    }
    const double disc = c1 * c1 - 4 * c2 * c0;
    if (disc < 0) return root;
    const double sq = std::sqrt(disc);
    for (double r : {(-c1 - sq) / (2 * c2), (-c1 + sq) / (2 * c2)})
      if (r > 0) root = std::min(root, r);
    return root;
  }
  // FaceNewton::max_step's bound for face f, its corners moved by s0, s1, s2 (times t).
  double first_turn(const mesh::Vertices& X, const detail::BarrierFace& f, const Eigen::Vector2d& s0,
                    const Eigen::Vector2d& s1, const Eigen::Vector2d& s2) const {
    return first_root(edges(X, f), s1 - s0, s2 - s0);
  }
};

// The sphere: corners on the unit sphere, a vertex moved by delta in its tangent plane goes to
// (x + B delta) / |x + B delta|, B an orthonormal tangent basis; J is the chord edges
// [b - a, c - a] (3x2) times R. D measures the face against its reference in one of two ways:
//  - volume: det(a, b, c) / (2 A), the chord area times the plane's distance from the centre.
//    It is linear in each corner and vanishes exactly when the face turns over, so it is a
//    barrier against turning even for slivers along a great circle (whose chord area stays
//    positive as they turn). The references carry each plane's distance, reread before every
//    step, so that D is the chord area's ratio where each step starts.
//  - chord: |n| / (2 A), n = (b - a) x (c - a), the chord area itself, which the result is
//    judged by. One function throughout, so coarse polyhedra, whose planes' distances change a
//    lot (a cube's faces go from 0.5 to 0.577), descend to equal areas; but |n| is no barrier
//    against a face turning over, so the energy adds a small one on each plane's distance from
//    the centre (add_plane_barrier). It still stalls on spread starts and serves as the polish
//    after the volume stage.
struct SphereGeometry {
  bool chord = false;  // D as the chord area's ratio (else the volume's)
  const mesh::Vertices* X0 = nullptr;
  std::vector<Eigen::Matrix<double, 3, 2>> basis;  // per vertex, at the step's start

  static Eigen::Vector3d at(const mesh::Vertices& X, int r) { return X.row(r).transpose(); }
  static Eigen::Matrix3d skew(const Eigen::Vector3d& u) {
    Eigen::Matrix3d S;
    S << 0, -u.z(), u.y(), u.z(), 0, -u.x(), -u.y(), u.x(), 0;
    return S;
  }
  static double chord_area(const mesh::Vertices& X, const mesh::Faces& F, int f) {
    const Eigen::Vector3d a = at(X, F(f, 0)), b = at(X, F(f, 1)), c = at(X, F(f, 2));
    return 0.5 * (b - a).cross(c - a).norm();
  }
  // A face's area in the energy's measure over its chord area: 1, or (volume) its plane's
  // distance from the centre.
  double measure(const mesh::Vertices& X, const mesh::Faces& F, int f) const {
    if (chord) return 1;
    const Eigen::Vector3d a = at(X, F(f, 0)), b = at(X, F(f, 1)), c = at(X, F(f, 2));
    const Eigen::Vector3d n = (b - a).cross(c - a);
    return n.norm() > 0 ? a.dot(n) / n.norm() : 1;
  }
  // At each step's start: tangent bases at X, where the moves start from.
  void begin(const mesh::Vertices& X) {
    X0 = &X;
    basis.resize(X.rows());
    for (Eigen::Index r = 0; r < X.rows(); ++r) {
      const Eigen::Vector3d x = at(X, static_cast<int>(r));
      const Eigen::Vector3d e = std::abs(x.x()) < 0.6 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
      const Eigen::Vector3d u = x.cross(e).normalized();
      basis[r] << u, x.cross(u);
    }
  }
  double term(const mesh::Vertices& X, const detail::BarrierFace& f, double theta) const {
    const Eigen::Vector3d a = at(X, f.v[0]), b = at(X, f.v[1]), c = at(X, f.v[2]);
    Eigen::Matrix<double, 3, 2> M;
    M << b - a, c - a;
    const Eigen::Vector3d n = M.col(0).cross(M.col(1));
    const double det = a.dot(n);  // det(a, b, c), from the edges: no cancellation on small faces
    const double D = (chord ? n.norm() : det) / (2 * f.weight);
    if (!(det > 0) || !(D > 0)) return std::numeric_limits<double>::infinity();
    const double e = scalars(f.weight * f.scale, theta, D, (M * f.ref_inv).squaredNorm()).e;
    return chord ? e + plane_barrier * f.weight * n.norm() / det : e;  // + beta w / h
  }
  // The Hessian in the nine coordinates of (a, b, c), then in the corners' tangent
  // coordinates (B^T H B, less (x . g_x) I for the sphere's curvature), projected there.
  // D's derivatives are det's (volume) or |n|'s (chord), below.
  Local derivatives(const mesh::Vertices& X, const detail::BarrierFace& f, double theta) const {
    const Eigen::Vector3d a = at(X, f.v[0]), b = at(X, f.v[1]), c = at(X, f.v[2]);
    const double k = 1 / (2 * f.weight);
    using V9 = Eigen::Matrix<double, 9, 1>;
    using M9 = Eigen::Matrix<double, 9, 9>;
    const Eigen::Vector3d n = (b - a).cross(c - a);  // from the edges: no cancellation on small faces
    const Scalar9 raw = chord ? normal_length(a, b, c, n) : determinant(a, b, c, n);
    const double D = raw.value * k;
    const V9 gD = k * raw.g;
    const M9 HD = k * raw.H;
    // T = |M R|^2 = sum_{m,n} (R R^T)(m, n) e_m . e_n with e_0 = b - a, e_1 = c - a.
    const Eigen::Matrix2d K = f.ref_inv * f.ref_inv.transpose();
    Eigen::Matrix<double, 2, 3> E;  // e_m = sum_p E(m, p) corner_p
    E << -1, 1, 0, -1, 0, 1;
    const Eigen::Matrix3d W = E.transpose() * K * E;  // T = sum_{p,q} W(p, q) x_p . x_q
    M9 HT;
    for (int p = 0; p < 3; ++p)
      for (int q = 0; q < 3; ++q) HT.block<3, 3>(3 * p, 3 * q) = 2 * W(p, q) * Eigen::Matrix3d::Identity();
    V9 x;
    x << a, b, c;
    const V9 gT = HT * x;
    const double T = 0.5 * x.dot(gT);
    const Scalars s = scalars(f.weight * f.scale, theta, D, T);
    V9 g9 = s.eD * gD + s.eT * gT;
    M9 H9 = s.eDD * gD * gD.transpose() + s.eDT * (gD * gT.transpose() + gT * gD.transpose()) + s.eD * HD + s.eT * HT;
    if (chord) add_plane_barrier(determinant(a, b, c, n), raw, f.weight, g9, H9);
    Eigen::Matrix<double, 9, 6> P = Eigen::Matrix<double, 9, 6>::Zero();
    for (int p = 0; p < 3; ++p) P.block<3, 2>(3 * p, 2 * p) = basis[f.v[p]];
    Mat6 H = P.transpose() * H9 * P;
    for (int p = 0; p < 3; ++p) H.block<2, 2>(2 * p, 2 * p) -= x.segment<3>(3 * p).dot(g9.segment<3>(3 * p)) * Eigen::Matrix2d::Identity();
    return {P.transpose() * g9, numeric::clamped<6>(H)};
  }
  // A function of the corners (a, b, c) with its gradient and Hessian in their nine coordinates.
  struct Scalar9 {
    double value;
    Eigen::Matrix<double, 9, 1> g;
    Eigen::Matrix<double, 9, 9> H;
  };
  // Adds S at block (p, q) of H and its transpose at (q, p).
  static void add_pair(Eigen::Matrix<double, 9, 9>& H, int p, int q, const Eigen::Matrix3d& S) {
    H.block<3, 3>(3 * p, 3 * q) += S;
    H.block<3, 3>(3 * q, 3 * p) += S.transpose();
  }
  // det(a, b, c) = a . n, n = (b - a) x (c - a). It is trilinear: d det / da = b x c and so on,
  // and its Hessian's blocks are (a, b) = -[c]x, (a, c) = [b]x, (b, c) = -[a]x and their
  // transposes.
  static Scalar9 determinant(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                             const Eigen::Vector3d& n) {
    Scalar9 d{a.dot(n), {}, Eigen::Matrix<double, 9, 9>::Zero()};
    d.g << b.cross(c), c.cross(a), a.cross(b);
    add_pair(d.H, 0, 1, -skew(c));
    add_pair(d.H, 0, 2, skew(b));
    add_pair(d.H, 1, 2, -skew(a));
    return d;
  }
  // |n|, twice the chord area. With n = a x b + b x c + c x a (bilinear, dn/da = [c - b]x,
  // dn/db = [a - c]x, dn/dc = [b - a]x, N = [dn/da dn/db dn/dc]) and u = n / |n|: d|n| = N^T u
  // and d^2|n| = N^T (I - u u^T) N / |n| + Q, Q the constant Hessian of u . n, whose blocks are
  // (a, b) = (b, c) = (c, a) = -[u]x and their transposes.
  static Scalar9 normal_length(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                               const Eigen::Vector3d& n) {
    const double len = n.norm();
    const Eigen::Vector3d u = n / len;
    Eigen::Matrix<double, 3, 9> N;
    N << skew(c - b), skew(a - c), skew(b - a);
    Scalar9 l{len, N.transpose() * u, N.transpose() * (Eigen::Matrix3d::Identity() - u * u.transpose()) * N / len};
    for (int p = 0; p < 3; ++p) add_pair(l.H, p, (p + 1) % 3, -skew(u));
    return l;
  }
  // The chord measure's barrier against turning: beta w / h, h = det(a, b, c) / |n| the plane's
  // distance from the centre (near 1 for a small face, 0 where the face turns over). Without it
  // the Newton steps did not see that wall, which only the line search's det > 0 found: on
  // coarse polyhedra they pressed a face's plane against the centre and stalled there (beam.off:
  // every step cut to t = 1/256 at mean |log area ratio| 0.13, where its inscribed box has 0).
  // On a small face h's gradient is of the order of its edges, so the barrier moves fine meshes
  // by nothing measurable. beta: over the sphere meshes of up to 1,000 vertices, 1e-5, 1e-4 and
  // 1e-3 meet the tolerances on the same meshes; 1e-3 leaves the coarse thin ones nearest
  // (oblong 0.071 against 0.17-0.18), the tetrahedra, whose targets no inscribed tetrahedron
  // meets, farthest (0.124 against 0.109-0.113; bench/RESULTS.md).
  static constexpr double plane_barrier = 1e-3;
  // Adds the barrier's gradient and Hessian, from det's and l = |n|'s: h = det / l,
  // grad h = grad det / l - det grad l / l^2,
  // hess h = hess det / l - (grad det grad l^T + grad l grad det^T) / l^2 - det hess l / l^2
  //          + 2 det grad l grad l^T / l^3,
  // and B = beta w / h: grad B = -beta w grad h / h^2, hess B = beta w (2 grad h grad h^T / h^3
  // - hess h / h^2).
  static void add_plane_barrier(const Scalar9& det, const Scalar9& l, double w, Eigen::Matrix<double, 9, 1>& g,
                                Eigen::Matrix<double, 9, 9>& H) {
    const double L = l.value, h = det.value / L;
    const Eigen::Matrix<double, 9, 1> gh = det.g / L - det.value * l.g / (L * L);
    const Eigen::Matrix<double, 9, 9> Hh = det.H / L - (det.g * l.g.transpose() + l.g * det.g.transpose()) / (L * L) -
                                           det.value * l.H / (L * L) + 2 * det.value * l.g * l.g.transpose() / (L * L * L);
    const double bw = plane_barrier * w;
    g -= bw * gh / (h * h);
    H += bw * (2 * gh * gh.transpose() / (h * h * h) - Hh / (h * h));
  }
  void move(mesh::Vertices& Y, int row, const Eigen::Vector2d& step) const {
    Y.row(row) = (at(*X0, row) + basis[row] * step).normalized().transpose();
  }
  // FaceNewton::max_step's bound for face f, its corners moved by s0, s1, s2 (times t) in their
  // tangent planes: detail::first_turn_on_sphere, looked for up to t = 2 (the step is cut to 0.9
  // of the root, so a root past 1 / 0.9 leaves the full step).
  double first_turn(const mesh::Vertices& X, const detail::BarrierFace& f, const Eigen::Vector2d& s0,
                    const Eigen::Vector2d& s1, const Eigen::Vector2d& s2) const {
    return detail::first_turn_on_sphere(at(X, f.v[0]), at(X, f.v[1]), at(X, f.v[2]), basis[f.v[0]] * s0,
                                        basis[f.v[1]] * s1, basis[f.v[2]] * s2, 2.0);
  }
  // A map with every face outward can still wrap around the sphere: it must cover it once.
  const mesh::Faces* F = nullptr;
  bool valid(const mesh::Vertices& Y) const { return quality::covers_once(quality::sphere_degree(*F, Y)); }
};

// Damped projected Newton on the energy of area_refinement.hpp over the unknowns of Dof: each
// face's clamped Hessian, in its corners' unknowns, into the global one, whose pattern is
// fixed (the entries go straight into its values), factored by CHOLMOD; the step is cut to
// 0.9 of the way to the first face that degenerates or turns over along it (the plane: the
// root of a quadratic; the sphere: of a cubic, detail::first_turn_on_sphere), then halved
// until the energy drops by Armijo's rule and the map stays valid (finite energy: no face
// degenerate or turned over). On the sphere the cut came in session 55: before it, the
// halvings alone found t below the first turn, and on the spread starts of crowded conformal
// maps, where a few faces bound nearly every step at t ~ 0.1-0.3, the 0.9 of the root is up to
// twice as long (dino 0.059 -> 0.041 mean |log area ratio| in the same budget; bench/RESULTS.md).
template <class Geometry>
class FaceNewton {
 public:
  FaceNewton(const std::vector<detail::BarrierFace>& faces, RefinementPlan& plan, Geometry& geometry)
      : faces_(faces), dof_(plan.hessian.dof()), n_(plan.hessian.size()), geometry_(geometry), local_(faces.size()),
        corner_g_(faces.size() * 3), tangent_(dof_.size(), Eigen::Vector2d::Zero()), H_(plan.hessian) {}

  // The energy at X (infinite when a face degenerates or turns over).
  // The faces' terms are summed in face order, not by an OpenMP reduction: libgomp combines
  // the threads' partial sums in the order they finish, so the sum's last bits, and through
  // the line search the map's, changed from run to run (a brenierd job's lion-head map once
  // differed from the engine's by 1e-12).
  double energy(const mesh::Vertices& X, double theta) const {
    const long nf = static_cast<long>(faces_.size());
    terms_.resize(faces_.size());
#pragma omp parallel for schedule(static)
    for (long k = 0; k < nf; ++k) terms_[static_cast<size_t>(k)] = geometry_.term(X, faces_[k], theta);
    double E = 0;
    for (double t : terms_) E += t;
    return E;
  }

  // One damped Newton step at theta; returns the Newton decrement -g.d (0: no step taken)
  // and sets `before` to the energy at the step's start.
  double step(mesh::Vertices& X, double theta, double& before) {
    before = std::numeric_limits<double>::infinity();
    const long nf = static_cast<long>(faces_.size());
    geometry_.begin(X);
    for (size_t r = 0; r < dof_.size(); ++r)
      if (dof_[r].count == 1) tangent_[r] << -X(r, 1), X(r, 0);
#pragma omp parallel for schedule(static)
    for (long k = 0; k < nf; ++k) {
      const Local full = geometry_.derivatives(X, faces_[k], theta);
      for (int p = 0; p < 3; ++p) corner_g_[k * 3 + p] = full.g.segment<2>(2 * p);
      if (all_free(faces_[k])) {  // the reduction is the identity
        local_[k] = full;
        continue;
      }
      const Mat6 T = reduction(faces_[k]);
      local_[k] = {T.transpose() * full.g, T.transpose() * full.H * T};
    }
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n_);
    H_.clear();
    std::vector<Eigen::Vector2d> circle_g(dof_.size(), Eigen::Vector2d::Zero());
    for (long k = 0; k < nf; ++k) {
      const Local& L = local_[k];
      const detail::BarrierFace& f = faces_[k];
      for (int p = 0; p < 3; ++p) {
        const numeric::Dof& d = dof_[f.v[p]];
        for (int a = 0; a < d.count; ++a) g[d.offset + a] += L.g[2 * p + a];
        if (d.count == 1) circle_g[f.v[p]] += corner_g_[k * 3 + p];
      }
      H_.add(k, L.H);
    }
    // The circle's curvature: along x(tau) = (x + tau t) / |x + tau t|, x'' = -x, so the energy's
    // second derivative gains -grad . x (kept only where positive: the Hessian stays definite).
    for (size_t r = 0; r < dof_.size(); ++r)
      if (dof_[r].count == 1)
        H_.diagonal(dof_[r].offset) += std::max(0.0, -circle_g[r].dot(X.row(r).head<2>().transpose()));
    // A small multiple of the diagonal's mean keeps the clamped Hessian definite (the
    // sphere's energy is invariant under rotations).
    H_.shift_diagonal_by_mean(1e-9);
    if (!H_.factorize()) return 0;
    const double E0 = before = energy(X, theta);
    const Eigen::VectorXd d = -H_.solve(g);
    const double decrement = -g.dot(d);
    if (!(decrement > 0) || !d.allFinite()) return 0;
    double t = std::min(1.0, 0.9 * max_step(X, d));
    mesh::Vertices trial = X;
    for (int k = 0; k < 40; ++k, t *= 0.5) {
      trial = X;
      for (Eigen::Index r = 0; r < X.rows(); ++r)
        if (dof_[r].count > 0) {
          geometry_.move(trial, static_cast<int>(r), t * step_of(static_cast<int>(r), d));
          if (dof_[r].count == 1) trial.row(r).head<2>().normalize();  // back onto the circle
        }
      if (energy(trial, theta) <= E0 - 1e-4 * t * decrement && geometry_.valid(trial)) {
        X = std::move(trial);
        return decrement;
      }
    }
    return 0;
  }

 private:
  // The corners' steps from their unknowns: columns 2p, 2p + 1 of the face's six coordinates
  // for corner p's unknowns (the identity, the circle's tangent, or nothing).
  Mat6 reduction(const detail::BarrierFace& f) const {
    Mat6 T = Mat6::Zero();
    for (int p = 0; p < 3; ++p) {
      const numeric::Dof& d = dof_[f.v[p]];
      if (d.count == 2) T.block<2, 2>(2 * p, 2 * p).setIdentity();
      if (d.count == 1) T.block<2, 1>(2 * p, 2 * p) = tangent_[f.v[p]];
    }
    return T;
  }
  // Whether each corner of f has its two coordinates as unknowns (the plane's inner vertices,
  // every vertex on the sphere): the reduction is then the identity, and the 6x6 products it
  // costs were a quarter of the derivatives' time (100K-vertex disk map: 33 -> 24 ms a step).
  bool all_free(const detail::BarrierFace& f) const {
    return dof_[f.v[0]].count == 2 && dof_[f.v[1]].count == 2 && dof_[f.v[2]].count == 2;
  }
  // The 2-D step of vertex r in its geometry's frame.
  Eigen::Vector2d step_of(int r, const Eigen::VectorXd& d) const {
    const numeric::Dof& v = dof_[r];
    if (v.count == 2) return d.segment<2>(v.offset);
    if (v.count == 1) return d[v.offset] * tangent_[r];
    return Eigen::Vector2d::Zero();
  }

  // The least over the faces of the geometry's first t at which the face degenerates or turns
  // over along the step (the min is exact in any order, so the threads do not change it).
  double max_step(const mesh::Vertices& X, const Eigen::VectorXd& d) const {
    double best = std::numeric_limits<double>::infinity();
    const long nf = static_cast<long>(faces_.size());
#pragma omp parallel for reduction(min : best) schedule(static)
    for (long k = 0; k < nf; ++k) {
      const detail::BarrierFace& f = faces_[k];
      best = std::min(best, geometry_.first_turn(X, f, step_of(f.v[0], d), step_of(f.v[1], d), step_of(f.v[2], d)));
    }
    return best;
  }

  const std::vector<detail::BarrierFace>& faces_;
  const std::vector<numeric::Dof>& dof_;
  int n_;
  Geometry& geometry_;
  std::vector<Local> local_;           // per face, in its corners' unknowns
  mutable std::vector<double> terms_;  // per face: the energy's terms (energy())
  std::vector<Eigen::Vector2d> corner_g_;  // per face corner, the gradient in the geometry's frame
  std::vector<Eigen::Vector2d> tangent_;   // per vertex on the circle, the tangent at the step's start
  numeric::FaceHessian& H_;                // the plan's: its values set at every step
};

// The reference triangle of face f: m's own shape, scaled to area a.
detail::BarrierFace reference(const mesh::TriMesh& m, int f, double a) {
  return detail::barrier_face(m.F(f, 0), m.F(f, 1), m.F(f, 2), m.V.row(m.F(f, 0)), m.V.row(m.F(f, 1)),
                              m.V.row(m.F(f, 2)), a);
}

void check_targets(const mesh::TriMesh& m, const Eigen::VectorXd& target, const mesh::Vertices& X) {
  BRENIER_CHECK(target.size() == m.num_faces() && X.rows() == m.num_vertices(),
                target.size() << " target areas, " << X.rows() << " rows for " << m.num_faces() << " faces");
  for (Eigen::Index f = 0; f < target.size(); ++f)
    BRENIER_CHECK(target[f] > 0 && std::isfinite(target[f]), "face " << f << " has target area " << target[f]);
}

// The sphere stages' patience (refine's min_progress). Until session 55 a stage ended at the
// first step short of the progress, and kept that step's map: with the steps cut at the first
// face turning over (FaceNewton::max_step) the mean |log area ratio| no longer falls at every
// step of the spread starts, and that rule stopped handle at 0.0215 and dino at 0.041 where
// three steps of patience reach 0.0104 and 0.0229 (bench/RESULTS.md).
constexpr int kPatience = 3;

// The stages' thetas. The disk's, and the sphere's from a start near its areas: 0.999, then
// 0.9999.
constexpr std::array<double, 2> kThetas = {0.999, 0.9999};
// The sphere's from a start far from its areas (mean |log area ratio| above kFarStart: the
// spread starts of crowded conformal maps and coarse polyhedra, 0.26-0.81 on data/meshes), a
// continuation from a stiffer shape term. A spread start's arms and legs must stretch across
// the sphere; begun at 0.999 the stages stalled where a few thin faces held their neighbours
// (bull 0.0417, dino 0.0229, spool 0.0227, part 0.0456). Begun at 0.98, the early stages move
// the map as a whole while the shapes still resist, and the later ones meet the areas from
// there: bull 0.0382, dino 0.0168, spool 0.0115, part 0.0165 (bench/RESULTS.md, session 56).
// Starting lower (0.95, 0.5) or with more stages was no better. Near starts (bunny00 0.17,
// bear 0.06) meet the tolerances either way, in fewer steps without the stiff stages (bunny00
// 9 against 50). On the disk the five stages were worse (mannequin-devil off its tolerances).
constexpr std::array<double, 5> kFarThetas = {0.98, 0.995, 0.999, 0.9999, 0.99999};
constexpr double kFarStart = 0.25;

// AreaRefineOptions::keep_going after a Newton step.
void keep_going(const AreaRefineOptions& opt, int step, double mean) {
  if (opt.keep_going && !opt.keep_going(step, mean)) fail(ErrorCode::kCancelled, "the area refinement was cancelled");
}

// Whether a refinement's result meets both of its stated tolerances.
bool meets(const AreaRefineOptions& opt, const quality::Stats& s) {
  return s.mean <= opt.mean_tolerance && s.p95 <= opt.p95_tolerance;
}

// The rounds toward the bar's own measure (AreaRefineOptions::reweighted_rounds), after the
// disk's stages and the sphere's chord stages. The energy's area term weighs each face by its
// target area and grows like l_f^2 (l_f = log D_f) near D_f = 1, while the bar is the mean of
// |l_f| over the faces, each face once. Iteratively reweighted least squares for that L1
// measure: each round multiplies face f's term by (mean target / target_f) /
// sqrt(l_f^2 + delta^2) (BarrierFace::scale), l_f read at the round's start, so that the area
// term is, to second order, sum_f l_f^2 / sqrt(l0_f^2 + delta^2), whose minimum lowers sum_f
// sqrt(l_f^2 + delta^2); then up to 50 Newton steps at the last stage's theta. The rounds go on
// from each other's maps, and one is kept only if its mean is lower and neither its p95 (beyond
// the tolerance) nor its max is higher than the best kept: on corner_with_sharp_edge (18
// vertices) three rounds are each worse than the last (0.026, 0.038, 0.053) and the fourth lands
// at 0.0025 / p95 0.013 / max 0.018 against the stages' 0.0213 / 0.098 / 0.117, so the maps on
// the way are not kept and the result is never worse than the stages'. On patch-23 the rounds
// lower the mean to 0.0205 only by letting one face grow 2.4 times (max 0.16 -> 0.89): not kept.
// delta 0.01 and 0.005 take corner to 0.0052 and 0.0024 as well. On the sphere: cross 0.0415 ->
// 0.0282, cross_quad 0.0621 -> 0.0274, u 0.1244 -> 0.096, oblong 0.0406 -> 0.0309, every statistic
// lower, none onto the bar. Meshes of at most kReweightedFaces faces only, where the rounds cost
// a second at most: on bull (12,396 faces) they kept nothing and cost 14 s, and on the sphere's
// large meshes rounds after every stage doubled the sweep's time (bench/RESULTS.md, sessions
// 74-75).
constexpr int kReweightedFaces = 1000;
constexpr double kReweightDelta = 0.02;

template <class Geometry, class SetReferences>
void reweighted_rounds(const mesh::TriMesh& m, const Eigen::VectorXd& target, mesh::Vertices& X,
                       FaceNewton<Geometry>& newton, std::vector<detail::BarrierFace>& faces,
                       const SetReferences& set_references, double theta, const AreaRefineOptions& opt,
                       AreaRefinement& out) {
  auto met = [&opt](const quality::Stats& s) { return meets(opt, s); };
  if (m.num_faces() > kReweightedFaces || met(out.after)) return;
  mesh::Vertices best_X = X;
  quality::Stats best = out.after;
  const double mean_target = target.mean();
  Eigen::VectorXd c(m.num_faces());
  for (int round = 0; round < opt.reweighted_rounds && !met(best); ++round) {
    const Eigen::VectorXd l = abs_log_area_ratios(m.F, X, target);
    for (int f = 0; f < m.num_faces(); ++f)
      c[f] = mean_target / target[f] / std::sqrt(l[f] * l[f] + kReweightDelta * kReweightDelta);
    c /= c.mean();
    for (int k = 0; k < 50; ++k) {
      set_references();
      for (int f = 0; f < m.num_faces(); ++f) faces[f].scale = c[f];
      double E = 0;
      const double decrement = newton.step(X, theta, E);
      ++out.iterations;
      keep_going(opt, out.iterations, best.mean);
      if (!(decrement > 1e-7 * E)) break;
    }
    const quality::Stats s = abs_log_stats(m.F, X, target);
    if (s.mean < best.mean && s.p95 <= std::max(best.p95, opt.p95_tolerance) && s.max <= best.max) {
      best_X = X;
      best = s;
    }
  }
  X = std::move(best_X);
  out.after = best;
  out.converged = met(best);
  set_references();
}

// The staged minimization of area_refinement.hpp, one stage per theta of `thetas`, each stage
// ended when the Newton decrement falls below 1e-7 of the energy or after 50 steps, the
// whole when the tolerances hold or the budget is spent; the unknowns and the analysed
// pattern are plan's. Given min_progress (the sphere), a stage also ends once kPatience steps
// in a row have not cut the mean |log area ratio| by that fraction from where it last did (0:
// have not lowered it), and the map goes back to the stage's best. Given reweight (the disk's run,
// the sphere's chord runs), the reweighted rounds follow the stages.
template <class Geometry>
AreaRefinement refine(const mesh::TriMesh& m, const Eigen::VectorXd& target, mesh::Vertices& X,
                      RefinementPlan& plan, const AreaRefineOptions& opt, Geometry& geometry,
                      std::span<const double> thetas, std::optional<double> min_progress = std::nullopt,
                      bool reweight = false) {
  const auto t0 = std::chrono::steady_clock::now();
  AreaRefinement out;
  out.ran = true;
  out.mean_tolerance = opt.mean_tolerance;
  out.p95_tolerance = opt.p95_tolerance;
  out.before = out.after = abs_log_stats(m.F, X, target);
  auto met = [&opt](const quality::Stats& s) { return meets(opt, s); };
  out.converged = met(out.after);
  const mesh::Vertices start = X;
  // The reference triangles, of the target areas in the energy's measure (on the sphere, in
  // the volume measure, the chord areas times their planes' distances from the centre, read at
  // the current map, so that the targets are the chord areas the result is measured by; in the
  // chord measure the chord areas themselves), their total the map's.
  // The map's total is not fixed: on the sphere a coarse mesh's inscribed polyhedron can hold
  // far less volume than the start's, on the disk the boundary vertices slide along the circle
  // and so change the inscribed polygon's area (cube-ouvert, an open cube of ten triangles:
  // 0.043 with the scale set once at the start, 0.0096 refitted). So the targets' common
  // scale sigma is refitted before every step to the one that minimizes the area term
  // sum_f t_f (r_f / sigma + sigma / r_f) at the current map (r_f = D_f sigma, here the chord
  // area over the target): sigma^2 = sum t_f r_f / sum t_f / r_f. The steps and the refits
  // then descend one function, which is invariant under scaling every r_f; with a scale fixed
  // at the start, the energy's minimum sat where the map's total matched that scale, not where
  // its areas were equal (a cube's map on the sphere stayed at mean |log area ratio| 0.068
  // though the inscribed cube's is 0). (Refitting to the plain ratio of totals instead was no
  // descent: it drifted toward smaller volumes.)
  std::vector<detail::BarrierFace> faces(m.num_faces());
  auto set_references = [&] {
    Eigen::VectorXd t(m.num_faces());
    for (int f = 0; f < m.num_faces(); ++f) t[f] = target[f] * geometry.measure(X, m.F, f);
    double sum_tr = 0, sum_t_over_r = 0;
    for (int f = 0; f < m.num_faces(); ++f) {
      const double r = Geometry::chord_area(X, m.F, f) / target[f];
      sum_tr += t[f] * r;
      sum_t_over_r += t[f] / r;
    }
    // (Never degenerate here: the start has no degenerate face, and the steps keep it so.)
    BRENIER_CHECK(sum_tr > 0 && std::isfinite(sum_t_over_r), "a degenerate face in the area refinement");
    const double scale = std::sqrt(sum_tr / sum_t_over_r);
    for (int f = 0; f < m.num_faces(); ++f) faces[f] = reference(m, f, t[f] * scale);
  };
  set_references();
  const int n = plan.hessian.size();
  FaceNewton<Geometry> newton(faces, plan, geometry);
  for (double theta : thetas) {
    if (out.converged || out.iterations >= opt.max_iterations || n == 0) break;
    ++out.stages;
    // Sphere stages (min_progress given): the map of the stage's least mean |log area ratio|,
    // and the steps since the last that cut the mean by min_progress (to `progressed`).
    mesh::Vertices best_X;
    if (min_progress) best_X = X;
    quality::Stats best = out.after;
    double progressed = out.after.mean;
    int since = 0;
    for (int k = 0; k < 50 && out.iterations < opt.max_iterations && !out.converged; ++k) {
      if (k > 0) set_references();
      double E = 0;
      const double decrement = newton.step(X, theta, E);
      ++out.iterations;
      out.after = abs_log_stats(m.F, X, target);
      out.converged = met(out.after);
      keep_going(opt, out.iterations, out.after.mean);
      if (min_progress) {
        if (out.after.mean < best.mean || out.converged) {
          best_X = X;
          best = out.after;
        }
        if (out.after.mean <= (1 - *min_progress) * progressed) {
          progressed = out.after.mean;
          since = 0;
        } else if (++since >= kPatience) {
          break;
        }
      }
      if (!(decrement > 1e-7 * E)) break;
    }
    if (min_progress && best.mean < out.after.mean) {
      X = best_X;
      out.after = best;
      out.converged = met(out.after);
      set_references();
    }
  }
  if (reweight && !thetas.empty())
    reweighted_rounds(m, target, X, newton, faces, set_references, thetas.back(), opt, out);
  // The energy is not the measure: where the targets cannot be met (a cube's eight corners, a
  // beam's), its minimum can sit at a larger mean |log area ratio| than the start. Then the
  // start is kept.
  if (out.after.mean > out.before.mean) {
    X = start;
    out.after = out.before;
    out.converged = false;
    out.kept_start = true;
  }
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

template <class Test>
bool every_face(const mesh::TriMesh& m, const Test& test) {
  for (int f = 0; f < m.num_faces(); ++f)
    if (!test(f)) return false;
  return true;
}

// The plan the caller made, checked against the mesh and the unknowns it asks for, or a new one.
std::shared_ptr<RefinementPlan> plan_for(const mesh::TriMesh& m, const std::vector<char>& free,
                                         std::shared_ptr<RefinementPlan> plan) {
  if (!plan) return plan_refinement(m.F, free);
  bool same = plan->hessian.dof().size() == free.size() && plan->faces.rows() == m.F.rows() && plan->faces == m.F;
  for (size_t v = 0; same && v < free.size(); ++v) same = plan->hessian.dof()[v].count == free[v];
  BRENIER_CHECK(same, "the area refinement's plan was made for another mesh or other held vertices");
  return plan;
}

}  // namespace

AreaRefinement refine_disk_areas(const mesh::TriMesh& m, const Eigen::VectorXd& target, mesh::Vertices& X,
                                 const std::vector<char>& fixed, const AreaRefineOptions& opt,
                                 std::shared_ptr<RefinementPlan> plan) {
  check_targets(m, target, X);
  if (!opt.enabled) return {};
  // A fold: the barrier needs a valid start.
  if (!every_face(m, [&](int f) { return PlaneGeometry::chord_area(X, m.F, f) > 0; })) return {};
  plan = plan_for(m, disk_unknowns(fixed, opt), std::move(plan));
  PlaneGeometry plane;
  return refine(m, target, X, *plan, opt, plane, kThetas, std::nullopt, true);
}

AreaRefinement refine_sphere_areas(const mesh::TriMesh& m, const Eigen::VectorXd& target, mesh::Vertices& X,
                                   const AreaRefineOptions& opt, std::shared_ptr<RefinementPlan> plan) {
  check_targets(m, target, X);
  if (!opt.enabled) return {};
  auto turns_out = [&](int f) { return X.row(m.F(f, 0)).dot(X.row(m.F(f, 1)).cross(X.row(m.F(f, 2)))) > 0; };
  if (!every_face(m, turns_out) || !quality::covers_once(quality::sphere_degree(m.F, X))) return {};
  plan = plan_for(m, std::vector<char>(m.num_vertices(), 2), std::move(plan));
  SphereGeometry sphere;
  sphere.F = &m.F;
  // The volume measure first (a barrier against turning, from any start), then, where the
  // tolerances are not met, the chord measure (see SphereGeometry): from the volume stage's
  // result, and if that is still short, from the start too, the better kept. Each chord stage
  // ends once kPatience steps in a row have gained less than 1 %: on the spread starts of the
  // real meshes (cow, armadillo, man) it creeps (cow 0.01494 to 0.01488 in 29 steps), on the
  // coarse polyhedra it converges in a few (a cube in 2, corner in 11). Where the volume stage
  // stops short on a coarse mesh, the chord stage from its result can stall where the one from
  // the start does not (horizons-domain: 0.50 against 0.005; bench/RESULTS.md). Each volume
  // stage ends once kPatience steps have not lowered the mean |log area ratio|: past that point
  // its minimum is not the measure's, and the steps only cost time (over the 88 meshes of the
  // sweep, 67 s of refinement against 84 s, and diplodocus meets the tolerances;
  // bench/RESULTS.md). Either returns to its best map.
  const mesh::Vertices start = X;
  std::span<const double> thetas = kThetas;
  if (abs_log_stats(m.F, X, target).mean > kFarStart) thetas = kFarThetas;
  AreaRefinement out = refine(m, target, X, *plan, opt, sphere, thetas, 0.0);
  auto add = [&out](const AreaRefinement& r) {
    out.iterations += r.iterations;
    out.stages += r.stages;
    out.seconds += r.seconds;
  };
  sphere.chord = true;
  for (int from_start = 0; from_start < 2 && !out.converged; ++from_start) {
    if (from_start && out.kept_start) break;  // the first chord run already started there
    mesh::Vertices Y = from_start ? start : X;
    const AreaRefinement chord = refine(m, target, Y, *plan, opt, sphere, thetas, 0.01, true);
    add(chord);
    if (!chord.kept_start && chord.after.mean < out.after.mean) {
      X = std::move(Y);
      out.after = chord.after;
      out.converged = chord.converged;
      out.kept_start = false;
    }
  }
  return out;
}

}  // namespace brenier::omt

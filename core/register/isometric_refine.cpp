// The refinement of g toward an isometry (isometric_refine.hpp): Gauss-Newton steps on the
// as-rigid-as-possible energy of f = phi2^-1 o g o phi1, with a barrier on each face's area.
#include "register/isometric_refine.hpp"

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

#include "common/error.hpp"
#include "mesh/topology.hpp"
#include "numeric/face_hessian.hpp"
#include "register/correspondence.hpp"

namespace brenier::registration {

namespace {

using Mat2 = Eigen::Matrix2d;
using Vec2 = Eigen::Vector2d;
using Mat32 = Eigen::Matrix<double, 3, 2>;

// The barrier's weight against the isometric term.
constexpr double kBarrier = 0.1;
// A step is halved at most this often before the refinement stops where it is.
constexpr int kHalvings = 14;
// Steps in a row that must each lower the energy by less than the tolerance to stop.
constexpr int kSmallSteps = 3;
// On the sphere, a face whose area ratio starts below this is collapsed: its barrier reads the
// ratio scaled to start here, and charges only shrinking below that.
constexpr double kCollapsed = 0.01;

Vec2 xy(const mesh::Vertices& X, int v) { return {X(v, 0), X(v, 1)}; }
Eigen::Vector3d xyz(const mesh::Vertices& X, int v) { return X.row(v).transpose(); }

double signed_area(const mesh::Vertices& U, int a, int b, int c) {
  return (U(b, 0) - U(a, 0)) * (U(c, 1) - U(a, 1)) - (U(b, 1) - U(a, 1)) * (U(c, 0) - U(a, 0));
}

// On the sphere, a face's orientation seen from outside: det(a, b, c) = a . ((b - a) x (c - a)),
// twice its chord triangle's area times the plane's distance from the centre (about 1 for
// the small triangles of a map), from the edges so that a tiny face keeps its sign.
double sphere_orientation(const mesh::Vertices& U, int a, int b, int c) {
  const Eigen::Vector3d p = xyz(U, a);
  return p.dot((xyz(U, b) - p).cross(xyz(U, c) - p));
}

// Two orthonormal tangents of the unit sphere at p: a vertex's unknowns on the sphere. Not the
// area refinement's basis (SphereGeometry::begin, another axis rule): the sphere's Marquardt
// shift scales each unknown by its own diagonal entry, so the steps depend on the basis, and
// with that one cow's bent pair went 0.0118 -> 0.0138 (bench/RESULTS.md, session 67).
Mat32 tangent_frame(const Eigen::Vector3d& p) {
  Eigen::Index k;
  p.cwiseAbs().minCoeff(&k);
  const Eigen::Vector3d t1 = p.cross(Eigen::Vector3d::Unit(k)).normalized();
  Mat32 T;
  T.col(0) = t1;
  T.col(1) = p.cross(t1).normalized();
  return T;
}

// The closest matrix with orthonormal columns to J (3 x 2), the polar factor: in closed form
// J (J^T J)^-1/2, the square root of the 2 x 2 C = J^T J being
// (C + sqrt(det C) I) / sqrt(tr C + 2 sqrt(det C)); by the SVD where J is nearly of rank one.
Mat32 nearest_isometry(const Mat32& J) {
  const Mat2 C = J.transpose() * J;
  const double det = C.determinant(), tr = C.trace();
  if (det > 1e-20 * tr * tr) {
    const double sd = std::sqrt(det);
    const Mat2 root = (C + sd * Mat2::Identity()) / std::sqrt(tr + 2 * sd);
    return J * root.inverse();
  }
  Eigen::JacobiSVD<Mat32> svd(J, Eigen::ComputeFullU | Eigen::ComputeFullV);
  return svd.matrixU().leftCols<2>() * svd.matrixV().transpose();
}

// One source face: its corners, the gradients g_k of the linear map from its own plane (so
// that T X^-1 = sum_k p_k g_k^T for corner images p_k) and its 3-D area.
struct Face {
  int v[3];
  Vec2 g[3];
  double area;
};

// Where each source vertex lands on the target: the point, the Jacobian of the chart's
// inverse on the target face that holds it (by the vertex's unknowns: the plane's axes, or on
// the sphere the tangent frame; filled only for an accepted place, by differentiate()), and
// that face with the barycentric coordinates.
struct Places {
  std::vector<Eigen::Vector3d> p;
  std::vector<Mat32> J;
  std::vector<Mat32> frame;  // on the sphere, each vertex's tangent frame
  std::vector<SurfacePoint> at;  // the target face and barycentric coordinates
};

// A face's share of the step's model: the rows of its Gauss-Newton Hessian and gradient for
// each corner, before the corners' unknowns are applied.
struct FaceModel {
  Vec2 gradient[3];  // minus the energy's gradient in each corner's chart coordinates
  Mat2 block[3][3];  // Hessian blocks between corners
};

class Refiner {
 public:
  Refiner(const mesh::TriMesh& source, const mesh::Vertices& mapped, const mesh::TriMesh& target,
          const mesh::Vertices& target_domain, const std::vector<int>& fixed, bool sphere)
      : target_(target), domain_(target_domain), sphere_(sphere), locator_(target.F, target_domain, sphere), U_(mapped) {
    // The chart's inverse on each target face: on the plane J = T D^-1 (T its 3-D edges, D its
    // domain edges), zero on a face the chart flattens to a segment; on the sphere it varies
    // over the face (sphere_jacobian) and only its area factor is kept here: the face's area
    // over det(a, b, c) of its corners in the chart (twice its chord triangle's area times the
    // plane's distance from the centre), so that a face mapped onto itself has ratio 1.
    chart_J_.assign(static_cast<size_t>(target.num_faces()), Mat32::Zero());
    area_factor_.assign(static_cast<size_t>(target.num_faces()), 0.0);
    for (int f = 0; f < target.num_faces(); ++f) {
      const int a = target.F(f, 0), b = target.F(f, 1), c = target.F(f, 2);
      Mat32 T;
      T.col(0) = (target.V.row(b) - target.V.row(a)).transpose();
      T.col(1) = (target.V.row(c) - target.V.row(a)).transpose();
      if (sphere) {  // over det(a, b, c), as the source faces' ratios read their images
        const double det = sphere_orientation(target_domain, a, b, c);
        const double factor = T.col(0).cross(T.col(1)).norm() / det;
        if (det > 0 && std::isfinite(factor)) area_factor_[static_cast<size_t>(f)] = factor;
        continue;
      }
      Mat2 D;
      D.col(0) = xy(target_domain, b) - xy(target_domain, a);
      D.col(1) = xy(target_domain, c) - xy(target_domain, a);
      const Mat32 J = T * D.inverse();
      if (std::abs(D.determinant()) > 0 && J.allFinite()) {
        chart_J_[static_cast<size_t>(f)] = J;
        area_factor_[static_cast<size_t>(f)] = J.col(0).cross(J.col(1)).norm();
      }
    }
    double orientation = 0;
    for (int f = 0; f < source.num_faces(); ++f) orientation += orient(U_, source.F(f, 0), source.F(f, 1), source.F(f, 2));
    sign_ = orientation < 0 ? -1.0 : 1.0;
    for (int f = 0; f < source.num_faces(); ++f) {
      Face face{};
      for (int k = 0; k < 3; ++k) face.v[k] = source.F(f, k);
      const Eigen::Vector3d e1 = source.V.row(face.v[1]) - source.V.row(face.v[0]);
      const Eigen::Vector3d e2 = source.V.row(face.v[2]) - source.V.row(face.v[0]);
      const double l = e1.norm(), twice = e1.cross(e2).norm();
      if (!(l > 0) || !(twice > 0)) continue;  // a degenerate source face constrains nothing
      Mat2 X;  // the face in its own plane
      X << l, e1.dot(e2) / l, 0, twice / l;
      const Mat2 P = X.inverse();
      face.g[1] = P.row(0).transpose();
      face.g[2] = P.row(1).transpose();
      face.g[0] = -face.g[1] - face.g[2];
      face.area = 0.5 * twice;
      area_ += face.area;
      faces_.push_back(face);
      checked_.push_back(sign_ * orient(U_, face.v[0], face.v[1], face.v[2]) > 0);
      scale_.push_back(1.0);
    }
    // Unknowns: none for a landmark, one for a boundary vertex that slides on the circle,
    // two for the rest (on the sphere, along its tangent frame).
    const int n = source.num_vertices();
    const std::vector<char> boundary = mesh::boundary_flags(source);
    kind_.assign(static_cast<size_t>(n), 2);
    for (int v = 0; v < n; ++v)
      if (boundary[static_cast<size_t>(v)]) kind_[static_cast<size_t>(v)] = fixed.empty() ? 0 : 1;
    for (int v : fixed) {
      if (v < 0 || v >= n) invalid("a fixed vertex is not a vertex of the source");
      kind_[static_cast<size_t>(v)] = 0;
    }
    mesh::Faces kept(static_cast<Eigen::Index>(faces_.size()), 3);
    for (size_t f = 0; f < faces_.size(); ++f) kept.row(static_cast<Eigen::Index>(f)) << faces_[f].v[0], faces_[f].v[1], faces_[f].v[2];
    hessian_ = std::make_unique<numeric::FaceHessian>(kept, kind_);
  }

  IsometricRefineResult run(const IsometricRefineOptions& o) {
    IsometricRefineResult out;
    out.mapped = U_;
    if (hessian_->size() == 0 || faces_.empty()) {
      out.converged = true;
      return out;
    }
    Places at = place(U_);
    accept(at);
    scale_collapsed();
    double e = out.energy_before = energy(U_, at);
    int small = 0;
    // An energy at round-off (a mesh onto itself) has nothing left to lower.
    constexpr double kNothing = 1e-20;
    while (out.iterations < o.max_iterations && small < kSmallSteps && e > kNothing) {
      if (o.keep_going && !o.keep_going(out.iterations, e)) fail(ErrorCode::kCancelled, "cancelled");
      const mesh::Vertices next = step(at);
      // The longest of 1, 1/2, 1/4, ... of the step that lowers the energy (infinite on a
      // face turned over) and shrinks no face to below a tenth of its area in the chart: a
      // step that nearly folds a face jumps across its barrier, where the model no longer
      // holds.
      bool taken = false;
      double t = 1;
      for (int h = 0; h <= kHalvings && !taken; ++h, t /= 2) {
        mesh::Vertices W = along(next, t);
        if (shrinks_a_face(W)) continue;
        Places at_w = place(W);
        if (!(energy(W, at_w) < e)) continue;
        U_ = std::move(W);
        at = std::move(at_w);
        accept(at);
        const double e_next = energy(U_, at);  // with the area factors of the new place
        small = e - e_next < o.tolerance * out.energy_before ? small + 1 : 0;
        e = e_next;
        taken = true;
        out.shortened_steps += h > 0;
      }
      if (!taken) break;  // no step along the model's direction lowers the energy
      ++out.iterations;
    }
    out.converged = small >= kSmallSteps || !(e > kNothing);
    out.energy_after = e;
    out.mapped = U_;
    out.located = std::move(at.at);
    return out;
  }

 private:
  // Each vertex of U on the target: by a walk from the target face that held it at the last
  // accepted place (most vertices stay in theirs from one step to the next, the rest move a
  // face or two), by the search tree where the walk fails. At 33K vertices the tree's queries
  // took a fifth of the refinement (bench/RESULTS.md, session 66).
  Places place(const mesh::Vertices& U) const {
    std::vector<SurfacePoint> at(static_cast<size_t>(U.rows()));
    std::vector<char> walked(at.size(), 0);
#pragma omp parallel for schedule(static)
    for (Eigen::Index v = 0; v < U.rows(); ++v) {
      const int f = hint_.empty() ? -1 : hint_[static_cast<size_t>(v)];
      walked[static_cast<size_t>(v)] = f >= 0 && locator_.walk(f, xyz(U, static_cast<int>(v)), at[static_cast<size_t>(v)]);
    }
    std::vector<Eigen::Index> lost;
    for (Eigen::Index v = 0; v < U.rows(); ++v)
      if (!walked[static_cast<size_t>(v)]) lost.push_back(v);
    if (!lost.empty()) {
      mesh::Vertices Q(static_cast<Eigen::Index>(lost.size()), 3);
      for (size_t i = 0; i < lost.size(); ++i) Q.row(static_cast<Eigen::Index>(i)) = U.row(lost[i]);
      const std::vector<SurfacePoint> found = locator_(Q);
      for (size_t i = 0; i < lost.size(); ++i) at[static_cast<size_t>(lost[i])] = found[i];
    }
    Places out;
    out.p.resize(at.size());
#pragma omp parallel for schedule(static)
    for (size_t v = 0; v < at.size(); ++v) {
      const SurfacePoint& s = at[v];
      out.p[v] = s.bary[0] * target_.V.row(target_.F(s.face, 0)).transpose() +
                 s.bary[1] * target_.V.row(target_.F(s.face, 1)).transpose() +
                 s.bary[2] * target_.V.row(target_.F(s.face, 2)).transpose();
    }
    out.at = std::move(at);
    return out;
  }

  // The chart inverse's Jacobians (and on the sphere the tangent frames) of an accepted place
  // at U_, which the next step's model needs; the trials' places need only their points.
  void differentiate(Places& at) const {
    at.J.resize(at.at.size());
    if (sphere_) at.frame.resize(at.at.size());
#pragma omp parallel for schedule(static)
    for (size_t v = 0; v < at.at.size(); ++v) {
      const SurfacePoint& s = at.at[v];
      if (!sphere_) {
        at.J[v] = chart_J_[static_cast<size_t>(s.face)];
        continue;
      }
      const Eigen::Vector3d x = xyz(U_, static_cast<int>(v)).normalized();
      at.frame[v] = tangent_frame(x);
      at.J[v] = sphere_jacobian(s, x) * at.frame[v];
    }
  }

  // On the sphere, the derivative of the target point phi2^-1(x) in x (3 x 3; zero along x):
  // x's coordinates on the chord triangle a, b = a + e1, c = a + e2 that its ray crosses are
  // lambda_b = d . (e2 x a) / (x . N), lambda_c = d . (a x e1) / (x . N) (d = x - a, N = e1 x
  // e2; correspondence.cpp), whose gradients are (e2 x a - lambda_b N) / (x . N) and
  // (a x e1 - lambda_c N) / (x . N), and the target point is linear in them. Zero where the
  // ray meets the triangle edge-on.
  Eigen::Matrix3d sphere_jacobian(const SurfacePoint& s, const Eigen::Vector3d& x) const {
    const int ia = target_.F(s.face, 0), ib = target_.F(s.face, 1), ic = target_.F(s.face, 2);
    const Eigen::Vector3d a = xyz(domain_, ia), e1 = xyz(domain_, ib) - a, e2 = xyz(domain_, ic) - a;
    const Eigen::Vector3d N = e1.cross(e2);
    const double xn = x.dot(N);
    if (!(xn > 0)) return Eigen::Matrix3d::Zero();
    const Eigen::Vector3d gb = (e2.cross(a) - s.bary[1] * N) / xn, gc = (a.cross(e1) - s.bary[2] * N) / xn;
    const Eigen::Matrix3d D = (xyz(target_.V, ib) - xyz(target_.V, ia)) * gb.transpose() +
                              (xyz(target_.V, ic) - xyz(target_.V, ia)) * gc.transpose();
    return D.allFinite() ? D : Eigen::Matrix3d::Zero();
  }

  // The face's orientation in the domain: its signed area on the plane, det on the sphere.
  double orient(const mesh::Vertices& U, int a, int b, int c) const {
    return sphere_ ? sphere_orientation(U, a, b, c) : signed_area(U, a, b, c);
  }

  // The chart point under face f's corners at U: the plane's centroid; on the sphere the mean
  // of the corners, whose ray crosses the target's chord triangles where the centroid's does.
  Eigen::Vector3d centroid(const mesh::Vertices& U, const Face& F) const {
    Eigen::Vector3d c = (xyz(U, F.v[0]) + xyz(U, F.v[1]) + xyz(U, F.v[2])) / 3;
    if (!sphere_) c.z() = 0;
    return c;
  }

  // A new accepted place (at U_): its target faces start the next search, its area factors
  // serve the barrier until the next one, and its Jacobians the next step's model.
  void accept(Places& at) {
    differentiate(at);
    hint_.resize(at.at.size());
    for (size_t v = 0; v < at.at.size(); ++v) hint_[v] = at.at[v].face;
    read_area_factors();
  }

  // rho_f: the chart inverse's area factor (|J_t e1 x J_t e2|; on the sphere the target face's
  // area over its corners' det, times 2) on the target face t under
  // face f's centroid, read at the accepted place and held through a step's trials, so that
  // s stays linear in each corner as the step's model has it. Read afresh at each trial, a
  // corner crossing into a target face of another area factor made the barrier jump, and one
  // nearly folded face refused every full step of the whole mesh (lion-head's twisted pair).
  // Not the chord triangle's own factor: on a face spanning a curl of the target that is far
  // below the surface's, and its barrier then pushed faces apart against the model, whose
  // steps then folded faces at every length. Not the mean of the corners' faces' factors
  // either: a corner on a target vertex lies on any of its faces, and a mesh registered onto
  // itself drifted off the identity.
  void read_area_factors() {
    rho_.resize(faces_.size());
    std::vector<char> walked(faces_.size(), 0);
#pragma omp parallel for schedule(static)
    for (size_t f = 0; f < faces_.size(); ++f) {  // from the first corner's target face
      const Face& F = faces_[f];
      SurfacePoint under;
      if (locator_.walk(hint_[static_cast<size_t>(F.v[0])], centroid(U_, F), under)) {
        rho_[f] = area_factor_[static_cast<size_t>(under.face)];
        walked[f] = 1;
      }
    }
    std::vector<size_t> lost;
    for (size_t f = 0; f < faces_.size(); ++f)
      if (!walked[f]) lost.push_back(f);
    if (lost.empty()) return;
    mesh::Vertices centroids(static_cast<Eigen::Index>(lost.size()), 3);
    for (size_t i = 0; i < lost.size(); ++i)
      centroids.row(static_cast<Eigen::Index>(i)) = centroid(U_, faces_[lost[i]]).transpose();
    const std::vector<SurfacePoint> found = locator_(centroids);
    for (size_t i = 0; i < lost.size(); ++i) rho_[lost[i]] = area_factor_[static_cast<size_t>(found[i].face)];
  }

  // T X^-1 of face f: its image's 3-D edges (chords of the target) over its own.
  Mat32 jacobian(const Places& at, size_t f) const {
    const Face& F = faces_[f];
    Mat32 J = Mat32::Zero();
    for (int k = 0; k < 3; ++k) J += at.p[static_cast<size_t>(F.v[k])] * F.g[k].transpose();
    return J;
  }

  // The image's area on the target over the face's own, signed by its orientation in the
  // chart: det E rho_f / (2 area); zero where the face turns over in the chart.
  double area_ratio(const mesh::Vertices& U, size_t f) const {
    const Face& F = faces_[f];
    return sign_ * orient(U, F.v[0], F.v[1], F.v[2]) * rho_[f] * scale_[f] / (2 * F.area);
  }

  // The barrier beta (s + 1/s - 2), zero from 1 up on a collapsed face (scale_ > 1).
  bool barrier_applies(size_t f, double s) const { return !(scale_[f] > 1 && s >= 1); }

  // On the sphere, faces whose image starts collapsed, at area ratios down to 1e-9 where one
  // map crowds a part of the surface the other does not (cow's legs): their ratio is read
  // scaled to start at kCollapsed, and their barrier charges only shrinking. Unscaled, a
  // barrier of 1e8 per unit area on a few faces made the whole energy, and the steps went
  // into them alone. Not on the disk, where it moved the medians by -0.0002 to +0.0009
  // (mannequin-devil's stretched pair, conformal route; bench/RESULTS.md, session 67).
  void scale_collapsed() {
    if (!sphere_) return;
    for (size_t f = 0; f < faces_.size(); ++f) {
      if (!checked_[f] || !(rho_[f] > 0)) continue;
      const double s = area_ratio(U_, f);
      if (s < kCollapsed) scale_[f] = kCollapsed / s;
    }
  }

  // The area-weighted mean over the faces of |J - R|^2 (R the nearest isometry) plus the
  // barrier beta (s + 1/s - 2) on the area ratio s: zero at an isometry, infinite where a face
  // that began the right way round turns over.
  // Faces in parallel, summed in their order (the same energy on any number of threads).
  double energy(const mesh::Vertices& U, const Places& at) const {
    std::vector<double> per_face(faces_.size());
#pragma omp parallel for schedule(static)
    for (size_t f = 0; f < faces_.size(); ++f) {
      const Mat32 J = jacobian(at, f);
      double e = faces_[f].area * (J - nearest_isometry(J)).squaredNorm();
      if (checked_[f] && rho_[f] > 0) {  // no barrier where the image has no area
        const double s = area_ratio(U, f);
        if (!(s > 0)) e = std::numeric_limits<double>::infinity();
        else if (barrier_applies(f, s)) e += faces_[f].area * kBarrier * (s + 1 / s - 2);
      }
      per_face[f] = e;
    }
    double e = 0;
    for (double x : per_face) e += x;
    return e / area_;
  }

  // The face's Gauss-Newton model. The image points are linearized through the chart's
  // inverse (p_v + J_v d_v) and R is held, which gives blocks area (g_j . g_k) J_j^T J_k. Held R
  // charges every turn of the face as a stretch, though the energy's own curvature is lower
  // along its rotation modes (Smith, Goes, Kim 2019, the as-rigid-as-possible eigensystem):
  // in its plane along R Rot90 / sqrt 2 it is 1 - 2 / (s1 + s2), out of its plane along
  // n v_i^T (n its normal, v_i, s_i J's right singular vectors and values) 1 - 1/s_i, in
  // units where a stretch costs 1. The model keeps the positive part of each: with R held,
  // a face that turns or slides over the curved target (it tilts with it) was stiff, and the
  // twisted pairs crept 2 % per step for 100 steps. The barrier's model is psi + psi' ds +
  // psi'' ds^2 / 2, ds linear in each corner, psi'' > 0.
  FaceModel face_model(const Places& at, size_t f) const {
    const Face& F = faces_[f];
    const Mat32 J = jacobian(at, f);
    const Mat32 R = nearest_isometry(J);
    const Mat2 C = J.transpose() * J;
    const Eigen::SelfAdjointEigenSolver<Mat2> es(C);
    const double s0 = std::sqrt(std::max(0.0, es.eigenvalues()[0])), s1 = std::sqrt(std::max(0.0, es.eigenvalues()[1]));
    Mat2 rot90;
    rot90 << 0, -1, 1, 0;
    const Mat32 twist = R * rot90 / std::sqrt(2.0);
    Eigen::Vector3d normal = J.col(0).cross(J.col(1));
    const double nn = normal.norm();
    if (nn > 0) normal /= nn;
    // (mode in the corners' unknowns, the share of the model's stiffness taken off along it)
    Vec2 mode[3][3];
    double relief[3] = {s0 + s1 > 0 ? std::min(1.0, 2 / (s0 + s1)) : 0.0, nn > 0 && s0 > 0 ? std::min(1.0, 1 / s0) : 0.0,
                        nn > 0 && s1 > 0 ? std::min(1.0, 1 / s1) : 0.0};
    for (int k = 0; k < 3; ++k) {
      const Mat32& Jk = at.J[static_cast<size_t>(F.v[k])];
      mode[0][k] = Jk.transpose() * twist * F.g[k];
      mode[1][k] = Jk.transpose() * normal * es.eigenvectors().col(0).dot(F.g[k]);
      mode[2][k] = Jk.transpose() * normal * es.eigenvectors().col(1).dot(F.g[k]);
    }
    Vec2 ds[3] = {Vec2::Zero(), Vec2::Zero(), Vec2::Zero()};
    double slope = 0, curvature = 0;
    if (checked_[f] && rho_[f] > 0) {
      const double per_det = sign_ * rho_[f] * scale_[f] / (2 * F.area);  // s per unit of the chart's det E
      if (sphere_) {  // d det(a, b, c) / da = b x c, and so round; in each corner's tangent frame
        for (int k = 0; k < 3; ++k)
          ds[k] = per_det * at.frame[static_cast<size_t>(F.v[k])].transpose() *
                  xyz(U_, F.v[(k + 1) % 3]).cross(xyz(U_, F.v[(k + 2) % 3]));
      } else {
        const Vec2 a = xy(U_, F.v[0]), b = xy(U_, F.v[1]), c = xy(U_, F.v[2]);
        ds[1] = per_det * Vec2((c - a).y(), -(c - a).x());
        ds[2] = per_det * Vec2(-(b - a).y(), (b - a).x());
        ds[0] = -ds[1] - ds[2];
      }
      const double s = area_ratio(U_, f);
      if (barrier_applies(f, s)) {
        slope = F.area * kBarrier * (1 - 1 / (s * s));
        curvature = F.area * kBarrier * 2 / (s * s * s);
      }
    }
    FaceModel m;
    for (int j = 0; j < 3; ++j) {
      const Mat32& Jj = at.J[static_cast<size_t>(F.v[j])];
      m.gradient[j] = F.area * Jj.transpose() * (R - J) * F.g[j] - slope * ds[j];
      for (int k = 0; k < 3; ++k) {
        Mat2 K = F.g[j].dot(F.g[k]) * Jj.transpose() * at.J[static_cast<size_t>(F.v[k])];
        for (int i = 0; i < 3; ++i) K -= relief[i] * mode[i][j] * mode[i][k].transpose();
        m.block[j][k] = F.area * K + curvature * ds[j] * ds[k].transpose();
      }
    }
    return m;
  }

  // The columns of B are vertex v's unknowns (kind_ of them; the others zero) in its chart
  // coordinates: the plane's axes (on the sphere the tangent frame's), or the circle's tangent.
  Mat2 basis(int v) const {
    const int k = kind_[static_cast<size_t>(v)];
    Mat2 B = Mat2::Zero();
    if (k == 2) B.setIdentity();
    if (k == 1) B.col(0) = Vec2(-U_(v, 1), U_(v, 0)).normalized();
    return B;
  }

  // The model's minimizer: U + d, boundary vertices moved along their tangent (put back on
  // the circle by along()), on the sphere every vertex along its tangent frame (put back on
  // the sphere by along()), landmarks held. The faces' models go into the Hessian's fixed pattern
  // (numeric/face_hessian.hpp), each block in its corners' unknowns B_j^T M_jk B_k.
  mesh::Vertices step(const Places& at) {
    const std::vector<numeric::Dof>& dof = hessian_->dof();
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(hessian_->size());
    std::vector<FaceModel> models(faces_.size());
#pragma omp parallel for schedule(static)
    for (size_t f = 0; f < faces_.size(); ++f) models[f] = face_model(at, f);
    hessian_->clear();
    for (size_t f = 0; f < faces_.size(); ++f) {
      const FaceModel& m = models[f];
      Mat2 B[3];
      for (int j = 0; j < 3; ++j) B[j] = basis(faces_[f].v[j]);
      numeric::FaceHessian::Mat6 H;
      for (int j = 0; j < 3; ++j) {
        const numeric::Dof& d = dof[static_cast<size_t>(faces_[f].v[j])];
        const Vec2 g = B[j].transpose() * m.gradient[j];
        for (int a = 0; a < d.count; ++a) rhs[d.offset + a] += g[a];
        for (int k = 0; k < 3; ++k) H.block<2, 2>(2 * j, 2 * k) = B[j].transpose() * m.block[j][k] * B[k];
      }
      hessian_->add(static_cast<Eigen::Index>(f), H);
    }
    // A Levenberg-Marquardt shift: a vertex on a target face the chart flattens has no
    // Jacobian and would leave the system singular. On the plane, 1e-6 of the mean diagonal.
    // On the sphere, 1e-6 of each diagonal entry (Marquardt's scaling) and of the median one:
    // where one sphere map crowds a part the other does not (cow's legs) the diagonal spans
    // 1e-2 to 1e24, and a shift of the mean held every other vertex still while the rows of
    // 1e24 needed their own. On the plane that rule made lion-head's twisted pair, OMT route,
    // worse (0.0191 -> 0.0219; bench/RESULTS.md, session 67).
    const int n = hessian_->size();
    if (sphere_) {
      Eigen::VectorXd diagonal(n);
      for (int r = 0; r < n; ++r) diagonal[r] = hessian_->diagonal(r);
      auto middle = diagonal.data() + diagonal.size() / 2;
      std::nth_element(diagonal.data(), middle, diagonal.data() + diagonal.size());
      const double floor = *middle;
      for (int r = 0; r < n; ++r) hessian_->diagonal(r) += 1e-6 * (hessian_->diagonal(r) + floor);
    } else {
      hessian_->shift_diagonal_by_mean(1e-6);
    }
    if (!hessian_->factorize()) fail(ErrorCode::kInternal, "the isometric refinement's system is not positive definite");
    const Eigen::VectorXd z = hessian_->solve(rhs);
    mesh::Vertices next = U_;
    for (int v = 0; v < U_.rows(); ++v) {
      const numeric::Dof& d = dof[static_cast<size_t>(v)];
      if (d.count == 0) continue;
      Vec2 dz = Vec2::Zero();
      dz.head(d.count) = z.segment(d.offset, d.count);
      if (sphere_) {
        next.row(v) += (at.frame[static_cast<size_t>(v)] * (basis(v) * dz)).transpose();
        continue;
      }
      const Vec2 u = xy(U_, v) + basis(v) * dz;
      next(v, 0) = u.x();
      next(v, 1) = u.y();
    }
    return next;
  }

  bool shrinks_a_face(const mesh::Vertices& W) const {
    for (size_t f = 0; f < faces_.size(); ++f) {
      if (!checked_[f]) continue;
      const int a = faces_[f].v[0], b = faces_[f].v[1], c = faces_[f].v[2];
      if (!(sign_ * orient(W, a, b, c) > 0.1 * sign_ * orient(U_, a, b, c))) return true;
    }
    return false;
  }

  // U + t (next - U), boundary vertices put back on the circle, on the sphere every vertex
  // that moves put back on the sphere.
  mesh::Vertices along(const mesh::Vertices& next, double t) const {
    mesh::Vertices W = U_ + t * (next - U_);
    for (int v = 0; v < W.rows(); ++v) {
      if (kind_[static_cast<size_t>(v)] == 1) W.row(v) /= std::hypot(W(v, 0), W(v, 1));
      if (sphere_ && kind_[static_cast<size_t>(v)] != 0) W.row(v).normalize();
    }
    return W;
  }

  const mesh::TriMesh& target_;
  const mesh::Vertices& domain_;  // the target's vertices in its chart
  bool sphere_;
  DomainLocator locator_;
  std::vector<Mat32> chart_J_;  // on the plane, per target face, the Jacobian of the chart's inverse
  std::vector<double> area_factor_;  // per target face, the chart inverse's area factor
  mesh::Vertices U_;            // the accepted place
  std::vector<int> hint_;       // per source vertex, its target face at the accepted place
  double sign_ = 1, area_ = 0;
  std::vector<Face> faces_;
  std::vector<char> checked_;  // the face's image was the right way round at the start
  std::vector<double> rho_;    // per face, the chart inverse's area factor at the accepted place
  std::vector<double> scale_;  // per face, its area ratio's scale (scale_collapsed)
  std::vector<char> kind_;  // per vertex, its unknowns: 0 held, 1 on the circle, 2 free
  std::unique_ptr<numeric::FaceHessian> hessian_;  // over faces_' corners, made in the constructor
};

}  // namespace

IsometricRefineResult refine_isometric(const mesh::TriMesh& source, const mesh::Vertices& mapped,
                                       const mesh::TriMesh& target, const mesh::Vertices& target_domain,
                                       const std::vector<int>& fixed, bool sphere, const IsometricRefineOptions& options) {
  if (mapped.rows() != source.V.rows()) invalid("the refinement needs one domain point per source vertex");
  if (target_domain.rows() != target.V.rows()) invalid("the refinement needs one domain point per target vertex");
  Refiner r(source, mapped, target, target_domain, fixed, sphere);
  return r.run(options);
}

}  // namespace brenier::registration

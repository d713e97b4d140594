#include "omt/fold_repair.hpp"

#include <Eigen/Geometry>
#include <LBFGS.h>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "common/error.hpp"
#include "conformal/conformal_map.hpp"
#include "mesh/geometry.hpp"
#include "quality/quality.hpp"

namespace brenier::omt {
namespace {

struct BarrierFace {
  std::array<int, 3> v;     // indices into the positions, counter-clockwise in the reference
  Eigen::Matrix2d ref_inv;  // inverse of [q1 - q0, q2 - q0] of the reference triangle
  double weight = 0;        // the reference triangle's area
};

// The reference triangle of a face with 3-D corners a, b, c, scaled to area `area`.
BarrierFace barrier_face(int i, int j, int k, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                         const Eigen::Vector3d& c, double area) {
  // The face in its own plane: q0 = 0, q1 on the first axis, q2 above it (counter-clockwise).
  const Eigen::Vector3d e = b - a, g = c - a;
  const double len = e.norm();
  const Eigen::Vector3d u = e / len, n = e.cross(g);
  const Eigen::Vector3d w = n.normalized().cross(u);
  Eigen::Matrix2d Q;
  Q << len, g.dot(u), 0, g.dot(w);
  Q *= std::sqrt(area / (0.5 * n.norm()));  // scaled to the target area
  BarrierFace f;
  f.v = {i, j, k};
  f.ref_inv = Q.inverse();
  f.weight = area;
  return f;
}

// The energy of fold_repair.hpp over the free vertices, for L-BFGS. A free vertex is
// x = y / |y| for unknowns y in R^3, so every trial point lies on the sphere. The face's
// signed area is read as det(a, b, c) / 2 (the chord triangle's area times its plane's
// distance from the centre: positive exactly when it faces outward, the fold test), so
// det J = det(a, b, c) / (2 A_target); |J|_F^2 is that of the chord triangle's edges
// against the reference's.
struct BarrierEnergy {
  const std::vector<BarrierFace>& faces;
  mesh::Vertices& X;
  const std::vector<int>& var;   // row of X -> its first unknown, or -1 when fixed
  const std::vector<int>& rows;  // the free rows, in the unknowns' order
  double theta, eps = 1;
  double min_det = 0;

  void load(const Eigen::VectorXd& y) {
    for (int r : rows) X.row(r) = y.segment<3>(var[r]).normalized().transpose();
  }
  double operator()(const Eigen::VectorXd& y, Eigen::VectorXd& grad) {
    load(y);
    grad.setZero(y.size());
    Eigen::VectorXd gx = Eigen::VectorXd::Zero(y.size());  // gradient in x
    double E = 0;
    min_det = std::numeric_limits<double>::infinity();
    for (const BarrierFace& f : faces) {
      const Eigen::Vector3d a = X.row(f.v[0]), b = X.row(f.v[1]), c = X.row(f.v[2]);
      Eigen::Matrix<double, 3, 2> M;
      M.col(0) = b - a;
      M.col(1) = c - a;
      const Eigen::Matrix<double, 3, 2> J = M * f.ref_inv;
      const double D = a.dot(b.cross(c)) / (2 * f.weight), T = J.squaredNorm();
      min_det = std::min(min_det, D);
      const double s = std::sqrt(eps * eps + D * D), chi = 0.5 * (D + s), dchi = 0.5 * (1 + D / s);
      const double num = theta * (D * D + 1) + (1 - theta) * T;
      E += f.weight * num / chi;
      const double dD = f.weight * ((theta * 2 * D) / chi - num * dchi / (chi * chi)) / (2 * f.weight);
      const Eigen::Matrix<double, 3, 2> dM = f.weight * (1 - theta) * 2 / chi * J * f.ref_inv.transpose();
      auto add = [&](int row, const Eigen::Vector3d& d) {
        if (var[row] >= 0) gx.segment<3>(var[row]) += d;
      };
      add(f.v[0], dD * b.cross(c) - dM.col(0) - dM.col(1));
      add(f.v[1], dD * c.cross(a) + dM.col(0));
      add(f.v[2], dD * a.cross(b) + dM.col(1));
    }
    for (int r : rows) {  // through x = y / |y|: (I - x x^T) g / |y|
      const Eigen::Vector3d x = X.row(r).transpose(), g = gx.segment<3>(var[r]);
      grad.segment<3>(var[r]) = (g - x * x.dot(g)) / y.segment<3>(var[r]).norm();
    }
    return E;
  }
};

// Moves the rows of X (points on the unit sphere) with free[row] != 0 to minimize the energy
// over `faces`, keeping them on the sphere; theta weighs the area term. Returns the number
// of `faces` whose chord triangles still do not face outward (0 on success).
int untangle_by_barrier(const std::vector<BarrierFace>& faces, mesh::Vertices& X, const std::vector<char>& free,
                        double theta = 0.9) {
  std::vector<int> var(X.rows(), -1), rows;
  int n = 0;
  for (Eigen::Index r = 0; r < X.rows(); ++r)
    if (free[r]) var[r] = n, n += 3, rows.push_back(static_cast<int>(r));
  BarrierEnergy energy{faces, X, var, rows, theta};
  Eigen::VectorXd y(n), grad(n);
  for (int r : rows) y.segment<3>(var[r]) = X.row(r).transpose();
  energy.eps = 1;
  energy(y, grad);
  // eps from the smallest det J: chi(min det, eps) = mu, i.e. eps = 2 sqrt(mu (mu - min det)),
  // mu shrinking with the energy's relative decrease (the paper's schedule).
  auto eps_for = [](double mu, double d) { return d < mu ? 2 * std::sqrt(mu * (mu - d)) : 1e-12; };
  energy.eps = eps_for(0.1, energy.min_det);
  LBFGSpp::LBFGSParam<double> param;
  param.epsilon = 1e-9;
  param.max_iterations = 400;
  param.max_linesearch = 40;
  for (int outer = 0; outer < 60; ++outer) {
    const double E_prev = energy(y, grad);
    LBFGSpp::LBFGSSolver<double> solver(param);
    double fx = E_prev;
    try {
      solver.minimize(energy, y, fx);
    } catch (const std::exception&) {
      // a line search that cannot lower the energy further leaves y at its best point
    }
    const double E = energy(y, grad);
    if (energy.min_det > 0 && outer > 0 && energy.eps < 1e-9) break;
    const double sigma = std::max(1 - E / E_prev, 0.1);
    const double s = std::sqrt(energy.eps * energy.eps + energy.min_det * energy.min_det);
    const double mu = (1 - sigma) * 0.5 * (energy.min_det + s);
    energy.eps = eps_for(mu, energy.min_det);
  }
  energy(y, grad);
  int folds = 0;
  for (const BarrierFace& f : faces) folds += !(X.row(f.v[0]).dot(X.row(f.v[1]).cross(X.row(f.v[2]))) > 0);
  return folds;
}

}  // namespace

int repair_sphere_folds_by_barrier(const mesh::TriMesh& m, mesh::Vertices& X, int& folded,
                                   const std::function<bool(int round, int folds)>& keep_going) {
  const int nv = m.num_vertices(), nf = m.num_faces();
  auto folded_face = [&](const mesh::Vertices& Z, int f) { return conformal::face_folded(m, Z, f, true); };
  auto count_folds = [&](const mesh::Vertices& Z) {
    int k = 0;
    for (int f = 0; f < nf; ++f) k += folded_face(Z, f);
    return k;
  };
  folded = count_folds(X);
  auto distortion = [&](const mesh::Vertices& Z) {
    const Eigen::VectorXd r = quality::area_log_ratios(m, Z);
    double sum = 0;
    for (Eigen::Index f = 0; f < r.size(); ++f) sum += std::abs(r[f]);
    return sum / static_cast<double>(r.size());
  };
  const double allowed = distortion(X);
  const Eigen::VectorXd area = mesh::face_areas(m);
  std::vector<std::vector<int>> star(nv), ring(nv);
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) {
      star[m.F(f, k)].push_back(f);
      ring[m.F(f, k)].push_back(m.F(f, (k + 1) % 3));
    }
  // Target areas in the energy's measure det(a, b, c) / 2, whose sum is the map's.
  auto target_scale = [&] {
    double total = 0;
    for (int f = 0; f < nf; ++f) total += 0.5 * X.row(m.F(f, 0)).dot(X.row(m.F(f, 1)).cross(X.row(m.F(f, 2))));
    return total / area.sum();
  };
  double scale = target_scale();
  int moved = 0;
  long work = 0;
  bool out_of_budget = false;
  std::vector<char> tried(nf, 0);
  for (int round = 0; round < nf && folded > 0 && !out_of_budget; ++round) {  // each face seeds once
    int seed = -1;
    for (int f = 0; f < nf && seed < 0; ++f)
      if (!tried[f] && folded_face(X, f)) seed = f;
    if (seed < 0) break;
    if (keep_going && !keep_going(round, folded)) fail(ErrorCode::kCancelled, "fold repair cancelled");
    tried[seed] = 1;
    int last_free = -1;
    for (int rings : {1, 2, 4, 8, 16}) {
      // The vertices within `rings` rings of the seed face, and the faces around them.
      std::vector<int> dist(nv, -1), layer;
      for (int k = 0; k < 3; ++k) dist[m.F(seed, k)] = 0, layer.push_back(m.F(seed, k));
      for (int r = 0; r < rings; ++r) {
        std::vector<int> next;
        for (int v : layer)
          for (int w : ring[v])
            if (dist[w] < 0) dist[w] = r + 1, next.push_back(w);
        layer = std::move(next);
      }
      std::vector<char> is_free(nv, 0), seen(nf, 0);
      int nfree = 0;
      std::vector<BarrierFace> faces;
      for (int v = 0; v < nv; ++v)
        if (dist[v] >= 0) {
          is_free[v] = 1, ++nfree;
          for (int f : star[v])
            if (!seen[f]) {
              seen[f] = 1;
              faces.push_back(barrier_face(m.F(f, 0), m.F(f, 1), m.F(f, 2), m.V.row(m.F(f, 0)), m.V.row(m.F(f, 1)),
                                           m.V.row(m.F(f, 2)), area[f] * scale));
            }
        }
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
      untangle_by_barrier(faces, back, is_free);
      if (!back.allFinite()) continue;
      const int left = count_folds(back);
      const double after = distortion(back);
      // A region untangled inside a fixed ring can still wrap around the sphere with every
      // face turned outward (cactus and u did, covering it 4 times): only a repair that
      // leaves the map's degree at 1 is a repair.
      if (left < folded && after <= allowed && quality::covers_once(quality::sphere_degree(m.F, back))) {
        X = std::move(back);
        folded = left;
        moved += nfree;
        scale = target_scale();
        break;
      }
    }
  }
  return moved;
}

}  // namespace brenier::omt

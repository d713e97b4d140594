#include "conformal/yamabe.hpp"

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <vector>

#include "common/check.hpp"
#include "common/error.hpp"

namespace brenier::conformal {

Eigen::VectorXd curvature(const IntrinsicTriangulation& T, const Eigen::VectorXd& u) {
  const int nv = T.num_vertices();
  Eigen::VectorXd K(nv);
  const auto& bnd = T.boundary_vertex();
  for (int v = 0; v < nv; ++v) K[v] = bnd[v] ? std::numbers::pi : 2 * std::numbers::pi;
  for (int f = 0; f < T.num_faces(); ++f) {
    int h0 = T.face_halfedge(f), h1 = T.next(h0), h2 = T.next(h1);
    double l0 = T.length(h0, u), l1 = T.length(h1, u), l2 = T.length(h2, u);
    // The angle at origin(h) is opposite the edge of next(h).
    K[T.origin(h0)] -= corner_angle(l1, l2, l0);
    K[T.origin(h1)] -= corner_angle(l2, l0, l1);
    K[T.origin(h2)] -= corner_angle(l0, l1, l2);
  }
  return K;
}

Eigen::SparseMatrix<double> curvature_jacobian(const IntrinsicTriangulation& T,
                                               const Eigen::VectorXd& u) {
  const int nv = T.num_vertices();
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(static_cast<size_t>(T.num_halfedges()) * 4);
  for (int f = 0; f < T.num_faces(); ++f) {
    int h[3] = {T.face_halfedge(f), 0, 0};
    h[1] = T.next(h[0]);
    h[2] = T.next(h[1]);
    double l[3] = {T.length(h[0], u), T.length(h[1], u), T.length(h[2], u)};
    for (int k = 0; k < 3; ++k) {
      // Edge of h[k] joins origin(h[k]) and origin(h[k+1]); its opposite corner's cot.
      double w = 0.5 * corner_cot(l[k], l[(k + 1) % 3], l[(k + 2) % 3]);
      int i = T.origin(h[k]), j = T.origin(h[(k + 1) % 3]);
      trip.emplace_back(i, j, -w);
      trip.emplace_back(j, i, -w);
      trip.emplace_back(i, i, w);
      trip.emplace_back(j, j, w);
    }
  }
  Eigen::SparseMatrix<double> H(nv, nv);
  H.setFromTriplets(trip.begin(), trip.end());
  return H;
}

namespace {

// Keeps the rows and columns of the free vertices (index[i] >= 0), renumbered.
Eigen::SparseMatrix<double> restrict_free(const Eigen::SparseMatrix<double>& H,
                                          const std::vector<int>& index, int nfree) {
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(H.nonZeros());
  for (int c = 0; c < H.outerSize(); ++c)
    for (Eigen::SparseMatrix<double>::InnerIterator it(H, c); it; ++it) {
      int r = index[it.row()], k = index[it.col()];
      if (r >= 0 && k >= 0) trip.emplace_back(r, k, it.value());
    }
  Eigen::SparseMatrix<double> R(nfree, nfree);
  R.setFromTriplets(trip.begin(), trip.end());
  return R;
}

// The kept factorization of the Newton system: LDL^T of J with J + c w w^T handled by
// Sherman-Morrison (aw = J^{-1} w), or Cholesky of H alone.
struct Factor {
  bool ready = false;
  bool use_ldlt = true;
  Eigen::VectorXd w, aw;
  double c = 0;
  template <typename LDLT, typename LLT>
  Eigen::VectorXd solve(const Eigen::VectorXd& b, LDLT& ldlt, LLT& llt) const {
    if (!use_ldlt) return llt.solve(b);
    Eigen::VectorXd x = ldlt.solve(b);
    if (c != 0) x -= aw * (c * w.dot(x) / (1.0 + c * w.dot(aw)));
    return x;
  }
};

}  // namespace

YamabeResult solve_yamabe(IntrinsicTriangulation& T, const TargetCurvature& target,
                          const Eigen::VectorXd& u0, const std::vector<char>& fixed,
                          const YamabeOptions& opt) {
  const int nv = T.num_vertices();
  BRENIER_CHECK(u0.size() == nv, "u0 has " << u0.size() << " entries for " << nv << " vertices");
  BRENIER_CHECK(static_cast<int>(fixed.size()) == nv, "fixed mask has " << fixed.size() << " entries");
  std::vector<int> index(nv, -1);
  int nfree = 0;
  for (int i = 0; i < nv; ++i)
    if (!fixed[i]) index[i] = nfree++;
  BRENIER_CHECK(nfree < nv, "at least one vertex must be fixed (the constants are H's null space)");
  // Only free vertices have a curvature equation; fixed ones keep their factor.
  auto residual = [&](const Target& tg, const Eigen::VectorXd& u) {
    Eigen::VectorXd g = tg.K - curvature(T, u);
    for (int i = 0; i < nv; ++i)
      if (fixed[i]) g[i] = 0;
    return g;
  };
  YamabeResult r;
  r.u = u0;
  if (T.make_delaunay(r.u) < 0)
    fail(ErrorCode::kInvalidArgument,
         "the starting metric cannot be made Delaunay (a degenerate triangle at the boundary)");
  Target tg = target(T, r.u);
  Eigen::VectorXd g = residual(tg, r.u);
  r.residual = g.cwiseAbs().maxCoeff();

  // H - M is symmetric but may be indefinite (M lowers the boundary block), so it is factored
  // LDL^T; CHOLMOD's own messages are silenced, failures are checked through info().
  Eigen::CholmodSimplicialLDLT<Eigen::SparseMatrix<double>> ldlt;
  Eigen::CholmodSupernodalLLT<Eigen::SparseMatrix<double>> llt;
  ldlt.cholmod().print = 0;
  llt.cholmod().print = 0;
  std::vector<double> history;
  Factor factor;
  for (r.iterations = 0; r.iterations < opt.max_iterations; ++r.iterations) {
    if (r.residual <= opt.tolerance) break;
    // Newton step (eq. 3.4, Alg. 1 line 8, with the targets' own derivative):
    // (H - M + c w w^T) du = Kbar - K on the free vertices, du = 0 on the fixed ones.
    Eigen::SparseMatrix<double> Hfull = curvature_jacobian(T, r.u);
    auto reduce = [&](const Eigen::VectorXd& x) {
      Eigen::VectorXd y(nfree);
      for (int i = 0; i < nv; ++i)
        if (index[i] >= 0) y[index[i]] = x[i];
      return y;
    };
    // The system J d = g with J = H - M + c w w^T (H alone when the targets do not depend on
    // u). A factorization costs far more than a solve (0.6-1.5 s against 0.03 s at 133K
    // vertices), so the last one is kept and reused as a preconditioner: refinement
    // d <- d + P^{-1} (g - J d) with P the stale J, to the accuracy inexact Newton needs
    // (Eisenstat-Walker: relative residual below min(1e-2, |g|)). Only when that stalls is
    // J factored afresh (LDL^T: J can be indefinite, M lowers the boundary block; if even
    // that fails, H's Cholesky), keeping Newton's quadratic convergence at a fraction of
    // the factorizations.
    Eigen::SparseMatrix<double> J;
    Eigen::VectorXd wr;
    double c = 0;
    if (!tg.M.empty()) {
      Eigen::SparseMatrix<double> M(nv, nv);
      M.setFromTriplets(tg.M.begin(), tg.M.end());
      J = restrict_free(Eigen::SparseMatrix<double>(Hfull - M), index, nfree);
      wr = reduce(tg.w);
      c = tg.c;
    } else {
      J = restrict_free(Hfull, index, nfree);
      wr = Eigen::VectorXd::Zero(nfree);
    }
    auto apply = [&](const Eigen::VectorXd& x) {
      Eigen::VectorXd y = J * x;
      if (c != 0) y += c * wr.dot(x) * wr;
      return y;
    };
    const Eigen::VectorXd gr = reduce(g);
    Eigen::VectorXd d;
    bool solved = false;
    // Near the solution a small linear residual no longer guarantees an accurate direction
    // (J is nearly singular along the scaling mode), so the last steps use a fresh factor.
    if (factor.ready && g.cwiseAbs().maxCoeff() > 1e-5) {
      const double eta = std::clamp(g.cwiseAbs().maxCoeff(), 1e-10, 1e-2);
      d = factor.solve(gr, ldlt, llt);
      double prev = std::numeric_limits<double>::infinity();
      for (int k = 0; k < 30 && d.allFinite(); ++k) {
        Eigen::VectorXd res = gr - apply(d);
        double rn = res.norm();
        if (rn <= eta * gr.norm()) {
          solved = true;
          break;
        }
        if (!(rn < 0.7 * prev)) break;  // contracting too slowly: refactor
        prev = rn;
        d += factor.solve(res, ldlt, llt);
      }
    }
    if (!solved) {
      factor.ready = false;
      ldlt.compute(J);
      if (ldlt.info() == Eigen::Success) {
        factor.use_ldlt = true;
        factor.w = wr;
        factor.c = c;
        factor.aw = c != 0 ? Eigen::VectorXd(ldlt.solve(wr)) : Eigen::VectorXd();
        factor.ready = factor.aw.allFinite();
      }
      if (!factor.ready) {
        llt.compute(restrict_free(Hfull, index, nfree));
        if (llt.info() != Eigen::Success)
          fail(ErrorCode::kNotConverged, "the Yamabe Hessian could not be factored at iteration " +
                                             std::to_string(r.iterations));
        factor.use_ldlt = false;
        factor.c = 0;
        factor.ready = true;
      }
      d = factor.solve(gr, ldlt, llt);
    }
    Eigen::VectorXd du = Eigen::VectorXd::Zero(nv);
    for (int i = 0; i < nv; ++i)
      if (index[i] >= 0) du[i] = d[index[i]];
    // Trust region: at most kMaxStep in any factor per iteration (a factor e^2 in length),
    // so a wild first step on a tube-like mesh cannot ask for an absurd metric.
    constexpr double kMaxStep = 4.0;
    double t = std::min(1.0, kMaxStep / std::max(du.cwiseAbs().maxCoeff(), 1e-300));
    bool accepted = false, blocked = false;
    const IntrinsicTriangulation before = T;  // each trial flips from the accepted state
    for (int halvings = 0; halvings < 40; ++halvings, t *= 0.5) {
      if (halvings > 0) T = before;
      Eigen::VectorXd trial = r.u + t * du;
      int fl = T.make_delaunay(trial);
      if (fl < 0) {
        blocked = blocked || fl == -1;
        continue;
      }
      Target tt = target(T, trial);
      Eigen::VectorXd gt = residual(tt, trial);
      if (!gt.allFinite()) continue;
      if (gt.squaredNorm() < (1.0 - 1e-4 * t) * g.squaredNorm() ||
          gt.cwiseAbs().maxCoeff() <= opt.tolerance) {
        r.u = std::move(trial);
        g = std::move(gt);
        tg = std::move(tt);
        accepted = true;
        break;
      }
    }
    r.residual = g.cwiseAbs().maxCoeff();
    // Round-off floor: once Newton has stopped halving the residual for a few iterations,
    // more iterations only shuffle round-off (curvatures are sums of many angles of cells
    // whose sizes span many orders of magnitude).
    history.push_back(r.residual);
    const size_t n = history.size();
    if (n > 4 && history[n - 1] > 0.5 * history[n - 5] && r.residual < 1e-6) {
      ++r.iterations;
      break;
    }
    if (opt.progress && !opt.progress(r.iterations + 1, r.residual))
      fail(ErrorCode::kCancelled, "conformal map cancelled");
    if (!accepted) {  // no progress possible: report as not converged
      T = before;
      r.blocked = blocked;
      break;
    }
    // A boundary triangle that cannot change shape any further throttles every step; stop
    // and let the caller give it room (see split_boundary_edge) rather than crawl.
    if (opt.stop_when_blocked && blocked && t < 0.25) {
      r.blocked = true;
      break;
    }
  }
  // The last trial may have flipped T for a rejected u; restore Delaunay for the accepted one.
  if (T.make_delaunay(r.u) < 0)
    fail(ErrorCode::kInternal, "the accepted metric lost its Delaunay triangulation");
  r.converged = r.residual <= opt.tolerance;
  r.flips = T.total_flips();
  return r;
}

}  // namespace brenier::conformal

#include "conformal/yamabe.hpp"

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <numbers>
#include <vector>

#include "common/check.hpp"
#include "common/error.hpp"
#include "common/parallel.hpp"
#include "numeric/cholmod_settings.hpp"
#include "numeric/krylov.hpp"

namespace brenier::conformal {

Eigen::VectorXd curvature(const IntrinsicTriangulation& T, const Eigen::VectorXd& u) {
  const int nv = T.num_vertices(), nf = T.num_faces();
  const Eigen::VectorXd s = half_exp(u);
  // The corner angles (the costly part: one atan each) in parallel, then summed per vertex.
  std::vector<double> angle(3 * static_cast<size_t>(nf));
#pragma omp parallel for schedule(static)
  for (int f = 0; f < nf; ++f) {
    int h0 = T.face_halfedge(f), h1 = T.next(h0), h2 = T.next(h1);
    double l0 = T.scaled_length(h0, s), l1 = T.scaled_length(h1, s), l2 = T.scaled_length(h2, s);
    // The angle at origin(h) is opposite the edge of next(h).
    angle[3 * f] = corner_angle(l1, l2, l0);
    angle[3 * f + 1] = corner_angle(l2, l0, l1);
    angle[3 * f + 2] = corner_angle(l0, l1, l2);
  }
  Eigen::VectorXd K(nv);
  const auto& bnd = T.boundary_vertex();
  for (int v = 0; v < nv; ++v) K[v] = bnd[v] ? std::numbers::pi : 2 * std::numbers::pi;
  for (int f = 0; f < nf; ++f) {
    int h = T.face_halfedge(f);
    for (int k = 0; k < 3; ++k, h = T.next(h)) K[T.origin(h)] -= angle[3 * f + k];
  }
  return K;
}

namespace {

// Cotangent weight of every edge (eq. 3.3): (cot a + cot b) / 2 over its opposite corners,
// one cot for a boundary edge.
std::vector<double> edge_weights(const IntrinsicTriangulation& T, const Eigen::VectorXd& u) {
  const int nf = T.num_faces();
  const Eigen::VectorXd s = half_exp(u);
  std::vector<double> half(3 * static_cast<size_t>(nf));  // per half-edge, its face's share
#pragma omp parallel for schedule(static)
  for (int f = 0; f < nf; ++f) {
    int h[3] = {T.face_halfedge(f), 0, 0};
    h[1] = T.next(h[0]);
    h[2] = T.next(h[1]);
    double l[3] = {T.scaled_length(h[0], s), T.scaled_length(h[1], s), T.scaled_length(h[2], s)};
    for (int k = 0; k < 3; ++k) half[3 * f + k] = 0.5 * corner_cot(l[k], l[(k + 1) % 3], l[(k + 2) % 3]);
  }
  std::vector<double> w(T.num_edges(), 0.0);
  for (int f = 0; f < nf; ++f) {
    int h = T.face_halfedge(f);
    for (int k = 0; k < 3; ++k, h = T.next(h)) w[T.edge(h)] += half[3 * f + k];
  }
  return w;
}

// The Newton matrix on the free vertices (index[i] >= 0, renumbered): H - M, assembled
// straight from the edge weights, without the fixed rows and columns.
Eigen::SparseMatrix<double> newton_matrix(const IntrinsicTriangulation& T, const Eigen::VectorXd& u,
                                          const std::vector<int>& index, int nfree,
                                          const std::vector<Eigen::Triplet<double>>& M) {
  const std::vector<double> w = edge_weights(T, u);
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(2 * w.size() + nfree + M.size());
  Eigen::VectorXd diag = Eigen::VectorXd::Zero(nfree);
  for (int e = 0; e < T.num_edges(); ++e) {
    // Any half-edge of the edge names its two ends.
    int h = T.edge_halfedge(e);
    int i = index[T.origin(h)], j = index[T.origin(T.next(h))];
    if (i >= 0) diag[i] += w[e];
    if (j >= 0) diag[j] += w[e];
    if (i >= 0 && j >= 0) {
      trip.emplace_back(i, j, -w[e]);
      trip.emplace_back(j, i, -w[e]);
    }
  }
  for (int i = 0; i < nfree; ++i) trip.emplace_back(i, i, diag[i]);
  for (const auto& t : M) {
    int i = index[t.row()], j = index[t.col()];
    if (i >= 0 && j >= 0) trip.emplace_back(i, j, -t.value());
  }
  Eigen::SparseMatrix<double> J(nfree, nfree);
  J.setFromTriplets(trip.begin(), trip.end());
  return J;
}

}  // namespace

Eigen::SparseMatrix<double> curvature_jacobian(const IntrinsicTriangulation& T,
                                               const Eigen::VectorXd& u) {
  std::vector<int> all(T.num_vertices());
  for (int i = 0; i < T.num_vertices(); ++i) all[i] = i;
  return newton_matrix(T, u, all, T.num_vertices(), {});
}

namespace {


}  // namespace

// The preconditioner of the Newton systems: a Cholesky factorization of the cotangent
// Laplacian H on the free vertices (positive definite: Delaunay weights, one vertex pinned),
// kept across iterations. Supernodal LL^T (BLAS-3; with OpenBLAS about twice as fast as a
// simplicial LDL^T of the indefinite J at 133K vertices); LDL^T if round-off defeats LL^T.
// GMRES applies the kept factor 30-60 times, and one right-hand side goes through a
// simplicial factor faster than through a supernodal one (a dtrsv per supernode), so each
// factor is converted once it is made (numeric::convert_factors_for_solves), as the planar
// transport's are: the 100K-vertex disk's conformal map 1.10-1.22 -> 1.03-1.09 s,
// mannequin-devil 0.118-0.123 -> 0.102-0.104 s, bunny00 on the sphere 0.42 -> 0.39-0.40 s
// (bench/RESULTS.md, session 53).
struct KeptFactor {
  Eigen::CholmodSupernodalLLT<Eigen::SparseMatrix<double>> llt;
  Eigen::CholmodSimplicialLDLT<Eigen::SparseMatrix<double>> ldlt;
  bool use_llt = true, ready = false;
  // How many preconditioned GMRES iterations cost about as much as one factorization:
  // measured here, 25-35 from 10K to 130K vertices (ordering and symbolic analysis weigh on
  // small meshes, flops on large ones); for larger meshes, CHOLMOD's flop count of the
  // factorization over that of the two triangular solves (4 nnz(L)), halved because the
  // factorization runs at BLAS-3 speed. A deterministic model, not a clock: the same input
  // always takes the same path.
  int budget = 30;
  bool refresh = false;  // the kept factor has grown stale: factor afresh at the next step
  // The free vertices it was factored on (row r is vertex vertex_of_row[r] of the
  // triangulation) and the reverse map, so that a later system -- after boundary splits
  // added vertices -- can still use it.
  std::vector<int> vertex_of_row, row_of_vertex;
  KeptFactor() {
    single_threaded_blas();  // before CHOLMOD reaches OpenBLAS
    llt.cholmod().print = 0;  // CHOLMOD's own messages off; failures are checked via info()
    ldlt.cholmod().print = 0;
    numeric::convert_factors_for_solves(llt.cholmod());
  }
  bool factor(const Eigen::SparseMatrix<double>& H, const std::vector<int>& index) {
    vertex_of_row.assign(H.rows(), -1);
    row_of_vertex = index;
    for (int v = 0; v < static_cast<int>(index.size()); ++v)
      if (index[v] >= 0) vertex_of_row[index[v]] = v;
    with_library_loops_serial([&] { llt.compute(H); });
    use_llt = llt.info() == Eigen::Success;
    if (!use_llt) ldlt.compute(H);
    ready = use_llt || ldlt.info() == Eigen::Success;
    refresh = false;
    if (use_llt && llt.cholmod().lnz > 0)
      budget = static_cast<int>(std::clamp(llt.cholmod().fl / (8.0 * llt.cholmod().lnz), 30.0, 60.0));
    return ready;
  }
  Eigen::VectorXd solve(const Eigen::VectorXd& b) const {
    return use_llt ? Eigen::VectorXd(llt.solve(b)) : Eigen::VectorXd(ldlt.solve(b));
  }
  /// Whether the factor's rows are exactly the free vertices of `index`.
  bool matches(const std::vector<int>& index) const { return index == row_of_vertex; }
  /// P^{-1} b for a system on the free vertices of `index`, which may hold vertices the
  /// factor never saw (new boundary split points: diagonally scaled by `diag`) and miss
  /// some it did (their entries are zero): a block preconditioner that differs from the
  /// factor in the rank of the new vertices, which GMRES absorbs in as many iterations.
  Eigen::VectorXd solve_mapped(const Eigen::VectorXd& b, const std::vector<int>& index,
                               const Eigen::VectorXd& diag) const {
    Eigen::VectorXd y = Eigen::VectorXd::Zero(static_cast<int>(vertex_of_row.size()));
    for (int v = 0; v < static_cast<int>(index.size()); ++v)
      if (index[v] >= 0 && v < static_cast<int>(row_of_vertex.size()) && row_of_vertex[v] >= 0)
        y[row_of_vertex[v]] = b[index[v]];
    y = solve(y);
    Eigen::VectorXd x(b.size());
    for (int v = 0; v < static_cast<int>(index.size()); ++v) {
      if (index[v] < 0) continue;
      bool known = v < static_cast<int>(row_of_vertex.size()) && row_of_vertex[v] >= 0;
      x[index[v]] = known ? y[row_of_vertex[v]] : b[index[v]] / diag[index[v]];
    }
    return x;
  }
};

std::shared_ptr<KeptFactor> make_kept_factor() { return std::make_shared<KeptFactor>(); }

namespace {

// The free vertices' numbering: the unknowns of the Newton system (fixed vertices keep
// their factor; their curvature has no equation).
struct FreeVertices {
  std::vector<int> index;  // by vertex: its unknown, or -1 when fixed
  int count = 0;
  explicit FreeVertices(const std::vector<char>& fixed) : index(fixed.size(), -1) {
    for (size_t i = 0; i < fixed.size(); ++i)
      if (!fixed[i]) index[i] = count++;
  }
  Eigen::VectorXd reduce(const Eigen::VectorXd& x) const {
    Eigen::VectorXd y(count);
    for (size_t i = 0; i < index.size(); ++i)
      if (index[i] >= 0) y[index[i]] = x[i];
    return y;
  }
  Eigen::VectorXd expand(const Eigen::VectorXd& d) const {
    Eigen::VectorXd x = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(index.size()));
    for (size_t i = 0; i < index.size(); ++i)
      if (index[i] >= 0) x[i] = d[index[i]];
    return x;
  }
};

// Newton step (eq. 3.4, Alg. 1 line 8, with the targets' own derivative):
// (H - M + c w w^T) du = Kbar - K on the free vertices, du = 0 on the fixed ones.
// The system J d = g with J = H - M + c w w^T (H alone when the targets do not depend on u)
// is solved by GMRES preconditioned with a Cholesky factor of H, to the accuracy inexact
// Newton needs (Eisenstat-Walker: |g - J d| <= min(1e-2, max|g|) |g|). A factorization
// costs far more than a solve, so the factor is kept and reused while GMRES converges with
// it within a few dozen iterations (the metric changes little between Newton steps);
// otherwise H is factored afresh at the current metric. M has the rank of the boundary, so
// a fresh factor of H needs a handful of iterations even where J is indefinite. Should even
// that fail, J itself is factored (LDL^T) with the rank-one term by Sherman-Morrison.
Eigen::VectorXd newton_step(const IntrinsicTriangulation& T, const Eigen::VectorXd& u, const FreeVertices& free,
                            const Target& tg, const Eigen::VectorXd& g, KeptFactor& pre, int iteration) {
  const Eigen::SparseMatrix<double> J = newton_matrix(T, u, free.index, free.count, tg.M);
  const Eigen::VectorXd wr = tg.M.empty() ? Eigen::VectorXd::Zero(free.count) : free.reduce(tg.w);
  const double c = tg.M.empty() ? 0.0 : tg.c;
  auto apply = [&](const Eigen::VectorXd& x) {
    Eigen::VectorXd y = J * x;
    if (c != 0) y += c * wr.dot(x) * wr;
    return y;
  };
  const Eigen::VectorXd diag = J.diagonal();
  auto precondition = [&](const Eigen::VectorXd& x) {
    return pre.matches(free.index) ? pre.solve(x) : pre.solve_mapped(x, free.index, diag);
  };
  const Eigen::VectorXd gr = free.reduce(g);
  // Forcing term min(1e-2, max|g|): quadratic convergence, and the last step usually lands
  // far below the tolerance (the map is then exact to round-off where it can be).
  const double eta = std::clamp(g.cwiseAbs().maxCoeff(), 1e-12, 1e-2);
  Eigen::VectorXd d;
  numeric::KrylovResult kr;
  for (int attempt = 0; attempt < 2 && !kr.converged; ++attempt) {
    const bool fresh = !pre.ready || pre.refresh || attempt > 0;
    if (fresh && !pre.factor(newton_matrix(T, u, free.index, free.count, {}), free.index)) break;
    d = Eigen::VectorXd::Zero(free.count);
    // A kept factor gets the budget of iterations one factorization is worth; when it
    // needs more than half of it, it is refreshed at the next step.
    kr = numeric::gmres(apply, precondition, gr, d, eta, fresh ? 60 : pre.budget);
    if (fresh) break;  // a fresh factor did its best
    pre.refresh = 2 * kr.iterations > pre.budget;
  }
  if (kr.converged) return free.expand(d);
  Eigen::CholmodSimplicialLDLT<Eigen::SparseMatrix<double>> ldlt;
  ldlt.cholmod().print = 0;
  ldlt.compute(J);
  Eigen::VectorXd exact;
  if (ldlt.info() == Eigen::Success) {
    exact = ldlt.solve(gr);
    if (c != 0) {
      Eigen::VectorXd aw = ldlt.solve(wr);
      exact -= aw * (c * wr.dot(exact) / (1.0 + c * wr.dot(aw)));
    }
  }
  if (exact.size() == free.count && exact.allFinite()) return free.expand(exact);
  if (!(d.size() == free.count && d.allFinite() && kr.relative_residual < 1))
    fail(ErrorCode::kNotConverged, "the Yamabe Newton system could not be solved at iteration " + std::to_string(iteration));
  return free.expand(d);
}

struct StepTaken {
  bool accepted = false;
  bool blocked = false;  // some trial could not be made Delaunay (a boundary triangle)
  double t = 1;          // the step length tried last
};

// Backtracking along du from u (Armijo on |g|^2), within a trust region of kMaxStep in any
// factor per iteration (a factor e^2 in length), so that a wild first step on a tube-like
// mesh cannot ask for an absurd metric. Each trial flips T from the accepted state; on
// success u, g and tg are the new point's.
template <class Residual>
StepTaken yamabe_line_search(IntrinsicTriangulation& T, const TargetCurvature& target, const Residual& residual,
                             const Eigen::VectorXd& du, double tolerance, Eigen::VectorXd& u, Eigen::VectorXd& g,
                             Target& tg) {
  constexpr double kMaxStep = 4.0;
  StepTaken s;
  s.t = std::min(1.0, kMaxStep / std::max(du.cwiseAbs().maxCoeff(), 1e-300));
  const IntrinsicTriangulation before = T;
  for (int halvings = 0; halvings < 40; ++halvings, s.t *= 0.5) {
    if (halvings > 0) T = before;
    Eigen::VectorXd trial = u + s.t * du;
    const int fl = T.make_delaunay(trial);
    if (fl < 0) {
      s.blocked = s.blocked || fl == -1;
      continue;
    }
    Target tt = target(T, trial);
    Eigen::VectorXd gt = residual(tt, trial);
    if (!gt.allFinite()) continue;
    if (gt.squaredNorm() < (1.0 - 1e-4 * s.t) * g.squaredNorm() || gt.cwiseAbs().maxCoeff() <= tolerance) {
      u = std::move(trial);
      g = std::move(gt);
      tg = std::move(tt);
      s.accepted = true;
      return s;
    }
  }
  T = before;
  return s;
}

}  // namespace

YamabeResult solve_yamabe(IntrinsicTriangulation& T, const TargetCurvature& target,
                          const Eigen::VectorXd& u0, const std::vector<char>& fixed,
                          const YamabeOptions& opt) {
  const int nv = T.num_vertices();
  BRENIER_CHECK(u0.size() == nv, "u0 has " << u0.size() << " entries for " << nv << " vertices");
  BRENIER_CHECK(static_cast<int>(fixed.size()) == nv, "fixed mask has " << fixed.size() << " entries");
  const FreeVertices free(fixed);
  BRENIER_CHECK(free.count < nv, "at least one vertex must be fixed (the constants are H's null space)");
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

  // The kept factor: the caller's (shared across the solves of one map) or our own.
  std::shared_ptr<KeptFactor> kept = opt.kept_factor ? opt.kept_factor : std::make_shared<KeptFactor>();
  std::vector<double> history;
  for (r.iterations = 0; r.iterations < opt.max_iterations; ++r.iterations) {
    if (r.residual <= opt.tolerance) break;
    const Eigen::VectorXd du = newton_step(T, r.u, free, tg, g, *kept, r.iterations);
    const StepTaken step = yamabe_line_search(T, target, residual, du, opt.tolerance, r.u, g, tg);
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
    if (!step.accepted) {  // no progress possible: report as not converged
      r.blocked = step.blocked;
      break;
    }
    // A boundary triangle that cannot change shape any further throttles every step; stop
    // and let the caller give it room (see split_boundary_edge) rather than crawl.
    if (opt.stop_when_blocked && step.blocked && step.t < 0.25) {
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

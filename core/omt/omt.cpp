#include "omt/omt.hpp"

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCore>
#include <algorithm>
#include <cmath>
#include <optional>
#include <string>

#include "common/check.hpp"
#include "common/error.hpp"
#include "common/parallel.hpp"
#include "numeric/krylov.hpp"

namespace brenier::omt {

namespace {

// The Hessian of eq. 3.28 on the heights other than h_p (held: the energy is invariant
// under adding a constant to h, so the Hessian is singular along the constants): the
// weighted graph Laplacian of the clipped dual edges. (Eq. 3.28 prints the off-diagonal
// entries with a plus sign; d w_i / d h_j = -|e_ij| / |y_i - y_j| for j != i, since
// raising h_j grows W_j at W_i's expense, and the diagonal is minus the sum of its row.)
// Unknown k stands for height k < p ? k : k + 1.
Eigen::SparseMatrix<double> hessian(const PowerCells& cells, const Points& sites, int n, int p) {
  const int m = n - 1;
  auto slot = [p](int i) { return i < p ? i : i - 1; };
  const std::vector<DualEdge>& edges = cells.edges;
  std::vector<double> weight(edges.size());
  Eigen::VectorXd diag = Eigen::VectorXd::Zero(n);
  std::vector<int> start(m + 1, 0);
  for (size_t k = 0; k < edges.size(); ++k) {
    const DualEdge& e = edges[k];
    const double w = weight[k] = e.length / (sites.row(e.i) - sites.row(e.j)).norm();
    diag[e.i] += w;
    diag[e.j] += w;
    if (e.i != p && e.j != p) ++start[slot(e.i) + 1], ++start[slot(e.j) + 1];
  }
  for (int c = 0; c < m; ++c) ++start[c + 1];  // the diagonal
  for (int c = 0; c < m; ++c) start[c + 1] += start[c];
  // Straight into compressed columns, rows ascending: the edges come ordered by (i, j)
  // with i < j, so column i gets rows i' < i (from earlier edges), then i, then j > i.
  // (Assembling 3M edges through triplets cost ~1 s per Newton iteration at 1M sites.)
  Eigen::SparseMatrix<double> H(m, m);
  H.resizeNonZeros(start[m]);
  std::vector<int> fill(start.begin(), start.end() - 1);
  auto put = [&](int row, int col, double v) {
    H.innerIndexPtr()[fill[col]] = row;
    H.valuePtr()[fill[col]++] = v;
  };
  size_t k = 0;
  for (int i = 0; i < n; ++i) {
    if (i != p) put(slot(i), slot(i), diag[i]);
    for (; k < edges.size() && edges[k].i == i; ++k) {
      const int j = edges[k].j;
      if (i == p || j == p) continue;
      put(slot(j), slot(i), -weight[k]);
      put(slot(i), slot(j), -weight[k]);
    }
  }
  BRENIER_CHECK(k == edges.size(), "dual edges must come ordered by their first cell");
  std::copy(start.begin(), start.end(), H.outerIndexPtr());
  return H;
}

// The vector without entry p, and back (entry p zero).
Eigen::VectorXd drop(const Eigen::VectorXd& v, int p) {
  Eigen::VectorXd out(v.size() - 1);
  out << v.head(p), v.tail(v.size() - p - 1);
  return out;
}
Eigen::VectorXd undrop(const Eigen::VectorXd& v, int p) {
  Eigen::VectorXd out(v.size() + 1);
  out << v.head(p), 0.0, v.tail(v.size() - p);
  return out;
}

double relative_norm(const Eigen::VectorXd& g, const Eigen::VectorXd& nu) {
  return (g.array() / nu.array()).matrix().norm();
}

double max_relative(const Eigen::VectorXd& w, const Eigen::VectorXd& nu) {
  return ((w - nu).array().abs() / nu.array()).maxCoeff();
}

// The Kantorovich dual D at offsets psi (+ psi_lo) with the cells there and g = masses -
// targets: w_i = |y_i|^2 + 2 h_i = 2 psi_i (OmtOptions::dual_gap_tolerance).
double dual(const Eigen::VectorXd& psi, const Eigen::VectorXd& psi_lo, const PowerCells& cells,
            const Eigen::VectorXd& g) {
  return cells.second_moment.sum() - 2 * (psi + psi_lo).dot(g);
}

}  // namespace

void check_transport_input(int n, const Eigen::VectorXd& nu_in, const OmtOptions& opt) {
  if (n == 0) invalid("no sites");
  if (nu_in.size() != n)
    invalid("target masses: " + std::to_string(nu_in.size()) + " for " + std::to_string(n) + " sites");
  for (int i = 0; i < n; ++i)
    if (!(nu_in[i] > 0) || !std::isfinite(nu_in[i]))
      invalid("target mass of site " + std::to_string(i) + " is " + std::to_string(nu_in[i]) + "; it must be positive");
  if (!(opt.tolerance > 0)) invalid("the OMT tolerance must be positive");
}

OmtResult solve_omt(const Domain& domain, const Points& sites, const Eigen::VectorXd& nu_in,
                    const OmtOptions& opt) {
  const int n = static_cast<int>(sites.rows());
  check_transport_input(n, nu_in, opt);
  OmtResult r;
  r.target = nu_in * (domain.area() / nu_in.sum());
  const Eigen::VectorXd& nu = r.target;
  // Alg. 2 starts from the Voronoi diagram ("h = 0" in the power-distance convention); with
  // u_h = max <x, y_i> + h_i that is h_i = -|y_i|^2 / 2 (equal power weights). The iterates
  // are the offsets psi = h + |y|^2 / 2 (PowerDiagrams::at_offsets), which keep their
  // precision where h would carry the round-off of |y_i|^2: the Voronoi start is psi = 0
  // exactly, and a Newton step changes psi as it changes h. The steps are accumulated in
  // double-double (psi + psi_lo): a cluster of sites d apart that the conformal map packs
  // together has offsets of size ~0.5 that differ by ~1e-8, and in plain doubles their
  // bisectors would stay eps |psi| / d off (bunny00 and armadillo stalled at 3e-8).
  const PowerDiagrams diagram(domain, sites);
  Eigen::VectorXd psi = Eigen::VectorXd::Zero(n), psi_lo = Eigen::VectorXd::Zero(n);
  // (hi, lo) + step in double-double: Knuth's two-sum, then renormalized (Dekker).
  auto add_step = [](const Eigen::VectorXd& hi, const Eigen::VectorXd& lo, const Eigen::VectorXd& step,
                     Eigen::VectorXd& out_hi, Eigen::VectorXd& out_lo) {
    out_hi.resize(hi.size());
    out_lo.resize(hi.size());
    for (Eigen::Index i = 0; i < hi.size(); ++i) {
      const double s = hi[i] + step[i], bb = s - hi[i];
      const double e = (hi[i] - (s - bb)) + (step[i] - bb);
      const double l = lo[i] + e, sum = s + l;
      out_hi[i] = sum;
      out_lo[i] = l - (sum - s);
    }
  };
  if (opt.initial_h.size() != 0) {
    if (opt.initial_h.size() != n || !opt.initial_h.allFinite())
      invalid("initial heights: " + std::to_string(opt.initial_h.size()) + " finite values needed for " +
              std::to_string(n) + " sites");
    // The given start if it leaves no cell empty and, when it is far off (some cell 10x its
    // target), is nearer the targets than Voronoi in the line search's per-cell relative
    // norm. Neither always wins: a shape's density sent to its own vertices starts well from
    // Voronoi (each cell about its share of the adjacent triangles; mannequin-devil, whose
    // density spans e^44, did not converge in 200 iterations from the uniform disk's
    // heights), another shape's density better from those heights (24 iterations where
    // Voronoi took 52). The threshold spares the extra diagram where the start is good.
    const Eigen::VectorXd initial = diagram.offsets(opt.initial_h);
    std::optional<PowerCells> c = diagram.at_offsets_if_none_hidden(initial);
    if (c && c->empty_cells == 0) {
      bool take = max_relative(c->mass, nu) <= 10;
      if (!take) {
        r.cells = diagram.at_offsets(psi);
        take = r.cells.empty_cells > 0 || relative_norm(c->mass - nu, nu) < relative_norm(r.cells.mass - nu, nu);
      }
      if (take) {
        psi = initial;
        psi_lo.setZero();
        r.cells = std::move(*c);
        r.warm_started = true;
      }
    }
  }
  if (!r.warm_started && r.cells.mass.size() == 0) r.cells = diagram.at_offsets(psi);
  if (!r.warm_started && r.cells.empty_cells > 0) {
    // Sites outside the domain (a conformal image's vertices on the unit circle, beyond the
    // chords of another image's hull) can have empty Voronoi cells. Pull the sites toward
    // the domain's centre c, z_i = c + s (y_i - c), halving s until every z_i is inside: the
    // Voronoi diagram of the z_i, which is the power diagram of the y_i at
    // h_i = -|z_i|^2 / (2 s), gives every site a cell containing z_i.
    Eigen::Vector2d c = Eigen::Vector2d::Zero();
    if (!domain.is_disk && !domain.is_sphere) c = domain.polygon.colwise().mean().transpose();
    auto all_inside = [&](double s) {
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector2d z = c + s * (sites.row(i).transpose() - c);
        if (!domain.contains(z.x(), z.y(), -1e-12)) return false;
      }
      return true;
    };
    double s = 1;
    for (int k = 0; k < 60 && !all_inside(s); ++k) s *= 0.5;
    if (s < 1) {
      // psi_i = h_i + |y_i|^2 / 2 = (s - 1) (|c|^2 - s |y_i - c|^2) / (2 s)
      Eigen::VectorXd shrunk(n);
      for (int i = 0; i < n; ++i)
        shrunk[i] = (s - 1) * (c.squaredNorm() - s * (sites.row(i).transpose() - c).squaredNorm()) / (2 * s);
      PowerCells cells = diagram.at_offsets(shrunk);
      if (cells.empty_cells < r.cells.empty_cells) {
        psi = std::move(shrunk);
        psi_lo.setZero();
        r.cells = std::move(cells);
      }
    }
  }
  r.max_relative_error = max_relative(r.cells.mass, nu);
  if (n == 1) {
    r.h = Eigen::VectorXd::Zero(1);
    r.converged = true;
    return r;
  }
  // Kitagawa-Merigot-Thibert damping: every cell keeps at least eps0.
  const double eps0 = 0.5 * std::min(nu.minCoeff(), r.cells.mass.minCoeff());
  if (!(eps0 > 0)) {
    int outside = 0;
    for (int i = 0; i < n; ++i) outside += !domain.contains(sites(i, 0), sites(i, 1), 1e-12);
    const std::string what = std::to_string(r.cells.empty_cells) + " of " + std::to_string(n) +
                             " sites have empty Voronoi cells in the domain";
    if (outside > 0) invalid(what + " (" + std::to_string(outside) + " sites lie outside it; move them in)");
    // Valid input beyond what doubles resolve: the method's limit, not the user's error.
    fail(ErrorCode::kNotConverged, what + " (sites crowded closer than double precision resolves, as where a "
                                          "conformal map compresses a long protrusion)");
  }
  Eigen::VectorXd g = r.cells.mass - nu;
  // The Newton step solves for every height but one; the held cell absorbs the round-off
  // of the total mass (sum_i w_i - sum_i nu_i, ~1e-15 at 100K cells). Holding the largest
  // target keeps that below 1e-11 of any cell's mass; holding the first cell, as before,
  // left a 1.5e-7 cell of a 100K Gaussian case 1.1e-8 off for good.
  int held = 0;
  nu.maxCoeff(&held);

  // The Newton systems are solved by conjugate-gradient-like GMRES preconditioned with the
  // sparse Cholesky factor of an earlier Hessian (CHOLMOD), refactored only when the kept
  // one has cost about a factorization in iterations: consecutive Hessians differ little.
  // Simplicial below 200K sites, supernodal above: the supernodes of a planar Laplacian are
  // small, and on one BLAS thread their dense calls cost more than they save until then
  // (omt-bench case (b): 5K 0.120 -> 0.085 s, 10K 0.220 -> 0.169 s, 100K 2.49 -> 2.18 s,
  // 300K 9.59 against 9.70 s; a 5K Wasserstein pair 0.064 -> 0.054 s). CHOLMOD's own
  // choice (CHOLMOD_AUTO) took supernodal at 5K. The sphere keeps supernodal: its maps were
  // checked on every sphere mesh with it; with simplicial, man's map keeps a fold torn across
  // the sphere until area_preserving_sphere's fourth try (bench/RESULTS.md, issue 4, session 10).
  constexpr int kSupernodalFrom = 200000;
  single_threaded_blas();  // before CHOLMOD reaches OpenBLAS
  Eigen::CholmodDecomposition<Eigen::SparseMatrix<double>> llt;
  llt.setMode(domain.is_sphere || n >= kSupernodalFrom ? Eigen::CholmodSupernodalLLt : Eigen::CholmodSimplicialLLt);
  llt.cholmod().print = 0;
  // AMD alone: by default CHOLMOD also tries METIS when AMD's fill is high, which for 1M
  // sites took 11.5 s of ordering to save 15 % of the fill (measured: analysis 14.5 s +
  // factorization 4.8 s by default, 4.3 s + 5.9 s with AMD alone; the solves cost the same).
  llt.cholmod().nmethods = 1;
  llt.cholmod().method[0].ordering = CHOLMOD_AMD;
  bool have_factor = false;
  constexpr int kBudget = 30;
  // The kept factor ages: its GMRES iterations grow with every Newton step (100K Gaussian:
  // 1, 6, 11, 14, 17, 21, 27, then 30 without converging), while a factorization costs
  // about 20-30 of them (0.43 s against ~20 ms at 100K; 25 ms against 0.85 ms at 10K).
  // Refactoring once the iterations spent on the current factor reach that cost (the
  // ski-rental rule, counted in iterations rather than clock time so that the result does
  // not depend on the machine's load) keeps the cycle near its optimum of ~3 Newton steps:
  // 100K Gaussian, 70 GMRES iterations and 3 factorizations instead of ~200 and 2. Not in
  // the quadratic phase (error below 1e-2): two or three steps remain, and at 1M sites a
  // factorization costs 9 s.
  constexpr int kRefactorAfter = 20;
  int since_factor = 0;
  if (opt.dual_gap_tolerance > 0 && domain.is_sphere)
    invalid("the dual gap test is for planar domains (the sphere's cells minimize another cost)");
  bool gap_closed = false;
  for (r.iterations = 0; r.iterations < opt.max_iterations; ++r.iterations) {
    if (r.max_relative_error <= opt.tolerance) break;
    const Eigen::SparseMatrix<double> H = hessian(r.cells, sites, n, held);
    const Eigen::VectorXd rhs = -drop(g, held);
    auto apply = [&](const Eigen::VectorXd& x) { return Eigen::VectorXd(H * x); };
    auto precondition = [&](const Eigen::VectorXd& x) { return Eigen::VectorXd(llt.solve(x)); };
    bool accepted = false;
    // Two passes: the direction from the kept factor at the forcing-term accuracy; if no
    // step along it is accepted, once more from a fresh factor solved to 1e-10 (an
    // inexact direction measured in the per-cell metric need not descend in the 2-norm of
    // the line search).
    for (int pass = 0; pass < 2 && !accepted; ++pass) {
      // Forcing term eta = error (superlinear convergence), but no smaller than what
      // brings this step to the tolerance (0.3 tol / error): the last step is not solved
      // beyond what it needs (1M sites to 1e-6: 21 GMRES iterations of 0.3 s each).
      const double e = r.max_relative_error;
      const double eta = pass ? 1e-10 : std::clamp(std::max(e, 0.3 * opt.tolerance / e), 1e-12, 1e-2);
      Eigen::VectorXd d;
      numeric::KrylovResult kr;
      for (int attempt = 0; attempt < 2 && !kr.converged; ++attempt) {
        const bool fresh =
            !have_factor || (since_factor >= kRefactorAfter && r.max_relative_error > 1e-2) || attempt > 0 ||
            (pass > 0 && attempt == 0);
        if (fresh) {
          llt.compute(H);
          if (llt.info() != Eigen::Success)
            fail(ErrorCode::kNotConverged, "the OMT Hessian is singular at iteration " +
                                               std::to_string(r.iterations) +
                                               " (a cell without neighbours inside the domain)");
          have_factor = true;
          since_factor = 0;
          ++r.factorizations;
        }
        d = Eigen::VectorXd::Zero(n - 1);
        kr = numeric::gmres(apply, precondition, rhs, d, eta, fresh ? 100 : kBudget);
        r.linear_iterations += kr.iterations;
        since_factor += kr.iterations;
        if (fresh) break;
      }
      const Eigen::VectorXd dh = undrop(d, held);
      if (pass == 0 && opt.dual_gap_tolerance > 0 && kr.converged && r.max_relative_error <= 0.25) {
        const double rise = -g.dot(dh), value = dual(psi, psi_lo, r.cells, g);
        if (rise >= 0 && rise <= opt.dual_gap_tolerance * std::abs(value)) {
          r.dual_value = value;
          r.dual_rise = rise;
          gap_closed = true;
          break;
        }
      }
      double t = 1;
      const double gnorm = relative_norm(g, nu);
      // Kitagawa-Merigot-Thibert halving. Their decrease test holds in any fixed norm (the
      // Newton step scales the gradient by 1 - t to first order); we measure it per cell
      // relative to the targets, as the stopping test does: in the plain 2-norm the large
      // cells' round-off hides the small cells' progress (100K Gaussian: |g| at its floor
      // 5e-14 while the smallest cells were still 1e-8 off). 30 halvings (t = 1e-9)
      // without progress mean the round-off floor; in the quadratic phase (error below
      // 1e-4, where full steps are taken) 4 do.
      const int max_halvings = r.max_relative_error < 1e-4 ? 4 : 30;
      for (int halvings = 0; halvings < max_halvings; ++halvings, t *= 0.5) {
        Eigen::VectorXd trial, trial_lo;
        add_step(psi, psi_lo, t * dh, trial, trial_lo);
        std::optional<PowerCells> c = diagram.at_offsets_if_none_hidden(trial, trial_lo);
        if (!c || c->empty_cells > 0 || c->mass.minCoeff() < eps0) continue;
        Eigen::VectorXd gt = c->mass - nu;
        if (relative_norm(gt, nu) <= (1 - 0.5 * t) * gnorm || max_relative(c->mass, nu) <= opt.tolerance) {
          psi = std::move(trial);
          psi_lo = std::move(trial_lo);
          r.cells = std::move(*c);
          g = std::move(gt);
          accepted = true;
          break;
        }
      }
    }
    if (gap_closed) break;
    r.max_relative_error = max_relative(r.cells.mass, nu);
    if (opt.progress && !opt.progress(r.iterations + 1, r.max_relative_error))
      fail(ErrorCode::kCancelled, "optimal transport cancelled");
    if (!accepted) {
      ++r.iterations;
      break;  // round-off floor: no step improves any more
    }
  }
  if (!domain.is_sphere && !gap_closed) r.dual_value = dual(psi, psi_lo, r.cells, r.cells.mass - nu);
  r.h = (psi - 0.5 * sites.rowwise().squaredNorm()) + psi_lo;
  r.h.array() -= r.h.mean();
  r.converged = r.max_relative_error <= opt.tolerance || gap_closed;
  return r;
}

}  // namespace brenier::omt

// A coarse-to-fine start for the semi-discrete transport (Merigot 2011, "A multiscale
// approach to optimal transport"; Levy 2015's multilevel solver in geogram): the Newton
// iterations of Alg. 2 are solved first for a quarter of the sites carrying the masses of
// their neighbours, recursively, and the finer problem starts from the coarse solution.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <numeric>
#include <random>
#include <vector>

#include "common/error.hpp"
#include "omt/omt.hpp"

namespace brenier::omt {

namespace {

// The fine sites' heights from the coarse solution. The coarse Brenier potential u_c(x) =
// max_j <x, Y_j> + H_j is sampled at the coarse cells' centroids X_j, where it equals
// <X_j, Y_j> + H_j, and its Legendre transform (the dual potential, whose value at a site is
// minus its height: sec. 6.2.2) is smoothed by a log-sum-exp over those samples, weighted by
// the cells' masses m_j:
//   phi(y) = eps log sum_j m_j exp((<X_j, y> - u_c(X_j)) / eps),   h_i = -phi(y_i).
// phi is strictly convex, so every fine site lies on the lower hull of the lifted points and
// no site is hidden (the failure of plain interpolation: fine sites inheriting the offsets of
// the coarse cell that holds them left 97 % of lion-head's cells empty, and piecewise-linear
// interpolation of the offsets a third). grad phi(y) is the softmax-weighted mean of the X_j,
// so a fine site's cell starts near where the coarse map sends its neighbourhood. eps is a
// site spacing times a coarse cell's size (the width over which neighbouring pieces blend):
// 2 pi / sqrt(n m); 1 pi left some transports unable to take a first step, 3 pi was slower.
Eigen::VectorXd smoothed_dual(const Points& coarse, const OmtResult& c, const Points& sites) {
  const int n = static_cast<int>(sites.rows()), m = static_cast<int>(coarse.rows());
  const double eps = 2 * std::numbers::pi / std::sqrt(static_cast<double>(n) * m);
  const Points& X = c.cells.centroid;
  Eigen::VectorXd offset(m), log_mass(m);
  for (int j = 0; j < m; ++j) {
    offset[j] = -X.row(j).dot(coarse.row(j)) - c.h[j];
    log_mass[j] = std::log(std::max(c.cells.mass[j], 1e-300));
  }
  Eigen::VectorXd h(n);
#pragma omp parallel
  {
    Eigen::VectorXd t(m);
#pragma omp for schedule(static)
    for (int i = 0; i < n; ++i) {
      t = (X * sites.row(i).transpose() + offset) / eps + log_mass;
      const double top = t.maxCoeff();
      // Only the terms within e^-40 of the largest: each one below adds under 4e-18 of the
      // sum. The exponentials of all m terms were a tenth of a whole pair's time.
      double sum = 0;
      for (int j = 0; j < m; ++j)
        if (t[j] > top - 40) sum += std::exp(t[j] - top);
      h[i] = -eps * (top + std::log(sum));
    }
  }
  return h;
}

}  // namespace

namespace detail {

std::optional<Eigen::VectorXd> coarse_to_fine_heights(const Domain& domain, const Points& sites,
                                                      const Eigen::VectorXd& nu, const OmtOptions& opt,
                                                      OmtResult& r) {
  constexpr int kRatio = 4;
  const int n = static_cast<int>(sites.rows()), m = n / kRatio;
  // The coarse sites: a pseudo-random subset, which follows the sites' own crowding (fixed
  // seed: the same answer on every run). Each site's mass goes to its nearest coarse site.
  std::vector<int> keep(n);
  std::iota(keep.begin(), keep.end(), 0);
  std::mt19937 rng(20111);
  std::shuffle(keep.begin(), keep.end(), rng);
  keep.resize(m);
  std::sort(keep.begin(), keep.end());
  Points coarse(m, 2);
  for (int k = 0; k < m; ++k) coarse.row(k) = sites.row(keep[k]);
  const PowerDiagrams coarse_diagram(domain, coarse, false);
  const std::vector<int> nearest = coarse_diagram.locate(-0.5 * coarse.rowwise().squaredNorm(), sites);
  Eigen::VectorXd coarse_nu = Eigen::VectorXd::Zero(m);
  for (int i = 0; i < n; ++i) coarse_nu[nearest[i]] += nu[i];
  // The coarse solve only places the start: 1 % per cell is what its Newton steps reach in
  // their quadratic phase, and the fine start's own error is larger than that anyway.
  OmtOptions co;
  co.tolerance = std::max(opt.tolerance, 1e-2);
  co.max_iterations = opt.max_iterations;
  co.progress = opt.progress;
  co.multilevel = true;
  co.multilevel_probe = false;  // the level above was damped: so is this one, as a rule
  if (opt.initial_h.size() == n) {
    co.initial_h.resize(m);
    for (int k = 0; k < m; ++k) co.initial_h[k] = opt.initial_h[keep[k]];
  }
  OmtResult c;
  try {
    c = solve_omt(domain, coarse, coarse_nu, co);
  } catch (const Error& e) {
    if (e.code() != ErrorCode::kNotConverged) throw;
    return std::nullopt;  // where the coarse problem fails the fine one may not
  }
  r.coarse_iterations += c.iterations;
  if (!c.converged) return std::nullopt;
  r.levels = c.levels + 1;
  // Blended with the Voronoi diagram's potential |y|^2 / 2 (heights -|y_i|^2 / 2, offsets 0):
  // phi is nearly flat across the fine sites a coarse cell is blended from, which left their
  // cells as small as 1e-16 of their targets (lion-head's 8,356 sites from mannequin-devil's
  // density) and some sites within round-off of hidden, so that a change in the last bits of
  // phi made the start be rejected. The convex combination (1 - a) phi + a |y|^2 / 2 has
  // curvature at least a everywhere: a = 0.03 raised the smallest start cell to 5e-4 of its
  // target and cut that pair from 113 to 97 Newton iterations (0.05 and 0.08: 93 and 92
  // there, but more on the others; bench/RESULTS.md, session 20).
  constexpr double kVoronoi = 0.03;
  Eigen::VectorXd h = smoothed_dual(coarse, c, sites);
  h = (1 - kVoronoi) * h - kVoronoi * 0.5 * sites.rowwise().squaredNorm();
  return h;
}

}  // namespace detail

}  // namespace brenier::omt

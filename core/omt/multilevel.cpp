// A coarse-to-fine start for the semi-discrete transport (Merigot 2011, "A multiscale
// approach to optimal transport"; Levy 2015's multilevel solver in geogram): the Newton
// iterations of Alg. 2 are solved first for an eighth of the sites carrying the masses of
// their neighbours, recursively, and the finer problem starts from the coarse solution.
#include <cmath>
#include <numbers>
#include <vector>

#include "common/error.hpp"
#include "omt/coarse_to_fine.hpp"
#include "omt/omt.hpp"

namespace brenier::omt {

namespace detail {

std::optional<Eigen::VectorXd> coarse_to_fine_heights(const Domain& domain, const Points& sites,
                                                      const Eigen::VectorXd& nu, const OmtOptions& opt,
                                                      OmtResult& r, int ratio, bool recurse) {
  const int n = static_cast<int>(sites.rows());
  // The coarse sites: 1/ratio of them, an eighth (kCoarseRatio) but for the rival start's probe
  // (omt.cpp); each site's mass goes to its nearest coarse site.
  // A quarter (the ratio until session 38) gave the real disk pairs more levels and more damped
  // steps in all: over the 45 pairs of the ten real disk meshes 1,824 Newton iterations
  // against 1,487 with an eighth, 18 pairs changed, 16 of them fewer (mannequin-devil x
  // three_peaks 327 -> 187, lion-head x cylinder_locally_refined 43 -> 29); the 100K-vertex
  // disk map's transport 31 -> 27. A half or a third: more; 1/16 or 1/32: mixed
  // (bench/RESULTS.md, session 38).
  const std::vector<int> keep = coarse_subset(n, ratio);
  const int m = static_cast<int>(keep.size());
  Points coarse(m, 2);
  for (int k = 0; k < m; ++k) coarse.row(k) = sites.row(keep[k]);
  const PowerDiagrams coarse_diagram(domain, coarse, false);
  const std::vector<int> nearest = coarse_diagram.locate(-0.5 * coarse.rowwise().squaredNorm(), sites);
  Eigen::VectorXd coarse_nu = Eigen::VectorXd::Zero(m);
  for (int i = 0; i < n; ++i) coarse_nu[nearest[i]] += nu[i];
  OmtResult c;
  try {
    OmtOptions co = coarse_options(opt, keep, n);
    co.multilevel = recurse;
    c = solve_omt(domain, coarse, coarse_nu, co);
  } catch (const Error& e) {
    if (e.code() != ErrorCode::kNotConverged) throw;
    return std::nullopt;  // where the coarse problem fails the fine one may not
  }
  r.coarse_iterations += c.iterations;
  if (!c.converged) return std::nullopt;
  r.levels = c.levels + 1;
  // eps: a site spacing times a coarse cell's size (the width over which neighbouring pieces
  // blend), 2 pi / sqrt(n m) on the unit disk; 1 pi left some transports unable to take a
  // first step, 3 pi was slower. The Voronoi blend 0.03 raised lion-head's smallest start
  // cell from 1e-16 to 5e-4 of its target and cut that pair from 113 to 97 Newton
  // iterations (0.05 and 0.08: 93 and 92 there, but more on the others; bench/RESULTS.md,
  // session 20).
  const double eps = 2 * std::numbers::pi / std::sqrt(static_cast<double>(n) * m);
  return smoothed_dual(coarse, c.cells.centroid, c.h, c.cells.mass, sites, eps, 0.03);
}

}  // namespace detail

}  // namespace brenier::omt

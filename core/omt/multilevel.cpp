// A coarse-to-fine start for the semi-discrete transport (Merigot 2011, "A multiscale
// approach to optimal transport"; Levy 2015's multilevel solver in geogram): the Newton
// iterations of Alg. 2 are solved first for an eighth of the sites carrying the masses of
// their neighbours, recursively, and the finer problem starts from the coarse solution.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include "common/error.hpp"
#include "omt/coarse_to_fine.hpp"
#include "omt/omt.hpp"

namespace brenier::omt {

namespace detail {

namespace {

// The coarse potential u_c (coarse_to_fine.hpp) is affine on each coarse cell, so its Legendre
// transform at a fine site y, sup_x <x, y> - u_c(x), is reached at a corner of some cell. For
// a site on the hull of the sites (a disk map's boundary vertex, on the circle) that corner
// lies on the domain's outline, half a coarse cell from the nearest centroid: sampled at the
// centroids alone the transform fell short there, the site's height came out too high and
// its start cell too large (the 100K-vertex disk map's boundary sites 18-30 times their
// targets, 465 of 554 above 3 times). Samples on the outline, one per fine site spacing,
// where u_c is evaluated exactly, bring that down to 10 (84 above 3 times); that map's
// transport takes 23 Newton iterations over its levels instead of 26, the fine level 8
// instead of 9; omt-bench's Gaussian masses with --multilevel --no-probe 28 -> 23 at 10K
// sites and 39 -> 33 at 100K (bench/RESULTS.md, session 77). Their weight, in fine cells'
// mass (the map / 10K / 100K): 1: 25 / 25 / 33; 2 and 4: 23 / 23 / 32-33; 8: 25 / 23 / 33;
// 64: 28 / 25 / 33. A share of the holding coarse cell's mass (0.25-2 of it) instead: 27-29
// and 39-43 Newton iterations on the Gaussian.
// Not on domains with a density (the shape distances' conformal images): there the samples
// cost the real pairs Newton iterations (lion-head x mannequin-devil 99 -> 105,
// mannequin-devil x cylinder_locally_refined 63 -> 71), weighted as above or by a share of
// the coarse cell's mass alike.
constexpr double kOutlineSampleCells = 4;

// Points `spacing` apart on the domain's outline (the circle, or the polygon's sides).
Points outline_points(const Domain& domain, double spacing) {
  std::vector<Eigen::RowVector2d> p;
  if (domain.is_disk) {
    const int k = static_cast<int>(std::ceil(2 * std::numbers::pi * domain.radius / spacing));
    for (int i = 0; i < k; ++i) {
      const double a = 2 * std::numbers::pi * i / k;
      p.emplace_back(domain.radius * std::cos(a), domain.radius * std::sin(a));
    }
  } else {
    const Eigen::Index corners = domain.polygon.rows();
    for (Eigen::Index e = 0; e < corners; ++e) {
      const Eigen::RowVector2d a = domain.polygon.row(e), b = domain.polygon.row((e + 1) % corners);
      const int k = std::max(1, static_cast<int>(std::ceil((b - a).norm() / spacing)));
      for (int i = 0; i < k; ++i) p.push_back(a + (b - a) * (static_cast<double>(i) / k));
    }
  }
  Points out(static_cast<Eigen::Index>(p.size()), 2);
  for (size_t i = 0; i < p.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = p[i];
  return out;
}

}  // namespace

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
  if (domain.density) return smoothed_dual(coarse, c.cells.centroid, c.h, c.cells.mass, sites, eps, 0.03);
  // Uniform density: the samples at the centroids, then on the outline (outline_points), each
  // of those with the coarse cell that holds it and four fine cells' mass.
  const Points outline = outline_points(domain, std::sqrt(domain.area() / n));
  const std::vector<int> holder = coarse_diagram.locate(c.h, outline);
  const int k = static_cast<int>(outline.rows());
  Points Y(m + k, 2), X(m + k, 2);
  Eigen::VectorXd H(m + k), mass(m + k);
  Y.topRows(m) = coarse;
  X.topRows(m) = c.cells.centroid;
  H.head(m) = c.h;
  mass.head(m) = c.cells.mass;
  X.bottomRows(k) = outline;
  mass.tail(k).setConstant(kOutlineSampleCells * domain.area() / n);
  for (int b = 0; b < k; ++b) {
    Y.row(m + b) = coarse.row(holder[b]);
    H[m + b] = c.h[holder[b]];
  }
  return smoothed_dual(Y, X, H, mass, sites, eps, 0.03);
}

}  // namespace detail

}  // namespace brenier::omt

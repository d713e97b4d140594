// Pieces of the coarse-to-fine start (OmtOptions::multilevel) shared by the planar
// transport (multilevel.cpp) and the transport on the sphere (surface_cells.cpp).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <type_traits>
#include <vector>

#include "omt/omt.hpp"
#include "omt/stall.hpp"

namespace brenier::omt::detail {

/// How many fine sites per coarse site, on the plane (multilevel.cpp) and the sphere
/// (surface_cells.cpp) alike: an eighth kept per level (the measurements behind it are in
/// the comments at both uses).
inline constexpr int kCoarseRatio = 8;

/// The coarse level: every `ratio`-th site of a pseudo-random order, which follows the
/// sites' own crowding (fixed seed: the same answer on every run); sorted.
inline std::vector<int> coarse_subset(int n, int ratio) {
  std::vector<int> keep(n);
  std::iota(keep.begin(), keep.end(), 0);
  std::mt19937 rng(20111);
  std::shuffle(keep.begin(), keep.end(), rng);
  keep.resize(n / ratio);
  std::sort(keep.begin(), keep.end());
  return keep;
}

/// The coarse level's options: it only places the start, so 1 % per cell (what its Newton
/// steps reach in their quadratic phase; the fine start's own error is larger anyway); the
/// same rule below it, without the first-step trial (the level above was damped: so is this
/// one, as a rule); the fine start's heights at the kept sites, if there is one.
inline OmtOptions coarse_options(const OmtOptions& opt, const std::vector<int>& keep, int n) {
  OmtOptions co;
  co.tolerance = std::max(opt.tolerance, 1e-2);
  co.max_iterations = opt.max_iterations;
  co.progress = opt.progress;
  co.multilevel = true;
  co.multilevel_probe = false;
  if (opt.initial_h.size() == n) {
    co.initial_h.resize(static_cast<Eigen::Index>(keep.size()));
    for (size_t k = 0; k < keep.size(); ++k) co.initial_h[static_cast<Eigen::Index>(k)] = opt.initial_h[keep[k]];
  }
  return co;
}

/// The fine sites' heights from a coarse solution (coarse sites Y_j, heights H_j, cells of
/// mass m_j and centroid X_j). The coarse Brenier potential u_c(x) = max_j <x, Y_j> + H_j is
/// sampled at the centroids, where it equals <X_j, Y_j> + H_j, and its Legendre transform
/// (the dual potential, whose value at a site is minus its height: sec. 6.2.2) is smoothed by
/// a log-sum-exp over those samples, weighted by the masses:
///   phi(y) = eps log sum_j m_j exp((<X_j, y> - u_c(X_j)) / eps).
/// phi is strictly convex, so every fine site lies on the lower hull of the lifted points
/// (the failure of plain interpolation: fine sites inheriting the offsets of the coarse cell
/// that holds them left 97 % of lion-head's cells empty, and piecewise-linear interpolation
/// of the offsets a third); grad phi(y) is the softmax-weighted mean of the X_j, so a fine
/// site's cell starts near where the coarse map sends its neighbourhood. phi is then blended
/// with the Voronoi diagram's potential |y|^2 / 2 (weight `voronoi`, below), and h_i =
/// -((1 - voronoi) phi(y_i) + voronoi |y_i|^2 / 2): phi is nearly flat across the fine sites
/// a coarse cell is blended from, which left their cells as small as 1e-16 of their targets
/// (lion-head's 8,356 sites from mannequin-devil's density) and some sites within round-off
/// of hidden; the blend has curvature at least `voronoi` everywhere.
template <class Sites>
Eigen::VectorXd smoothed_dual(const Sites& coarse, const Sites& X, const Eigen::VectorXd& H, const Eigen::VectorXd& m,
                              const Sites& sites, double eps, double voronoi) {
  const int n = static_cast<int>(sites.rows()), k = static_cast<int>(coarse.rows());
  Eigen::VectorXd offset(k), log_mass(k);
  for (int j = 0; j < k; ++j) {
    offset[j] = -X.row(j).dot(coarse.row(j)) - H[j];
    log_mass[j] = std::log(std::max(m[j], 1e-300));
  }
  Eigen::VectorXd h(n);
  if constexpr (std::is_same_v<Sites, Points>) {
    // In the plane, the terms that count are found through the regular triangulation of the
    // centroids (PowerDiagrams::smoothed_max): the dense sum over every coarse centroid
    // took 1.9 s for 99,731 fine and 24,932 coarse sites.
    const Eigen::VectorXd phi =
        PowerDiagrams(Domain::unit_disk(), X, false).smoothed_max(offset + eps * log_mass, sites, eps);
    for (int i = 0; i < n; ++i)
      h[i] = -(1 - voronoi) * phi[i] - voronoi * 0.5 * sites.row(i).squaredNorm();
    return h;
  }
#pragma omp parallel
  {
    Eigen::VectorXd t(k);
#pragma omp for schedule(static)
    for (int i = 0; i < n; ++i) {
      t = (X * sites.row(i).transpose() + offset) / eps + log_mass;
      const double top = t.maxCoeff();
      // Only the terms within e^-40 of the largest: each one below adds under 4e-18 of the
      // sum. The exponentials of all terms were a tenth of a whole pair's time.
      double sum = 0;
      for (int j = 0; j < k; ++j)
        if (t[j] > top - 40) sum += std::exp(t[j] - top);
      h[i] = -(1 - voronoi) * eps * (top + std::log(sum)) - voronoi * 0.5 * sites.row(i).squaredNorm();
    }
  }
  return h;
}

}  // namespace brenier::omt::detail

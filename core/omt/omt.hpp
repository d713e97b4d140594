// Semi-discrete optimal mass transport from the uniform density on a convex domain to
// weighted sites (dissertation Thm 3.8/3.9, Alg. 2): Newton's method on the convex energy
// E(h) = ∫ u_h - sum nu_i h_i (eq. 3.25), one power diagram per step.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <optional>

#include "omt/power_diagram.hpp"

namespace brenier::omt {

/// Called after every Newton iteration with (iteration, max relative cell-mass error);
/// returning false cancels the solve (Error(kCancelled)).
using Progress = std::function<bool(int iteration, double residual)>;

struct OmtOptions {
  /// Stop when max_i |w_i - nu_i| / nu_i <= tolerance: relative per cell, so the smallest
  /// cells are as exact as the largest.
  double tolerance = 1e-8;
  int max_iterations = 200;
  Progress progress;
  /// Heights to start from (one per site), e.g. the solution of a nearby problem: used when
  /// it leaves no cell empty and is nearer the targets than the Voronoi diagram of Alg. 2
  /// (which is the start otherwise).
  Eigen::VectorXd initial_h;
  /// Planar domains: where the start (initial_h or Voronoi) leaves a cell more than 10x
  /// off its target, there are at least 1,000 sites and the first Newton step from that
  /// start is damped below 1/4, start instead from a coarse-to-fine
  /// solve (multilevel.cpp): an eighth of the sites, carrying the masses of the sites
  /// nearest each, is solved first (recursively, by the same rule) and the fine heights
  /// start from the smoothed Legendre transform of its Brenier potential. Where the source
  /// density varies by orders of magnitude (conformal images of real shapes), the plain
  /// start spends most of its Newton iterations in the damped phase; here most of those run
  /// on the coarse levels, at a fraction of the cost. If the solve from that start does not
  /// converge, it is solved again from the plain start, so it answers wherever that does.
  /// solve_surface_omt (the sphere) takes it wherever the start is 10x off with at least
  /// 1,000 sites, without the first-step trial.
  bool multilevel = false;
  /// With `multilevel`, planar domains: a rival of the coarse-to-fine start (one height per
  /// site, or empty), taken instead of it where it leaves no cell empty and its Kantorovich
  /// dual D (below, at OmtOptions::dual_gap_tolerance) is higher. D is the concave function
  /// the Newton steps climb, at most the transport's cost W2^2 at any heights and equal to it
  /// at the solution, so the start with the higher D is nearer the solution in the solver's
  /// own objective. A one-level probe decides first whether the coarse levels are worth
  /// solving: the 1/64 subset alone, solved plainly and carried to the fine sites like a
  /// coarse level; it runs where the rival's D is within 15 % of the plain start's (positive)
  /// one. Where the rival's D beats the probe's start, the rival is taken at once; the
  /// near copies' rivals beat it 5-20x, the unrelated shapes' lose 10-200x (bench/RESULTS.md,
  /// session 44). Otherwise the coarse levels are solved and their start's D decides. A solve from
  /// the rival that does not converge is returned as it is (no plain start follows). For the
  /// distance: another shape's density onto a shape's vertices, from that shape's own heights
  /// (bench/RESULTS.md, session 43).
  Eigen::VectorXd alternative_h;
  /// With `multilevel`: whether the first Newton step decides (above). Off, the
  /// coarse-to-fine start is taken wherever the start is 10x off: how the coarse levels are
  /// solved, below a level whose own first step was damped.
  bool multilevel_probe = true;
  /// Also stop, on a planar domain, once the transport's cost is known to this relative
  /// accuracy though its cells are not yet within `tolerance` (0: off). For callers that
  /// want the cost, not the map (the Wasserstein distance). The Kantorovich dual
  ///   D(h) = sum_i int_{W_i} |x - y_i|^2 dmu - sum_i w_i (mu(W_i) - nu_i),  w_i = |y_i|^2 + 2 h_i,
  /// is concave in h with its maximum W2^2 at the solution, gradient -2 g (g_i = mu(W_i) -
  /// nu_i) and Hessian -2 H (H of eq. 3.28), so the Newton step dh = -H^-1 g raises it by
  /// g^T H^-1 g = -<g, dh> to second order: the Newton decrement. The solve stops when that
  /// is at most dual_gap_tolerance D(h) and every cell is within 25 % of its target (the
  /// quadratic phase, where the second-order prediction holds), without building the
  /// diagram the step would lead to; OmtResult::dual_rise then holds the decrement.
  double dual_gap_tolerance = 0;
  /// Planar and surface transports: called at the start and after every Newton iteration
  /// with the Kantorovich dual D(h) at the current heights, a lower bound of the transport's
  /// cost W2^2 whatever h is (weak duality); returning true stops the solve there, with
  /// `abandoned` set and dual_value holding that bound. For callers that compare transports
  /// (the best turn of a shape distance) and can drop one once its bound passes the best.
  std::function<bool(double lower_bound)> abandon;
  /// Stop, not converged and `stalled`, once the relative gradient norm |(m - nu) / nu| has
  /// fallen by less than kStallDecrease over the last `stall_window` Newton iterations (0:
  /// off). The damped steps guarantee a fall of at least t/2 per step, so this fires only
  /// where the accepted steps stay near t ~ 1e-3 for the whole window. On planar domains
  /// also once 10 accepted steps in a row were shorter than 1e-4 (detail::StallWatch, in
  /// stall.hpp). For callers with something better to do than creep. On the sphere
  /// (solve_surface_omt) the stalled solve is returned: the sphere distance retries at a
  /// lower density cap (distance.cpp). On planar domains (solve_omt) a stalled coarse-to-fine
  /// start is followed by the plain start (OmtOptions::multilevel), which gets the iterations
  /// the stalled one left unused. Not passed to the coarse levels.
  int stall_window = 0;
};

/// OmtOptions::stall_window's fall: 5 %, under half of the 11 % that steps of t = 1/256 (the
/// slowest seen in transports that converge) guarantee over 60 iterations.
inline constexpr double kStallDecrease = 0.05;

struct OmtResult {
  Eigen::VectorXd h;       // heights, sum zero (unique up to a constant: Thm 3.8)
  PowerCells cells;        // the power diagram at h
  Eigen::VectorXd target;  // nu, scaled to the domain's area
  int iterations = 0;
  double max_relative_error = 0;  // max_i |w_i - nu_i| / nu_i at h
  bool converged = false;
  long linear_iterations = 0;  // preconditioned CG iterations, summed
  int factorizations = 0;
  bool warm_started = false;  // options.initial_h was the start
  /// Planar domains: D(h), the Kantorovich dual at h (see OmtOptions::dual_gap_tolerance;
  /// a lower bound of the transport's cost, equal to it at the solution).
  double dual_value = 0;
  /// When the solve stopped by OmtOptions::dual_gap_tolerance: the Newton decrement, the
  /// rise of D left to its maximum (to second order; dual_value + dual_rise estimates the
  /// cost to third order). 0 otherwise.
  double dual_rise = 0;
  bool abandoned = false;  // stopped by OmtOptions::abandon (converged is then false)
  bool stalled = false;    // stopped by OmtOptions::stall_window (converged is then false)
  int levels = 1;          // OmtOptions::multilevel: the levels the start came from, this one included
  int coarse_iterations = 0;  // of `iterations`, those spent on the coarse levels
};

/// Throws Error(kInvalidArgument) unless there are sites, one positive finite target mass per
/// site, a positive tolerance and, if given, one finite alternative height per site: the
/// checks every transport solver makes first.
void check_transport_input(int sites, const Eigen::VectorXd& nu, const OmtOptions& options);

/// The OT map from the uniform density on `domain` to the sites with masses `nu` (any
/// positive scale: they are scaled to the domain's area). Sites must be distinct; they may
/// lie anywhere (those outside the domain get cells along its edge). Newton direction from
/// the Hessian of eq. 3.28 -- the weighted graph Laplacian of the power diagram, edge
/// (i, j) weighted by |W_i ∩ W_j ∩ Omega| / |y_i - y_j| -- on the sum-zero subspace; the
/// step is damped as in Kitagawa, Merigot and Thibert (2019): halved until every cell keeps
/// at least half the smaller of its target and the initial smallest cell, and the gradient
/// shrinks by (1 - t/2) -- Alg. 2's "halve while a cell is empty", with the guarantee of
/// global convergence. Throws Error(kInvalidArgument) for bad input; a solve that stops
/// short returns converged = false with its iteration count and error. `converged` means
/// max_relative_error <= tolerance, or the dual gap test of OmtOptions::dual_gap_tolerance.
OmtResult solve_omt(const Domain& domain, const Points& sites, const Eigen::VectorXd& nu,
                    const OmtOptions& options = {});

namespace detail {
/// OmtOptions::multilevel's start (multilevel.cpp): heights for the sites from the solve of
/// a 1/`ratio` subset carrying their masses (itself coarse-to-fine where `recurse`), or
/// nothing if that solve did not converge; adds the coarse levels' iterations to `r` and
/// sets r.levels (the caller resets it to 1 if it does not take the heights).
std::optional<Eigen::VectorXd> coarse_to_fine_heights(const Domain& domain, const Points& sites,
                                                      const Eigen::VectorXd& nu, const OmtOptions& options,
                                                      OmtResult& r, int ratio, bool recurse);
/// Whether the one-level probe runs before the coarse levels (omt.cpp, `coarse_start`), from
/// the Kantorovich duals of the plain start and of OmtOptions::alternative_h: where the two
/// agree within 15 % (a near copy: both just below W2^2 > 0), or where the plain start's is
/// negative and the rival's positive (a plain start far off). The probe then decides.
bool worth_probing(double plain_dual, double rival_dual);
}  // namespace detail

}  // namespace brenier::omt

// Shape distances between two prepared surfaces (distance/shape.hpp).
#pragma once

#include <array>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "distance/method.hpp"
#include "distance/shape.hpp"
#include "omt/omt.hpp"

namespace brenier::distance {

struct PairResult {
  double distance = 0;  // the reported distance
  /// Wasserstein only: W2 with the first surface's density as the source and the second's
  /// vertices as the sites, and the other way round; `distance` is their mean. raw_* are
  /// eq. 3.31 as it stands; forward/backward have the sites' own quantization removed
  /// (WassersteinOptions::debias), and are the raw values when it is off.
  double forward = std::numeric_limits<double>::quiet_NaN();
  double backward = std::numeric_limits<double>::quiet_NaN();
  double raw_forward = std::numeric_limits<double>::quiet_NaN();
  double raw_backward = std::numeric_limits<double>::quiet_NaN();
  double rotation = 0;        // radians: the second surface's conformal image was turned by it
  std::string normalization;  // what fixed the Moebius freedom, said in words
  int newton_iterations = 0;  // of the transports solved for this pair
  double max_relative_error = 0;  // their worst final cell-mass error
  /// Their worst dual gap left, relative to the cost (0 where the cells met their
  /// tolerance; see ShapeOptions::cost_tolerance).
  double max_relative_cost_gap = 0;
  bool converged = true;
  /// Sphere, per direction (forward: the first shape's density as the source): the lower
  /// density cap its transport needed to converge (0: the shape's own sufficed) and how far
  /// that moved the source measure in W2, on top of Shape::density_shift.
  std::array<double, 2> lowered_cap{}, lowered_shift{};
  /// Sphere: 0 or 1 where `distance` is that direction alone (0: forward, the first shape's
  /// density as the source), the other not solved (NaN); -1: the mean of both.
  int source = -1;
  /// Wasserstein with WassersteinOptions::exact_rotation: every turn (disk) or frame
  /// half-turn (sphere) compared by the exact cost, the chosen one first.
  struct Candidate {
    double rotation = 0;  // disk: radians
    int frame = 0;        // sphere: 0 identity, 1-3 the half-turn about that axis
    double omt_map = 0;   // the OMT-map distance there (an upper bound of the measures' W2)
    /// The exact distance (mean of both directions) where both converged; NaN otherwise.
    double distance = std::numeric_limits<double>::quiet_NaN();
    /// A lower bound of that distance from the transports' duals: the distance itself where
    /// they converged, less where the candidate was abandoned.
    double lower_bound = 0;
    bool abandoned = false;  // dropped once lower_bound passed the best distance (less its tolerance)
    int newton_iterations = 0;
  };
  std::vector<Candidate> candidates;
  bool sphere_frames = false;  // the candidates are the sphere frame's half-turns
  /// Every candidate but the chosen one converged above it or was abandoned with its lower
  /// bound above it less the tolerance (false where one stopped short).
  bool rotation_certified = false;
};

/// The OMT-map shape distance of Def. 2.24 as a linear embedding: the L2 distance between
/// the two shapes' OMT maps of the uniform disk, T_a and T_b, by the fixed quadrature,
///   d^2 = sum_q w_q |T_a(x_q) - T_b(x_q)|^2.
/// Without markers the second map is turned, T_b -> R T_b R^{-1}, by the rotation R among the
/// multiples of 2 pi / angles that minimizes d (the minimum over Moebius maps of Def. 2.24
/// once both are centred): on the quadrature a turn is a cyclic shift of each ring, so all
/// turns are scored at once by one cross-correlation (FFT) per pair. Over that finite group
/// of isometries the minimum is a metric on the shapes (symmetric, triangle inequality).
/// On the sphere (Shape::sphere) the same with the maps sampled on the band quadrature, in
/// each shape's principal frame, minimized over the frame's four sign choices (identity and
/// the half-turns about its axes), each a permutation of the samples (sphere_half_turn):
/// again a metric over a finite group of isometries.
PairResult omt_linear(const Shape& a, const Shape& b);

/// The permutation of the sphere quadrature's points under the half-turn about axis 1, 2 or
/// 3 (0: the identity): point q goes to point result[q]. Needs an even number of angles.
std::vector<int> sphere_half_turn(int axis, const Quadrature& quad);

struct WassersteinOptions {
  /// Without markers, refine the rotation of the second shape beyond the quadrature's
  /// 2 pi / angles steps (a parabola through three exact evaluations, then its vertex).
  /// Off by default: it costs three to four times the transports and moved mushroom vs
  /// three_peaks by 5e-5 of the distance.
  bool refine_rotation = false;
  /// Remove the quantization bias of the semi-discrete cost. Sending the density mu_A to
  /// B's vertex measure costs about W2^2(mu_A, mu_B) plus what quantizing mu_B onto its own
  /// vertices costs (the cross term averages out over the small cells), q_B =
  /// W2^2(mu_B, nu_B), computed once per shape (Shape::quantization). The debiased
  /// distance sqrt(max(0, W2^2(mu_A, nu_B) - q_B)) estimates the distance between the two
  /// surfaces' measures to O(h^2) instead of O(h), and d(A, A) is exactly 0 (the same
  /// transport is solved on both sides of the difference).
  bool debias = true;
  /// Choose the turn by the exact cost, not by the OMT-map distance alone. Disk: the OMT-map
  /// distance's local minima over the quadrature's turns are the candidates; sphere: the
  /// frame's four half-turns. The OMT-map's best is solved first; each other candidate is
  /// solved until it beats it or until the transports' duals (lower bounds of its cost) show
  /// it at most the distance's tolerance below it (PairResult::candidates: a certificate).
  bool exact_rotation = false;
  /// Solve the two directions on two threads (one OpenMP thread each): for a single pair.
  /// A matrix runs its pairs on its own pool and leaves this off.
  bool parallel_directions = false;
  omt::Progress progress;
};

/// One direction of Alg. 5 (eq. 3.31): W2^2 from src's pushed-forward density to dst's
/// vertex images turned by `angle`, with dst's vertex masses, to dst's transport and cost
/// tolerances. `h` is the start (empty: dst's heights for the uniform disk) and gets the
/// solution's heights.
struct TransportCost {
  double w2_squared = std::numeric_limits<double>::quiet_NaN();
  int iterations = 0;
  double max_relative_error = std::numeric_limits<double>::infinity();
  double relative_cost_gap = 0;  // the dual's rise left over the cost, when the cost test stopped it
  bool converged = false;
  bool abandoned = false;  // stopped by the caller's bound (omt::OmtOptions::abandon)
  std::string failure;  // why the solve stopped, when it threw
  /// Sphere: > 0 where the transport did not converge from the source shape's density and
  /// did from that density held to this lower cap (transport_cost_sphere's retry); the
  /// cap moved the source measure by at most density_shift more in W2.
  double density_cap = 0, density_shift = 0;
};
/// OmtOptions::abandon for one direction of a pair.
using Abandon = std::function<bool(double lower_bound)>;
TransportCost transport_cost(const Shape& src, const Shape& dst, double angle, const omt::Progress& progress,
                             Eigen::VectorXd& h, const Abandon& abandon = {});
/// On the sphere (squared chordal cost): src's density on its flat image triangles to dst's
/// vertex images, each coordinate of the frame multiplied by flip (+-1: a half-turn of dst's
/// principal frame), to dst's cell tolerance; the cost is the Kantorovich dual. Where that
/// transport does not converge (src a different shape from dst), it is solved again with
/// src's density held to a tenth, then a hundredth, of its peak (cap_density), then to 100
/// times its mean where that is lower still, and the result says which cap and bound it took
/// (TransportCost::density_cap). The caps tried are the levels first..last of: 0 the shape's
/// own density, 1 a tenth, 2 a hundredth of its peak, 3 100 times its mean (sphere_cap). A
/// level whose cap does not lower the one before is skipped; when no level runs, the result
/// is not converged with no iterations.
constexpr int kLowestCapLevel = 3;
/// The cap of level 1..kLowestCapLevel on src's sphere density; 0 where the level is skipped
/// (level 3 on densities whose peak is at most 1e4 times their mean).
double sphere_cap(const Shape& src, int level);
TransportCost transport_cost_sphere(const Shape& src, const Shape& dst, const Eigen::Vector3d& flip,
                                    const omt::Progress& progress, Eigen::VectorXd& h, const Abandon& abandon = {},
                                    int first_level = 0, int last_level = kLowestCapLevel);

/// The conformal Wasserstein distance (Alg. 5, eq. 3.31): the source is the first shape's
/// pushed-forward area density (piecewise constant on its conformal image), the sites the
/// second's conformal vertex images with their masses; semi-discrete OMT (Alg. 2) and
///   W2^2 = sum_i int_{W_i} |x - p_i|^2 mu(x) dx.
/// Computed both ways (the discretization makes them differ slightly); `distance` is the
/// mean of the two W2. On the sphere, where one shape's density was capped on more mass
/// than the other's (Shape::capped_mass), the distance is the direction from the other,
/// less crowded, density alone, when that converges at the shapes' own caps
/// (PairResult::source); otherwise both directions at a tenth, then a hundredth of the
/// peaks, then at 100 times the means (the directions whose density that lowers), the
/// distance being the mean of those that converged at the first such cap where one did.
/// Without markers, the second shape is turned by the rotation found by omt_linear (then
/// refined, see the options). A transport that does not converge makes converged false
/// with its error, never a silent value.
PairResult wasserstein(const Shape& a, const Shape& b, const WassersteinOptions& options = {});

}  // namespace brenier::distance

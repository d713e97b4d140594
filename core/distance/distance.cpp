#include "distance/distance.hpp"

#include <unsupported/Eigen/FFT>

#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <mutex>
#include <vector>

#include "common/check.hpp"
#include "common/error.hpp"
#include "common/parallel.hpp"
#include "mesh/geometry.hpp"

namespace brenier::distance {

namespace {

using cd = std::complex<double>;

// OmtOptions::stall_window of a pair's transports: 60 Newton iterations. On the sphere a lower
// cap follows a stalled solve: dino x bear's fine level fell 39.5x -> 35.3x off in 200 (3 %
// per 60). On the disk the plain start follows it, with the iterations left: mannequin-devil
// x its deformed copy's fine level held at 77.5x off for 200. Steps of t = 1/256, the slowest
// that went on to converge, guarantee 11 % per 60.
constexpr int kStallWindow = 60;

void require_comparable(const Shape& a, const Shape& b) {
  if (a.sphere != b.sphere)
    invalid("'" + a.name + "' and '" + b.name + "' were mapped onto different domains (disk and sphere)");
  if (a.sphere) {
    if (a.rings != b.rings || a.angles != b.angles)
      invalid("'" + a.name + "' and '" + b.name + "' were sampled on different quadratures");
    return;
  }
  if (a.markers != b.markers)
    invalid("'" + a.name + "' and '" + b.name + "': give markers for both shapes or for neither");
  if (a.samples.rows() != b.samples.rows() || a.samples.cols() != b.samples.cols())
    invalid("'" + a.name + "' and '" + b.name + "' were sampled on different quadratures");
}

struct Turn {
  int shift = 0;     // T_b's samples move `shift` places along each ring
  double angle = 0;  // 2 pi shift / angles
};

// The turn R minimizing sum_q |a_q - (R T_b R^{-1})(x_q)|^2. On ring r, point k sits at
// angle phi_k, and R^{-1} x_{r,k} = x_{r,k-s} for R the turn by 2 pi s / A, so the turned
// map's sample is e^{i theta_s} b_{r,k-s} and the sum is |a|^2 + |b|^2 - 2 Re(e^{i theta_s}
// c(s)) with c(s) = sum_{r,k} conj(a_{r,k}) b_{r,k-s}. By the DFTs of the rings (a_hat,
// b_hat), c(s) = (1/A) sum_m conj(a_hat_{r,m}) b_hat_{r,m} e^{-2 pi i m s / A}: one forward
// transform of the ring-summed product gives every c(s).
//
// Every turn's score, the candidates being the local maxima (the OMT-map distance's local
// minima over the turns), best first; ties keep the first turn, so the same on every run.
std::vector<Turn> candidate_turns(const Shape& a, const Shape& b) {
  if (a.markers) return {Turn{}};
  const int R = static_cast<int>(a.samples.rows()), A = static_cast<int>(a.samples.cols());
  std::vector<cd> x(A, cd(0, 0)), c(A);
  for (int m = 0; m < A; ++m)
    for (int r = 0; r < R; ++r) x[m] += std::conj(a.spectrum(r, m)) * b.spectrum(r, m);
  Eigen::FFT<double> fft;
  fft.fwd(c, x);
  std::vector<double> score(A);
  for (int s = 0; s < A; ++s) score[s] = std::real(std::polar(1.0, 2 * M_PI * s / A) * c[s]);
  std::vector<Turn> out;
  for (int s = 0; s < A; ++s) {
    const double left = score[(s + A - 1) % A], right = score[(s + 1) % A];
    if (score[s] > left && score[s] >= right) out.push_back({s, 2 * M_PI * s / A});
  }
  if (out.empty()) out.push_back({0, 0.0});  // a constant score: every turn alike
  std::stable_sort(out.begin(), out.end(), [&](const Turn& p, const Turn& q) { return score[p.shift] > score[q.shift]; });
  return out;
}

Turn best_turn(const Shape& a, const Shape& b) { return candidate_turns(a, b).front(); }

// sum_q w |a_q - e^{i theta} b_{r,k-s}|^2, summed directly (the FFT only chose s).
double squared_distance(const Shape& a, const Shape& b, const Turn& t) {
  const int R = static_cast<int>(a.samples.rows()), A = static_cast<int>(a.samples.cols());
  const cd turn = std::polar(1.0, t.angle);
  double sum = 0;
  for (int r = 0; r < R; ++r)
    for (int k = 0; k < A; ++k) sum += std::norm(a.samples(r, k) - turn * b.samples(r, ((k - t.shift) % A + A) % A));
  return sum * M_PI / (static_cast<double>(R) * A);
}

std::string turn_words(const Shape& a, int angles) {
  if (a.markers) return "markers (interior vertex at 0, boundary vertex at 1)";
  return "Moebius centring (area centre of mass at 0), rotation minimized over multiples of 2 pi / " +
         std::to_string(angles);
}

}  // namespace

namespace {

// Runs a transport; a failure of the method on valid input (cells too small for doubles) is
// reported as not converged, since both shapes were mapped and transported already.
template <class Solve>
bool guarded(TransportCost& out, Solve solve) {
  try {
    solve();
    return true;
  } catch (const Error& e) {
    if (e.code() != ErrorCode::kInvalidArgument && e.code() != ErrorCode::kNotConverged) throw;
    out.failure = e.what();
    return false;
  }
}

// One direction's transport onto dst's vertices, to dst's tolerances (`o` brings the rest):
// `solve(o)` gives an omt::OmtResult or omt::SurfaceOmtResult. The cost is the Kantorovich
// dual at the heights (the OMT energy of eq. 3.25 up to sign and constants):
//   sum_i int_{W_i} |x - y_i|^2 dmu - sum_i w_i (mu(W_i) - nu_i),  w_i = |y_i|^2 + 2 h_i.
// It equals eq. 3.31 at the solution and is stationary there, so its error is quadratic in
// the heights' error where the primal sum's is linear (measured on a 5K pair: 6e-11 relative
// with the cells 1e-2 off their masses, where eq. 3.31 was 2e-6 off). Where the cost test
// stopped the solve, the Newton step's predicted rise is added (third order).
// An abandoned solve (OmtOptions::abandon) leaves h as it was, with w2_squared its dual bound.
template <class Solve>
TransportCost transport_to(const Shape& dst, const omt::Progress& progress, const Abandon& abandon,
                           omt::OmtOptions o, Eigen::VectorXd& h, Solve solve) {
  o.tolerance = dst.transport_tolerance;
  o.dual_gap_tolerance = dst.cost_tolerance;
  o.progress = progress;
  o.abandon = abandon;
  TransportCost out;
  decltype(solve(o)) r;
  if (!guarded(out, [&] { r = solve(o); })) return out;
  out.iterations = r.iterations;
  out.max_relative_error = r.max_relative_error;
  out.converged = r.converged;
  out.abandoned = r.abandoned;
  out.w2_squared = r.dual_value + r.dual_rise;
  if (r.abandoned) return out;
  if (r.dual_rise > 0) out.relative_cost_gap = r.dual_rise / std::abs(r.dual_value);
  h = r.h;
  return out;
}

}  // namespace

// The caps of transport_cost_sphere's retry (issue 23). Levels 1 and 2 are fractions of the
// density's own peak. Where the peak is far above the mean, a hundredth of it still leaves the
// transport a range that stalls: man-deformed's density peaks at 62,157 times its mean and
// man-twisted's at 162,384, so their hundredths (622 and 1,624) are 6-16 times armadillo's, and
// armadillo-twisted x man-deformed ended 19-3,330x off after 1,949 Newton iterations. Held to
// 100 times the mean, the matrix's three such pairs converged (bench/RESULTS.md, sessions 81-82).
// Level 3 is that cap, tried only where it is below the hundredth: every pair that converged
// at the earlier levels keeps its value. A cap not above the mean is skipped at every level:
// it leaves no room for the mass (cap_density's check; a nearly uniform density's tenth).
double sphere_cap(const Shape& src, int level) {
  BRENIER_CHECK(src.surface && level >= 1 && level <= kLowestCapLevel, "no sphere cap level " << level);
  const omt::SurfaceDensity& s = *src.surface;
  const double peak = s.density.maxCoeff();
  const Eigen::VectorXd image = mesh::face_areas(s.faces, s.vertices);
  const double mean = s.density.dot(image) / image.sum();
  const double cap = level == 1 ? peak / 10 : level == 2 ? peak / 100 : std::min(100 * mean, peak / 100);
  return cap > mean && (level < kLowestCapLevel || cap < peak / 100) ? cap : 0;
}

TransportCost transport_cost_sphere(const Shape& src, const Shape& dst, const Eigen::Vector3d& flip,
                                    const omt::Progress& progress, Eigen::VectorXd& h, const Abandon& abandon,
                                    int first_level, int last_level) {
  if (!src.surface || dst.sphere_sites.rows() != dst.mass.size())
    invalid("'" + src.name + "' or '" + dst.name + "' has no sphere image for the exact distance");
  omt::Points3 sites = dst.sphere_sites;
  for (Eigen::Index i = 0; i < sites.rows(); ++i) sites.row(i) = sites.row(i).cwiseProduct(flip.transpose());
  omt::OmtOptions o;
  if (h.size()) o.initial_h = h;
  o.multilevel = true;  // real shapes' sphere densities span orders of magnitude too
  // Where a lower cap follows (below), a solve that creeps stops early (OmtOptions::
  // stall_window): the stalled first attempts took most of a crowded pair's time.
  const bool retry = &src != &dst;
  if (retry) o.stall_window = kStallWindow;
  TransportCost c;
  if (first_level == 0) {
    c = transport_to(dst, progress, abandon, o, h, [&](const omt::OmtOptions& oo) {
      return omt::solve_surface_omt(*src.surface, sites, dst.mass, oo);
    });
    if (c.converged || c.abandoned || !retry || last_level == 0) return c;
  }
  // The retry at lower caps (issue 23). bear's 13,826 sites into dino's density (29 % of its
  // mass at the 1e4 cap) stall: every refused trial of the line search empties a few small
  // cells in the peaks, whose sides move by dh / 0.03 across cells 1e-3 wide, and the steps
  // stay at t ~ 1e-3 for 600 iterations; warm starts from a solution at a lower cap stall
  // the same way. At a tenth of the peak man x bear converges (345 iterations); dino x bear
  // needs a hundredth (188). Each retry starts afresh (the coarse-to-fine start); its bound
  // adds to the shape's own by the triangle inequality. Raising the heights of the few sites
  // a refused trial empties, to their neighbours' step, did not help: their neighbours
  // emptied instead (bench/RESULTS.md, session 40). An exact frame search's lower bounds
  // (`abandon`) then mix the duals of both densities: each holds within the lowered cap's
  // shift, which the result states.
  const omt::SurfaceDensity& surface = *src.surface;
  const Eigen::VectorXd image = mesh::face_areas(surface.faces, surface.vertices);
  for (int level = std::max(1, first_level); level <= last_level; ++level) {
    const double cap = sphere_cap(src, level);
    if (cap == 0) break;  // skipped: c is the level before's
    // The hundredth and the mean cap run to their end: the hundredth was the last cap before
    // the mean cap came, and a window there would change pairs that converged late at it.
    o.stall_window = level == 1 ? kStallWindow : 0;
    omt::SurfaceDensity lower = surface;
    Eigen::VectorXd mass = surface.density.cwiseProduct(image);
    const DensityCap moved = cap_density(surface.faces, surface.vertices, image, cap, mass);
    lower.density = mass.cwiseQuotient(image);
    Eigen::VectorXd start = h;
    const int before = c.iterations;
    c = transport_to(dst, progress, abandon, o, start,
                     [&](const omt::OmtOptions& oo) { return omt::solve_surface_omt(lower, sites, dst.mass, oo); });
    c.iterations += before;
    c.density_cap = cap;
    c.density_shift = moved.shift;
    if (c.converged || c.abandoned) {
      h = start;
      break;
    }
  }
  return c;
}

TransportCost transport_cost(const Shape& src, const Shape& dst, double angle, const omt::Progress& progress,
                             Eigen::VectorXd& h, const Abandon& abandon) {
  const omt::Domain domain = src.density_domain ? *src.density_domain
                                                : omt::Domain::piecewise_constant(src.sites, src.tri, src.density);
  const double c = std::cos(angle), s = std::sin(angle);
  omt::Points sites(dst.sites.rows(), 2);
  sites.col(0) = c * dst.sites.col(0) - s * dst.sites.col(1);
  sites.col(1) = s * dst.sites.col(0) + c * dst.sites.col(1);
  omt::OmtOptions o;
  // dst's heights for the uniform disk: the cells start at the right areas, only the
  // density differs (measured, source three_peaks to mushroom's sites: 24 Newton iterations
  // where Alg. 2's Voronoi start took 52).
  o.initial_h = h.size() ? h : dst.h;
  // Real shapes' densities span orders of magnitude, which that start does not meet: the
  // coarse-to-fine start (bench/RESULTS.md, issue 23 session 19).
  o.multilevel = true;
  if (&src != &dst) o.stall_window = kStallWindow;  // a pair's, not a shape's quantization
  // The rival of that start (OmtOptions::alternative_h): dst's heights for its own density,
  // from its quantization, the better start where src is a copy of dst, deformed or remeshed,
  // and taken there by the dual. mannequin-devil's density onto its remeshed copy's 51,841
  // sites: the coarse-to-fine start's fine level fell from 153x to 93x off in 200 iterations
  // and the pair did not converge; from these heights (168x off, but D = 1.2e-4 against
  // -3.8e-4) it converged in 57. Unrelated shapes keep the coarse-to-fine start (lion-head x
  // mannequin-devil: D = 0.047 against 0.0013). (bench/RESULTS.md, session 43.)
  if (&src != &dst && h.size() == 0) o.alternative_h = dst.quantization_h;
  return transport_to(dst, progress, abandon, o, h,
                      [&](const omt::OmtOptions& oo) { return omt::solve_omt(domain, sites, dst.mass, oo); });
}


std::vector<int> sphere_half_turn(int axis, const Quadrature& quad) {
  const int R = quad.rings, A = quad.angles;
  if (axis < 0 || axis > 3 || A % 2 != 0) invalid("sphere_half_turn: axis 0..3 and an even number of angles");
  std::vector<int> to(static_cast<size_t>(R) * A);
  for (int k = 0; k < R; ++k)
    for (int j = 0; j < A; ++j) {
      // z -> -z flips the band; the longitude phi goes to -phi (first axis), pi - phi
      // (second) or phi + pi (third).
      int k2 = k, j2 = j;
      if (axis == 1) k2 = R - 1 - k, j2 = A - 1 - j;
      if (axis == 2) k2 = R - 1 - k, j2 = ((A / 2 - 1 - j) % A + A) % A;
      if (axis == 3) j2 = (j + A / 2) % A;
      to[static_cast<size_t>(k) * A + j] = k2 * A + j2;
    }
  return to;
}

namespace {

// On the sphere: the frames of both shapes are their principal frames, known up to the
// half-turns g about the frame's axes (sign choices of a right-handed frame). Turning B by g
// makes its map g T_B g (g is its own inverse); on the band quadrature, g x_q is another
// point x_{pi_g(q)}, so each candidate is a permutation of B's samples.
const Eigen::Vector3d kFlips[4] = {{1, 1, 1}, {1, -1, -1}, {-1, 1, -1}, {-1, -1, 1}};

const char* const kFrameNames[4] = {"identity", "half-turn about the first axis", "half-turn about the second axis",
                                    "half-turn about the third axis"};

// The OMT-map distance with B under the half-turn g of its frame.
double omt_linear_frame(const Shape& a, const Shape& b, int g) {
  Quadrature quad;
  quad.rings = a.rings;
  quad.angles = a.angles;
  const std::vector<int> to = sphere_half_turn(g, quad);
  double sum = 0;
  for (int q = 0; q < a.rings * a.angles; ++q) {
    const Eigen::Vector3d ta = a.sphere_samples.row(q).transpose(), tb = b.sphere_samples.row(to[q]).transpose();
    sum += (ta - kFlips[g].cwiseProduct(tb)).squaredNorm();
  }
  return std::sqrt(sum * 4 * M_PI / (static_cast<double>(a.rings) * a.angles));
}

PairResult omt_linear_sphere(const Shape& a, const Shape& b) {
  PairResult out;
  out.distance = std::numeric_limits<double>::infinity();
  for (int g = 0; g < 4; ++g) {
    const double d = omt_linear_frame(a, b, g);
    if (d < out.distance) {
      out.distance = d;
      out.normalization = std::string("Moebius centring, principal frames, ") + kFrameNames[g] + " of the second shape";
    }
  }
  out.normalization += " (the best of the frame's four sign choices)";
  return out;
}

}  // namespace

PairResult omt_linear(const Shape& a, const Shape& b) {
  require_comparable(a, b);
  if (a.sphere) return omt_linear_sphere(a, b);
  const Turn t = best_turn(a, b);
  PairResult out;
  out.distance = std::sqrt(std::max(0.0, squared_distance(a, b, t)));
  out.rotation = t.angle;
  out.normalization = turn_words(a, static_cast<int>(a.samples.cols()));
  return out;
}

namespace {

// Which directions of a pair are solved: forward (0, a's density to b's sites), backward (1).
using Directions = std::array<bool, 2>;
constexpr Directions kBoth = {true, true};

// The lower bound of a candidate's distance while its two directions run: each direction's
// Kantorovich dual bounds its W2^2 from below at every iterate (weak duality), so
//   d >= 1/2 (sqrt(D_ab - q_b) + sqrt(D_ba - q_a))   (q: the debiasing terms),
// or d >= sqrt(D - q) of the one direction solved. Once that passes the ceiling, the
// directions are told to stop.
class PairBound {
 public:
  PairBound(double q_forward, double q_backward, double ceiling, Directions use)
      : q_{q_forward, q_backward}, ceiling_(ceiling), use_(use) {}
  bool update(int k, double w2_squared) {
    std::lock_guard<std::mutex> lock(mutex_);
    lb_[k] = std::max(lb_[k], w2_squared);
    return bound_locked() > ceiling_;
  }
  double bound() {
    std::lock_guard<std::mutex> lock(mutex_);
    return bound_locked();
  }

 private:
  double bound_locked() const {
    double sum = 0;
    for (int k = 0; k < 2; ++k)
      if (use_[k]) sum += std::sqrt(std::max(0.0, lb_[k] - q_[k]));
    return sum / (use_[0] + use_[1]);
  }
  std::mutex mutex_;
  double q_[2], lb_[2] = {0, 0}, ceiling_;
  Directions use_;
};

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// One candidate (a turn of b's disk image, or a half-turn of its frame), both directions.
struct Eval {
  double angle = 0;
  int frame = 0;
  double mean = 0;
  double forward = kNaN, backward = kNaN, raw_forward = kNaN, raw_backward = kNaN;  // NaN: not solved
  double lower_bound = 0;
  bool converged = true, abandoned = false;
  int iterations = 0;
  double max_relative_error = 0, max_relative_cost_gap = 0;
  std::array<double, 2> lowered_cap{}, lowered_shift{};  // TransportCost::density_cap, per direction
  int source = -1;          // PairResult::source
  Eigen::VectorXd h[2];     // the heights reached (b's sites, a's sites)
  TransportCost cost[2];    // per direction solved
};

class PairSolver {
 public:
  PairSolver(const Shape& a, const Shape& b, const WassersteinOptions& opt) : a_(a), b_(b), opt_(opt) {
    if (opt.progress)  // one call's progress at a time, when the two directions run side by side
      progress_ = [this](int iteration, double residual) {
        std::lock_guard<std::mutex> lock(progress_mutex_);
        return opt_.progress(iteration, residual);
      };
  }

  /// The candidate solved, from `start` (empty: each shape's uniform heights), each
  /// direction dropped once the pair's bound passes `ceiling`.
  Eval disk(double angle, const Eigen::VectorXd (&start)[2], double ceiling) {
    Eval e;
    e.angle = angle;
    solve(e, start, ceiling, kBoth, [&](int k, Eigen::VectorXd& h, const Abandon& ab) {
      return k == 0 ? transport_cost(a_, b_, angle, progress_, h, ab) : transport_cost(b_, a_, -angle, progress_, h, ab);
    });
    return e;
  }
  // On the sphere, b's density goes backwards to a's vertices under the same half-turn (it
  // is its own inverse: W2(g mu_B, nu_A) = W2(mu_B, g nu_A)).
  Eval sphere(int g, double ceiling);

 private:
  int sphere_source() const;
  // The directions in `use` (forward, backward) of candidate e; e's value is their mean.
  template <class Direction>
  void solve(Eval& e, const Eigen::VectorXd (&start)[2], double ceiling, Directions use, Direction direction) {
    const bool watch = std::isfinite(ceiling);
    PairBound bound(opt_.debias ? b_.quantization : 0.0, opt_.debias ? a_.quantization : 0.0, ceiling, use);
    TransportCost* c = e.cost;
    std::vector<int> solved;
    for (int k = 0; k < 2; ++k)
      if (use[k]) solved.push_back(k);
    const int count = static_cast<int>(solved.size());
    parallel_for(count, opt_.parallel_directions ? count : 1, [&](int j) {
      const int k = solved[j];
      e.h[k] = start[k];
      Abandon ab;
      if (watch) ab = [&bound, k](double w) { return bound.update(k, w); };
      c[k] = direction(k, e.h[k], ab);
      if (watch && c[k].converged) bound.update(k, c[k].w2_squared);
    });
    for (int k : solved) e.iterations += c[k].iterations;
    combine(e, use, bound.bound());
  }

  /// e's figures from its directions in `use` (the value their mean); `bound` is the dual
  /// bound of the value, taken where one of them did not converge.
  void combine(Eval& e, Directions use, double bound) const {
    const Shape* dst[2] = {&b_, &a_};
    double* value[2] = {&e.forward, &e.backward};
    double* raw[2] = {&e.raw_forward, &e.raw_backward};
    const int count = use[0] + use[1];
    e.mean = e.max_relative_error = e.max_relative_cost_gap = 0;
    e.converged = true;
    e.abandoned = false;
    for (int k = 0; k < 2; ++k) {
      const TransportCost& c = e.cost[k];
      *value[k] = *raw[k] = kNaN;
      e.lowered_cap[k] = e.lowered_shift[k] = 0;
      if (!use[k]) continue;
      e.abandoned = e.abandoned || c.abandoned;
      e.converged = e.converged && c.converged;
      e.max_relative_error = std::max(e.max_relative_error, c.max_relative_error);
      e.max_relative_cost_gap = std::max(e.max_relative_cost_gap, c.relative_cost_gap);
      e.lowered_cap[k] = c.density_cap;
      e.lowered_shift[k] = c.density_shift;
      *raw[k] = std::sqrt(std::max(0.0, c.w2_squared));
      *value[k] = std::sqrt(std::max(0.0, c.w2_squared - (opt_.debias ? dst[k]->quantization : 0.0)));
      e.mean += *value[k] / count;
    }
    e.lower_bound = e.converged ? e.mean : bound;
    if (e.abandoned) e.converged = false;
    e.source = count == 2 ? -1 : use[0] ? 0 : 1;
  }

  const Shape& a_;
  const Shape& b_;
  const WassersteinOptions& opt_;
  std::mutex progress_mutex_;
  omt::Progress progress_;
};

// Issue 23: where one shape's conformal density was capped on more mass than the other's
// (Shape::capped_mass; the crowded sphere maps of elongated shapes: dino 29 %, camel 27 %,
// bull 12 %), the transport from that density is the one that stalls and needs a lowered
// cap, whose shift then bounds the distance loosely (dino x bear: 0.166 on 1.17), while the
// transport from the other density converges at the shapes' own caps, within a few per
// cent of the time. Both directions estimate the same W2 of the two measures (debiased, they
// agree to 0.1 % where both converge: bear x bull 1.0730 / 1.0737), so that direction alone
// is the distance: the less crowded density onto the more crowded shape's sites. Equal
// capped masses (none capped: most shapes) keep both directions, each lowering its own cap
// as it needs. The choice depends on the pair, not on its order: d(A, B) = d(B, A).
int PairSolver::sphere_source() const {
  if (a_.capped_mass == b_.capped_mass) return -1;
  return a_.capped_mass < b_.capped_mass ? 0 : 1;
}

// Where that one direction does not converge at the own caps either (two crowded copies of
// one shape: dino x its remeshed copy, whose peaks sit apart by more than their width), both
// directions are solved at a tenth of the peaks, then at a hundredth, then at 100 times the
// means (only the directions whose density that lowers: sphere_cap), side by side; the
// first cap at which one converges gives the distance, the mean of those that did there
// (dino x remeshed dino: at a hundredth, only the copy's density onto dino's sites). Where
// none converges, the value shows each direction's dual at its last cap.
Eval PairSolver::sphere(int g, double ceiling) {
  const Eigen::VectorXd none[2];
  auto run = [&](Directions use, int first, int last) {
    Eval e;
    e.frame = g;
    solve(e, none, ceiling, use, [&](int k, Eigen::VectorXd& h, const Abandon& ab) {
      return k == 0 ? transport_cost_sphere(a_, b_, kFlips[g], progress_, h, ab, first, last)
                    : transport_cost_sphere(b_, a_, kFlips[g], progress_, h, ab, first, last);
    });
    return e;
  };
  const int k = sphere_source();
  if (k < 0) return run(kBoth, 0, kLowestCapLevel);
  Eval e = run({k == 0, k == 1}, 0, 0);
  int iterations = e.iterations;
  for (int level = 1; level <= kLowestCapLevel && !e.converged && !e.abandoned; ++level) {
    const Directions use = {sphere_cap(a_, level) > 0, sphere_cap(b_, level) > 0};
    if (!use[0] && !use[1]) break;
    Eval next = run(use, level, level);
    iterations += next.iterations;
    // A level that skips one direction and does not converge either reports both duals: the
    // skipped direction's as it ended at the level before, if it was solved (its dual, at
    // heights short of the solution, is a lower bound, as PairBound's).
    const int j = use[0] ? 1 : 0;
    if (!(use[0] && use[1]) && !next.converged && !next.abandoned && !std::isnan(j ? e.raw_backward : e.raw_forward)) {
      next.cost[j] = std::move(e.cost[j]);
      next.h[j] = std::move(e.h[j]);
      combine(next, kBoth, 0.0);
      next.lower_bound = next.mean;
    }
    e = std::move(next);
    for (int j = 0; j < 2 && !e.converged && !e.abandoned; ++j)
      if (e.cost[j].converged) combine(e, {j == 0, j == 1}, 0.0);
  }
  e.iterations = iterations;
  return e;
}

// The candidates after the first: each solved while it may still beat `best` by more than
// the distance's tolerance (half the transports' relative cost tolerance, as d = sqrt(W2^2)),
// and taken only if it does (within the tolerance the OMT-map's choice stands: shapes with a
// symmetry have several turns equal up to round-off). `certify`: the search was asked for;
// `solve(k, ceiling)` gives candidate k's Eval, `omt_map[k]` its OMT-map distance.
template <class Solve>
void search_candidates(int count, const Shape& a, bool certify, Eval& best, PairResult& out, Solve solve,
                       const std::vector<double>& omt_map) {
  auto record = [&](const Eval& e, double d) {
    PairResult::Candidate c;
    c.rotation = e.angle;
    c.frame = e.frame;
    c.omt_map = d;
    if (e.converged) c.distance = e.mean;
    c.lower_bound = e.lower_bound;
    c.abandoned = e.abandoned;
    c.newton_iterations = e.iterations;
    out.candidates.push_back(c);
    out.newton_iterations += e.iterations;
  };
  record(best, omt_map[0]);
  out.rotation_certified = certify && best.converged;
  for (int k = 1; k < count && best.converged; ++k) {
    const double ceiling = best.mean * (1 - 0.5 * a.cost_tolerance);
    Eval e = solve(k, ceiling);
    record(e, omt_map[k]);
    // Settled: converged (then compared), or abandoned with its bound above the ceiling.
    out.rotation_certified = out.rotation_certified && (e.converged || e.abandoned);
    if (e.converged && e.mean < ceiling) best = std::move(e);
  }
}

void take(PairResult& out, const Eval& best, bool debias) {
  out.rotation = best.angle;
  out.forward = best.forward;
  out.backward = best.backward;
  out.raw_forward = best.raw_forward;
  out.raw_backward = best.raw_backward;
  out.converged = best.converged;
  out.max_relative_error = best.max_relative_error;
  out.max_relative_cost_gap = best.max_relative_cost_gap;
  out.lowered_cap = best.lowered_cap;
  out.lowered_shift = best.lowered_shift;
  out.source = best.source;
  if (debias) out.normalization += "; quantization bias removed";
  out.distance = out.converged ? best.mean : std::numeric_limits<double>::quiet_NaN();
}

PairResult wasserstein_sphere(const Shape& a, const Shape& b, const WassersteinOptions& opt) {
  // The squared chordal cost between A's density (on the flat triangles of its sphere
  // image) and B's vertices, B in a half-turn of its principal frame.
  PairResult out;
  out.sphere_frames = true;
  PairSolver solver(a, b, opt);
  // The half-turns by their OMT-map distance, ties in index order: the first is
  // omt_linear_sphere's choice, the others the likelier to win first.
  double frame_distance[4];
  for (int g = 0; g < 4; ++g) frame_distance[g] = omt_linear_frame(a, b, g);
  std::vector<int> order = {0, 1, 2, 3};
  std::stable_sort(order.begin(), order.end(), [&](int p, int q) { return frame_distance[p] < frame_distance[q]; });
  if (!opt.exact_rotation) order.resize(1);
  std::vector<double> omt_map;
  for (int g : order) omt_map.push_back(frame_distance[g]);
  Eval best = solver.sphere(order[0], std::numeric_limits<double>::infinity());
  search_candidates(static_cast<int>(order.size()), a, opt.exact_rotation, best, out,
                    [&](int k, double ceiling) { return solver.sphere(order[k], ceiling); }, omt_map);
  out.normalization = std::string("Moebius centring, principal frames, ") + kFrameNames[best.frame] +
                      " of the second shape, " +
                      (opt.exact_rotation ? "the least exact cost of the frame's four sign choices"
                                          : "chosen by the OMT-map distance") +
                      "; squared chordal cost, the density on the flat triangles of the sphere image";
  take(out, best, opt.debias);
  if (out.source >= 0) {
    const Shape& src = out.source == 0 ? a : b;
    const Shape& dst = out.source == 0 ? b : a;
    const bool lowered = out.lowered_cap[out.source] > 0;
    out.normalization += "; one direction: " + src.name + "'s density onto " + dst.name + "'s sites (" +
                         (lowered ? "the other did not converge at that lowered cap"
                                  : dst.name + "'s density is capped on more mass") + ")";
  }
  return out;
}

}  // namespace

PairResult wasserstein(const Shape& a, const Shape& b, const WassersteinOptions& opt) {
  require_comparable(a, b);
  if (a.transport_tolerance != b.transport_tolerance || a.cost_tolerance != b.cost_tolerance)
    invalid("'" + a.name + "' and '" + b.name + "' were prepared with different transport tolerances");
  if (a.sphere) return wasserstein_sphere(a, b, opt);
  PairResult out;
  const int A = static_cast<int>(a.samples.cols());
  out.normalization = turn_words(a, A);
  PairSolver solver(a, b, opt);
  // The candidates: the OMT-map distance's local minima within kCandidateWindow of its best
  // (where it upper-bounds the measures' W2 about as closely as at its best), at most
  // kMaxCandidates of them.
  constexpr double kCandidateWindow = 0.10;
  constexpr size_t kMaxCandidates = 8;
  std::vector<Turn> turns;
  std::vector<double> omt_map;
  for (const Turn& t : candidate_turns(a, b)) {
    const double d = std::sqrt(std::max(0.0, squared_distance(a, b, t)));
    if (!turns.empty() && (!opt.exact_rotation || d > (1 + kCandidateWindow) * omt_map[0] ||
                           turns.size() == kMaxCandidates))
      break;
    turns.push_back(t);
    omt_map.push_back(d);
  }
  const Eigen::VectorXd none[2];
  Eval best = solver.disk(turns[0].angle, none, std::numeric_limits<double>::infinity());
  search_candidates(static_cast<int>(turns.size()), a, opt.exact_rotation, best, out,
                    [&](int k, double ceiling) { return solver.disk(turns[k].angle, none, ceiling); }, omt_map);
  if (turns.size() > 1)
    out.normalization += " (the least exact cost among the OMT-map distance's " + std::to_string(turns.size()) +
                         " local minima within 10 % of its best)";
  if (!a.markers && opt.refine_rotation && best.converged) {
    // A parabola through the distances at the turn and half a quadrature step either side;
    // its vertex, if it is a minimum within two half-steps, is tried too. Each starts from
    // the turn's heights.
    const double step = M_PI / A, inf = std::numeric_limits<double>::infinity(), at = best.angle;
    const Eigen::VectorXd start[2] = {best.h[0], best.h[1]};
    const Eval lo = solver.disk(at - step, start, inf), hi = solver.disk(at + step, start, inf);
    out.newton_iterations += lo.iterations + hi.iterations;
    const double curvature = lo.mean + hi.mean - 2 * best.mean;
    std::vector<Eval> tried = {lo, hi};
    if (curvature > 0 && lo.converged && hi.converged) {
      const double offset = std::clamp(0.5 * step * (lo.mean - hi.mean) / curvature, -2 * step, 2 * step);
      if (std::abs(offset) > 1e-3 * step) {
        tried.push_back(solver.disk(at + offset, start, inf));
        out.newton_iterations += tried.back().iterations;
      }
    }
    bool all = true;
    for (const Eval& e : tried) all = all && e.converged;
    for (const Eval& e : tried)
      if (all && e.mean < best.mean) best = e;
    if (!all) best.converged = false;
    out.normalization += ", refined by exact evaluations";
  }
  take(out, best, opt.debias);
  return out;
}

}  // namespace brenier::distance

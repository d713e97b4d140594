#include "distance/distance.hpp"

#include <unsupported/Eigen/FFT>

#include <algorithm>
#include <cmath>
#include <complex>
#include <mutex>
#include <vector>

#include "common/error.hpp"
#include "common/parallel.hpp"

namespace brenier::distance {

namespace {

using cd = std::complex<double>;

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
Turn best_turn(const Shape& a, const Shape& b) {
  if (a.markers) return {};
  const int R = static_cast<int>(a.samples.rows()), A = static_cast<int>(a.samples.cols());
  std::vector<cd> x(A, cd(0, 0)), c(A);
  for (int m = 0; m < A; ++m)
    for (int r = 0; r < R; ++r) x[m] += std::conj(a.spectrum(r, m)) * b.spectrum(r, m);
  Eigen::FFT<double> fft;
  fft.fwd(c, x);
  Turn best;
  double top = -std::numeric_limits<double>::infinity();
  for (int s = 0; s < A; ++s) {
    const double theta = 2 * M_PI * s / A;
    const double score = std::real(std::polar(1.0, theta) * c[s]);
    if (score > top) {  // first maximum: the same turn on every run
      top = score;
      best = {s, theta};
    }
  }
  return best;
}

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
template <class Solve>
TransportCost transport_to(const Shape& dst, const omt::Progress& progress, omt::OmtOptions o, Eigen::VectorXd& h,
                           Solve solve) {
  o.tolerance = dst.transport_tolerance;
  o.dual_gap_tolerance = dst.cost_tolerance;
  o.progress = progress;
  TransportCost out;
  decltype(solve(o)) r;
  if (!guarded(out, [&] { r = solve(o); })) return out;
  out.iterations = r.iterations;
  out.max_relative_error = r.max_relative_error;
  out.converged = r.converged;
  out.w2_squared = r.dual_value + r.dual_rise;
  if (r.dual_rise > 0) out.relative_cost_gap = r.dual_rise / std::abs(r.dual_value);
  h = r.h;
  return out;
}

}  // namespace

TransportCost transport_cost_sphere(const Shape& src, const Shape& dst, const Eigen::Vector3d& flip,
                                    const omt::Progress& progress, Eigen::VectorXd& h) {
  if (!src.surface || dst.sphere_sites.rows() != dst.mass.size())
    invalid("'" + src.name + "' or '" + dst.name + "' has no sphere image for the exact distance");
  omt::Points3 sites = dst.sphere_sites;
  for (Eigen::Index i = 0; i < sites.rows(); ++i) sites.row(i) = sites.row(i).cwiseProduct(flip.transpose());
  omt::OmtOptions o;
  if (h.size()) o.initial_h = h;
  return transport_to(dst, progress, o, h,
                      [&](const omt::OmtOptions& oo) { return omt::solve_surface_omt(*src.surface, sites, dst.mass, oo); });
}

TransportCost transport_cost(const Shape& src, const Shape& dst, double angle, const omt::Progress& progress,
                             Eigen::VectorXd& h) {
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
  return transport_to(dst, progress, o, h,
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

// (`frame`, if given, gets the half-turn chosen: an index of kFlips.)
PairResult omt_linear_sphere(const Shape& a, const Shape& b, int rings, int angles, int* frame = nullptr) {
  PairResult out;
  out.distance = std::numeric_limits<double>::infinity();
  const char* names[4] = {"identity", "half-turn about the first axis", "half-turn about the second axis",
                          "half-turn about the third axis"};
  Quadrature quad;
  quad.rings = rings;
  quad.angles = angles;
  for (int g = 0; g < 4; ++g) {
    const std::vector<int> to = sphere_half_turn(g, quad);
    double sum = 0;
    for (int q = 0; q < rings * angles; ++q) {
      const Eigen::Vector3d ta = a.sphere_samples.row(q).transpose(), tb = b.sphere_samples.row(to[q]).transpose();
      sum += (ta - kFlips[g].cwiseProduct(tb)).squaredNorm();
    }
    const double d = std::sqrt(sum * 4 * M_PI / (static_cast<double>(rings) * angles));
    if (d < out.distance) {
      out.distance = d;
      out.normalization = std::string("Moebius centring, principal frames, ") + names[g] + " of the second shape";
      if (frame) *frame = g;
    }
  }
  out.normalization += " (the best of the frame's four sign choices)";
  return out;
}

}  // namespace

PairResult omt_linear(const Shape& a, const Shape& b) {
  require_comparable(a, b);
  if (a.sphere) return omt_linear_sphere(a, b, a.rings, a.angles);
  const Turn t = best_turn(a, b);
  PairResult out;
  out.distance = std::sqrt(std::max(0.0, squared_distance(a, b, t)));
  out.rotation = t.angle;
  out.normalization = turn_words(a, static_cast<int>(a.samples.cols()));
  return out;
}

PairResult wasserstein(const Shape& a, const Shape& b, const WassersteinOptions& opt) {
  require_comparable(a, b);
  if (a.transport_tolerance != b.transport_tolerance || a.cost_tolerance != b.cost_tolerance)
    invalid("'" + a.name + "' and '" + b.name + "' were prepared with different transport tolerances");
  PairResult out;
  const int A = static_cast<int>(a.samples.cols());
  out.normalization = turn_words(a, A);
  Eigen::VectorXd h_ab, h_ba;
  struct Eval {
    double angle, mean, forward, backward, raw_forward, raw_backward;
  };
  // One call's progress at a time, when the two directions run side by side.
  std::mutex progress_mutex;
  omt::Progress progress;
  if (opt.progress)
    progress = [&](int iteration, double residual) {
      std::lock_guard<std::mutex> lock(progress_mutex);
      return opt.progress(iteration, residual);
    };
  auto add = [&](const TransportCost& c, const Shape& dst, double& raw) {
    out.newton_iterations += c.iterations;
    out.max_relative_error = std::max(out.max_relative_error, c.max_relative_error);
    out.max_relative_cost_gap = std::max(out.max_relative_cost_gap, c.relative_cost_gap);
    out.converged = out.converged && c.converged;
    raw = std::sqrt(std::max(0.0, c.w2_squared));
    return std::sqrt(std::max(0.0, c.w2_squared - (opt.debias ? dst.quantization : 0.0)));
  };
  if (a.sphere) {
    // On the sphere, the squared chordal cost between A's density (on the flat triangles of
    // its sphere image) and B's vertices, B in the half-turn of its principal frame that the
    // OMT-map distance finds best; backwards B's density to A's vertices under the same
    // half-turn (it is its own inverse: W2(g mu_B, nu_A) = W2(mu_B, g nu_A)).
    int g = 0;
    const PairResult frame = omt_linear_sphere(a, b, a.rings, a.angles, &g);
    TransportCost c[2];
    Eigen::VectorXd h_a, h_b;
    parallel_for(2, opt.parallel_directions ? 2 : 1, [&](int k) {
      c[k] = k == 0 ? transport_cost_sphere(a, b, kFlips[g], progress, h_b)
                    : transport_cost_sphere(b, a, kFlips[g], progress, h_a);
    });
    out.forward = add(c[0], b, out.raw_forward);
    out.backward = add(c[1], a, out.raw_backward);
    out.normalization = frame.normalization + ", chosen by the OMT-map distance; squared chordal cost, the density on "
                                              "the flat triangles of the sphere image";
    if (opt.debias) out.normalization += "; quantization bias removed";
    out.distance = out.converged ? 0.5 * (out.forward + out.backward) : std::numeric_limits<double>::quiet_NaN();
    return out;
  }
  // d(A, R_theta B) both ways: the second direction turns A back instead (same thing, by the
  // rotation invariance of both measures' disk). The two transports are independent, and
  // each is bit-identical on any number of threads.
  auto evaluate = [&](double angle) {
    TransportCost c[2];
    parallel_for(2, opt.parallel_directions ? 2 : 1, [&](int k) {
      c[k] = k == 0 ? transport_cost(a, b, angle, progress, h_ab) : transport_cost(b, a, -angle, progress, h_ba);
    });
    Eval e{angle, 0, 0, 0, 0, 0};
    e.forward = add(c[0], b, e.raw_forward);
    e.backward = add(c[1], a, e.raw_backward);
    e.mean = 0.5 * (e.forward + e.backward);
    return e;
  };
  const Turn t = best_turn(a, b);
  Eval best = evaluate(t.angle);
  if (!a.markers && opt.refine_rotation && out.converged) {
    // A parabola through the distances at the turn and half a quadrature step either side;
    // its vertex, if it is a minimum within two half-steps, is tried too.
    const double step = M_PI / A;
    const Eval lo = evaluate(t.angle - step), hi = evaluate(t.angle + step);
    const double curvature = lo.mean + hi.mean - 2 * best.mean;
    std::vector<Eval> tried = {lo, best, hi};
    if (curvature > 0) {
      const double offset = std::clamp(0.5 * step * (lo.mean - hi.mean) / curvature, -2 * step, 2 * step);
      if (std::abs(offset) > 1e-3 * step) tried.push_back(evaluate(t.angle + offset));
    }
    for (const Eval& e : tried)
      if (e.mean < best.mean) best = e;
    out.normalization += ", refined by exact evaluations";
  }
  out.rotation = best.angle;
  out.forward = best.forward;
  out.backward = best.backward;
  out.raw_forward = best.raw_forward;
  out.raw_backward = best.raw_backward;
  if (opt.debias) out.normalization += "; quantization bias removed";
  out.distance = out.converged ? best.mean : std::numeric_limits<double>::quiet_NaN();
  return out;
}

}  // namespace brenier::distance

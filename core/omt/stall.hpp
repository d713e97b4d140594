// How a Newton solve that creeps is stopped (OmtOptions::stall_window), and what follows a
// coarse-to-fine start that did not converge (OmtOptions::multilevel): shared by the planar
// transport (omt.cpp) and the transport on the sphere (surface_cells.cpp). No OpenMP here,
// so tests include it alone.
#pragma once

#include <algorithm>
#include <cstddef>
#include <vector>

#include "omt/omt.hpp"

namespace brenier::omt::detail {

/// OmtOptions::stall_window's test, fed the relative gradient norm at the start of every
/// Newton iteration of one level: true once the last `window` iterations cut it by less than
/// kStallDecrease, or once the last kCreepingRun steps reported by took() were all shorter
/// than kCreepingStep. The planar solver reports its steps: mannequin-devil's density onto
/// its deformed copy's fine level took t ~ 2e-7 from iteration ~150 on, held by one cell at
/// the Kitagawa-Merigot-Thibert floor, each step after 12-13 refused trials (0.3 s, six times
/// a free step's), at 77.51x off; the gradient test fired 22 such steps later (bench/
/// RESULTS.md, session 42). The sphere's steps start at four times the last one and are not
/// reported.
class StallWatch {
 public:
  static constexpr double kCreepingStep = 1e-4;
  static constexpr int kCreepingRun = 10;

  explicit StallWatch(int window) : window_(window) {}
  /// Whether a window was set: callers skip computing the norm otherwise.
  bool on() const { return window_ > 0; }
  bool stalled(double gnorm) {
    if (window_ <= 0) return false;
    norms_.push_back(gnorm);
    const size_t k = norms_.size();
    return creeping_ >= kCreepingRun ||
           (k > static_cast<size_t>(window_) && gnorm > (1 - kStallDecrease) * norms_[k - 1 - window_]);
  }
  /// The step an iteration took (0: none).
  void took(double t) {
    creeping_ = t > 0 && t < kCreepingStep ? creeping_ + 1 : 0;
    last_ = t;
  }
  /// The step last reported by took() since the start (0: none).
  double last_step() const { return last_; }
  void restart() {  // a new start (the coarse-to-fine one taken)
    norms_.clear();
    creeping_ = 0;
    last_ = 0;
  }

 private:
  int window_;
  std::vector<double> norms_;
  int creeping_ = 0;  // steps in a row below kCreepingStep
  double last_ = 0;
};

/// What follows a coarse-to-fine solve that stalled (OmtOptions::stall_window).
enum class AfterStall {
  kReturn,      // the stalled result: its caller has something better (the sphere's lower cap)
  kPlainStart,  // the plain start, with the iterations the stalled solve left unused
};

/// OmtOptions::multilevel never costs an answer: where the solve from the coarse-to-fine
/// start did not converge (no step accepted from it, say), it is solved again from the plain
/// start, the iterations of both counted. `solve(options)` gives an OmtResult or
/// SurfaceOmtResult. A stalled solve (OmtOptions::stall_window) is followed as `after_stall`
/// says. On the sphere the plain start, further off, crept the same way where measured (dino
/// x bear: 766x -> 550x off in 200 iterations; bench/RESULTS.md, session 41); on the disk it
/// did not (mannequin-devil x its deformed copy: the fine level held at 77.5x off for 200
/// iterations, the plain start then fell from 57x to 5.6x in its 200; session 41).
template <class Solve>
auto with_plain_fallback(const OmtOptions& opt, Solve solve, AfterStall after_stall) {
  auto r = solve(opt);
  if (r.levels == 1 || r.converged || r.abandoned) return r;
  if (r.stalled && after_stall == AfterStall::kReturn) return r;
  OmtOptions plain = opt;
  plain.multilevel = false;
  if (r.stalled) plain.max_iterations += std::max(0, opt.max_iterations - (r.iterations - r.coarse_iterations));
  const int spent = r.iterations;
  r = solve(plain);
  r.iterations += spent;
  return r;
}

}  // namespace brenier::omt::detail

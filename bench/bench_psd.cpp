// The area refinement's per-face projection of a Hessian onto the positive semi-definite cone
// (core/numeric/psd.hpp): the eigensolver against the closed form for isotropic 2-D energies,
// on Hessians of the refinement's energy at Jacobians near the identity (Google Benchmark).
//
//     build/bench/bench_psd
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "numeric/psd.hpp"
#include "omt/barrier_energy.hpp"

namespace {

struct Case {
  Eigen::Matrix2d J;
  Eigen::Matrix4d H;
};

// Hessians in vec J of w [theta (D + 1/D) + (1 - theta) T / D] (D = det J, T = |J|_F^2,
// w = 1, theta = 0.999), at J = I plus noise: most are indefinite, as the refinement's are.
std::vector<Case> cases() {
  std::mt19937 rng(3);
  std::normal_distribution<double> N(0, 1);
  std::vector<Case> out;
  while (out.size() < 4096) {
    Eigen::Matrix2d J;
    J << 1 + 0.3 * N(rng), 0.3 * N(rng), 0.3 * N(rng), 1 + 0.3 * N(rng);
    const double D = J.determinant();
    if (!(D > 0.05)) continue;
    const brenier::omt::detail::RefinementScalars c =
        brenier::omt::detail::refinement_scalars(1, 0.999, D, J.squaredNorm());
    out.push_back({J, brenier::numeric::isotropic_derivatives_2d(J, c.eD, c.eT, c.eDD, c.eDT).H});
  }
  return out;
}

void BM_Eigensolver(benchmark::State& state) {
  const std::vector<Case> c = cases();
  size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(brenier::numeric::clamped<4>(c[i].H));
    i = (i + 1) % c.size();
  }
}
BENCHMARK(BM_Eigensolver);

void BM_ClosedForm(benchmark::State& state) {
  const std::vector<Case> c = cases();
  size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(brenier::numeric::clamped_isotropic_2d(c[i].J, c[i].H));
    i = (i + 1) % c.size();
  }
}
BENCHMARK(BM_ClosedForm);

}  // namespace

BENCHMARK_MAIN();

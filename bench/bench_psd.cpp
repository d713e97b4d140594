// The area refinement's per-face projection of a Hessian onto the positive semi-definite cone
// (core/numeric/psd.hpp): the eigensolver against the closed form for isotropic 2-D energies,
// on Hessians of the refinement's energy at Jacobians near the identity (Google Benchmark).
//
//     build/bench/bench_psd
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "numeric/psd.hpp"

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
    const double D = J.determinant(), T = J.squaredNorm(), th = 0.999, s = 1 - th;
    if (!(D > 0.05)) continue;
    const double eD = th * (1 - 1 / (D * D)) - s * T / (D * D), eT = s / D;
    const double eDD = 2 * th / (D * D * D) + 2 * s * T / (D * D * D), eDT = -s / (D * D);
    const Eigen::Vector4d j(J(0, 0), J(1, 0), J(0, 1), J(1, 1)), gD(J(1, 1), -J(0, 1), -J(1, 0), J(0, 0));
    Eigen::Matrix4d HD = Eigen::Matrix4d::Zero();
    HD(0, 3) = HD(3, 0) = 1;
    HD(1, 2) = HD(2, 1) = -1;
    out.push_back({J, eDD * gD * gD.transpose() + eDT * (gD * (2 * j).transpose() + 2 * j * gD.transpose()) +
                          eD * HD + 2 * eT * Eigen::Matrix4d::Identity()});
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

// Decimal text of doubles in written files (core/common/format.hpp, session 48): snprintf's
// "%.17g", which the writers used before, against std::to_chars's shortest exact form, per
// value, and the OBJ writer on a 100K-vertex mesh with texture coordinates (Google Benchmark).
//
//     build/bench/bench_format
#include <benchmark/benchmark.h>

#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "common/format.hpp"
#include "mesh/io.hpp"

namespace {

std::vector<double> values() {
  std::mt19937_64 rng(48);
  std::uniform_real_distribution<double> U(-1, 1);
  std::vector<double> v(1 << 16);
  for (double& x : v) x = U(rng);
  return v;
}

void BM_Snprintf17g(benchmark::State& state) {
  const std::vector<double> v = values();
  std::string out;
  for (auto _ : state) {
    out.clear();
    for (double x : v) {
      char buf[40];
      const int n = std::snprintf(buf, sizeof buf, "%.17g", x);
      out.append(buf, static_cast<size_t>(n));
    }
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(v.size()));
}
BENCHMARK(BM_Snprintf17g);

void BM_ToChars(benchmark::State& state) {
  const std::vector<double> v = values();
  std::string out;
  for (auto _ : state) {
    out.clear();
    for (double x : v) brenier::append_double(out, x);
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(v.size()));
}
BENCHMARK(BM_ToChars);

// A 316 x 316 grid (99,856 vertices, 198,450 faces) with its UV, as a disk map writes it.
void BM_WriteObj100K(benchmark::State& state) {
  const int k = 316;
  brenier::mesh::TriMesh m;
  m.V.resize(k * k, 3);
  brenier::mesh::UV uv(k * k, 2);
  for (int i = 0; i < k; ++i)
    for (int j = 0; j < k; ++j) {
      const double x = i / (k - 1.0), y = j / (k - 1.0);
      m.V.row(i * k + j) << x, y, 0.1 * x * y;
      uv.row(i * k + j) << 0.7 * x + 0.01 * y, 0.7 * y;
    }
  m.F.resize(2 * (k - 1) * (k - 1), 3);
  int f = 0;
  for (int i = 0; i + 1 < k; ++i)
    for (int j = 0; j + 1 < k; ++j) {
      const int a = i * k + j;
      m.F.row(f++) << a, a + k, a + 1;
      m.F.row(f++) << a + 1, a + k, a + k + 1;
    }
  for (auto _ : state) {
    const std::string text = brenier::mesh::write_mesh_string(m, brenier::mesh::Format::kObj, &uv);
    benchmark::DoNotOptimize(text.data());
    state.counters["MB"] = static_cast<double>(text.size()) / (1 << 20);
  }
}
BENCHMARK(BM_WriteObj100K)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();

// Reading, cleaning and topology of real meshes (data/meshes) and of a large synthetic one.
// Run: build/bench/bench_mesh_io   (after scripts/fetch-data.sh)
#include <benchmark/benchmark.h>

#include <string>

#include "mesh/io.hpp"
#include "mesh/shapes.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"

using namespace brenier::mesh;

namespace {

const std::string kData = BRENIER_DATA_DIR;

void BM_ReadOff(benchmark::State& state, const char* file) {
  std::string bytes = read_file_bytes(kData + "/" + file);
  for (auto _ : state) benchmark::DoNotOptimize(read_soup(bytes, Format::kOff));
  state.SetBytesProcessed(static_cast<int64_t>(state.iterations() * bytes.size()));
}

void BM_Clean(benchmark::State& state, const char* file) {
  PolygonSoup soup = read_soup_file(kData + "/" + file);
  for (auto _ : state) benchmark::DoNotOptimize(clean(soup));
  state.counters["vertices"] = static_cast<double>(soup.positions.size());
}

void BM_TopologyIcosphere(benchmark::State& state) {
  TriMesh m = make_icosphere(static_cast<int>(state.range(0)));
  for (auto _ : state) benchmark::DoNotOptimize(compute_topology(m));
  state.counters["vertices"] = static_cast<double>(m.num_vertices());
}

void BM_CleanIcosphere(benchmark::State& state) {
  TriMesh m = make_icosphere(static_cast<int>(state.range(0)));
  std::string off = write_mesh_string(m, Format::kPly);
  PolygonSoup soup = read_soup(off, Format::kPly);
  for (auto _ : state) benchmark::DoNotOptimize(clean(soup));
  state.counters["vertices"] = static_cast<double>(m.num_vertices());
}

}  // namespace

BENCHMARK_CAPTURE(BM_ReadOff, bunny00, "bunny00.off")->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_ReadOff, armadillo, "armadillo.off")->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Clean, bunny00, "bunny00.off")->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Clean, armadillo, "armadillo.off")->Unit(benchmark::kMillisecond);
BENCHMARK(BM_TopologyIcosphere)->Arg(7)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_CleanIcosphere)->Arg(7)->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();

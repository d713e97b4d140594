// A timed harness for one exact Wasserstein pair (issue 5's "one pair at 5K vertices" target):
// prepares both shapes once, then solves the pair `repeats` times and prints every time and
// the minimum and median, so that a change to the transport can be measured without the
// process start, the mesh reading and the shapes' own maps in the figure.
//
// Usage: bench_pair A.off B.off [repeats=15] [threads=2] [disk|sphere]
// BENCH_TRACE=1 in the environment prints every Newton iteration's error and clock time
// (with threads=1 the two directions' lines come one after the other). BENCH_CACHE=DIR keeps
// the prepared shapes there (distance::cached_shape), so that repeated runs skip the maps.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "common/error.hpp"
#include "common/parallel.hpp"
#include "process.hpp"
#include "distance/distance.hpp"
#include "distance/matrix.hpp"
#include "jobs/jobs.hpp"
#include "mesh/validate.hpp"

using namespace brenier;

int main(int argc, char** argv) {
  process::reexec_with_runtime_settings(argv);  // as the tools run
  process::tune_allocator(process::Lifetime::kOneShot);
  if (argc < 3) {
    std::fprintf(stderr, "usage: bench_pair A B [repeats] [threads]\n");
    return 2;
  }
  const int repeats = argc > 3 ? std::atoi(argv[3]) : 15;
  const int threads = argc > 4 ? std::atoi(argv[4]) : 2;
  try {
    jobs::ShapeRequest request;
    if (argc > 5) {
      const std::string domain = argv[5];
      if (domain != "disk" && domain != "sphere") throw Error(ErrorCode::kInvalidArgument, "domain: disk or sphere");
      request.domain = domain == "sphere" ? jobs::Domain::kSphere : jobs::Domain::kDisk;
    }
    std::vector<distance::Shape> shapes;
    for (int k = 1; k <= 2; ++k) {
      const distance::ShapeInput in = jobs::shape_input(mesh::load_mesh(argv[k]), argv[k], argv[k], request);
      const char* cache = std::getenv("BENCH_CACHE");
      shapes.push_back(distance::cached_shape(in, cache ? cache : ""));
    }
    distance::WassersteinOptions o;
    o.parallel_directions = threads > 1;
    const auto start = std::chrono::steady_clock::now();
    if (std::getenv("BENCH_TRACE"))
      o.progress = [&](int iteration, double error) {
        const double at = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        std::printf("  %8.3f s  iteration %3d  error %.3e\n", at, iteration, error);
        return true;
      };
    std::vector<double> t;
    double d = 0;
    for (int r = 0; r < repeats; ++r) {
      const auto t0 = std::chrono::steady_clock::now();
      const distance::PairResult p = distance::wasserstein(shapes[0], shapes[1], o);
      t.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      d = p.distance;
      std::printf("pair %2d: %.4f s, d = %.10f, %d Newton iterations%s\n", r, t.back(), p.distance,
                  p.newton_iterations, p.converged ? "" : " (not converged)");
    }
    std::sort(t.begin(), t.end());
    std::printf("%d vertices: min %.4f s, median %.4f s over %d runs (%d threads), d = %.10f\n", shapes[0].vertices,
                t.front(), t[t.size() / 2], repeats, threads, d);
  } catch (const Error& e) {
    std::fprintf(stderr, "bench_pair: %s\n", e.what());
    return 1;
  }
  return 0;
}

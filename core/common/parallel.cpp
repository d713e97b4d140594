#include "common/parallel.hpp"

#include <dlfcn.h>

#include <cstdlib>
#include <omp.h>

#include <algorithm>
#include <atomic>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace brenier {

void single_threaded_blas() {
  static std::once_flag once;
  std::call_once(once, [] {
    using SetThreads = void (*)(int);
    if (auto set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"))) set(1);
  });
}

int hardware_threads() { return std::max(1u, std::thread::hardware_concurrency()); }

void parallel_for(int n, int workers, const std::function<void(int)>& task) {
  if (n <= 0) return;
  single_threaded_blas();
  if (workers <= 1 || n == 1) {
    for (int k = 0; k < n; ++k) task(k);
    return;
  }
  std::atomic<int> next{0};
  std::atomic<bool> stop{false};
  std::mutex mutex;
  int failed_at = n;
  std::exception_ptr failure;
  auto work = [&] {
    for (int k; !stop.load() && (k = next.fetch_add(1)) < n;) {
      try {
        task(k);
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex);
        if (k < failed_at) {
          failed_at = k;
          failure = std::current_exception();
        }
        stop = true;
      }
    }
  };
  // The calling thread is one of the workers: one thread fewer to start, and its malloc
  // arena already holds pages (a fresh thread's arena faults in every page it touches).
  std::vector<std::thread> threads;
  const int count = std::min(workers, n);
  for (int t = 1; t < count; ++t)
    threads.emplace_back([&] {
      omp_set_num_threads(1);  // this thread's OpenMP teams
      work();
    });
  const int caller_teams = omp_get_max_threads();
  omp_set_num_threads(1);
  work();
  omp_set_num_threads(caller_teams);
  for (std::thread& t : threads) t.join();
  if (failure) std::rethrow_exception(failure);
}

}  // namespace brenier

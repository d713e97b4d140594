#include "common/parallel.hpp"

#include <dlfcn.h>

#include <sched.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <omp.h>
#include <sstream>

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

namespace {

// Whole CPUs of a quota over a period, rounded up; 0 for none ("max", -1, unreadable).
int quota_cpus(double quota, double period) {
  if (!(quota > 0) || !(period > 0)) return 0;
  return std::max(1, static_cast<int>(std::ceil(quota / period - 1e-9)));
}

int v2_limit(const std::filesystem::path& dir) {
  std::ifstream in(dir / "cpu.max");
  std::string quota;
  double period = 0;
  if (!(in >> quota >> period) || quota == "max") return 0;
  return quota_cpus(std::atof(quota.c_str()), period);
}

int v1_limit(const std::filesystem::path& dir) {
  std::ifstream q(dir / "cpu.cfs_quota_us"), p(dir / "cpu.cfs_period_us");
  double quota = 0, period = 0;
  if (!(q >> quota) || !(p >> period)) return 0;
  return quota_cpus(quota, period);
}

// The smallest limit from `leaf` up to `top` (a quota anywhere above binds too).
int smallest_up(std::filesystem::path leaf, const std::filesystem::path& top, int (*limit)(const std::filesystem::path&)) {
  int best = 0;
  for (;;) {
    const int l = limit(leaf);
    if (l > 0 && (best == 0 || l < best)) best = l;
    if (leaf == top || !leaf.has_relative_path() || leaf.parent_path() == leaf) break;
    leaf = leaf.parent_path();
    if (leaf.string().size() < top.string().size()) break;
  }
  return best;
}

}  // namespace

int cgroup_cpu_limit(const std::string& proc_self_cgroup, const std::string& cgroup_root) {
  std::istringstream lines(proc_self_cgroup);
  std::string line;
  int best = 0;
  auto take = [&best](int l) {
    if (l > 0 && (best == 0 || l < best)) best = l;
  };
  while (std::getline(lines, line)) {
    // "ID:CONTROLLERS:PATH"; cgroup v2 is "0::PATH".
    const size_t a = line.find(':'), b = line.find(':', a + 1);
    if (a == std::string::npos || b == std::string::npos) continue;
    const std::string controllers = line.substr(a + 1, b - a - 1), path = line.substr(b + 1);
    const std::string rel = path.substr(std::min(path.size(), path.find_first_not_of('/')));
    const std::filesystem::path root(cgroup_root);
    if (controllers.empty()) {
      take(smallest_up(root / rel, root, v2_limit));
    } else if (("," + controllers + ",").find(",cpu,") != std::string::npos) {
      for (const std::string& mount : {controllers, std::string("cpu"), std::string("cpu,cpuacct")})
        if (std::filesystem::exists(root / mount)) {
          take(smallest_up(root / mount / rel, root / mount, v1_limit));
          break;
        }
    }
  }
  return best;
}

int hardware_threads() {
  static const int cpus = [] {
    int n = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) == 0) n = std::max(1, CPU_COUNT(&set));
    std::ifstream in("/proc/self/cgroup");
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const int quota = cgroup_cpu_limit(text, "/sys/fs/cgroup");
    return quota > 0 ? std::min(n, quota) : n;
  }();
  return cpus;
}

namespace {

// The workers of the innermost parallel_for this thread runs a task of.
struct IdleWorkers {
  std::atomic<int> unclaimed{0};
};
thread_local IdleWorkers* t_pool = nullptr;

}  // namespace

void take_idle_workers() {
  if (t_pool == nullptr) return;
  if (const int spare = t_pool->unclaimed.exchange(0); spare > 0) omp_set_num_threads(omp_get_max_threads() + spare);
}

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
  // Each worker runs its tasks with one OpenMP thread (take_idle_workers widens that), and
  // when no task is left it offers itself to the tasks still running.
  IdleWorkers idle;
  auto lane = [&] {
    IdleWorkers* const outer = t_pool;
    t_pool = &idle;
    omp_set_num_threads(1);
    work();
    idle.unclaimed.fetch_add(1);
    t_pool = outer;
  };
  // The calling thread is one of the workers: one thread fewer to start, and its malloc
  // arena already holds pages (a fresh thread's arena faults in every page it touches).
  std::vector<std::thread> threads;
  const int count = std::min(workers, n);
  for (int t = 1; t < count; ++t) threads.emplace_back(lane);
  const int caller_teams = omp_get_max_threads();
  lane();
  omp_set_num_threads(caller_teams);
  for (std::thread& t : threads) t.join();
  if (failure) std::rethrow_exception(failure);
}

}  // namespace brenier

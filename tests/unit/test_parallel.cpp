// The work pool's CPU count: the affinity mask and the cgroup's CPU quota (issue 22: worker
// and thread counts follow a container's CPU limit, not the host's cores).
#include <gtest/gtest.h>
#include <sched.h>
#include <unistd.h>

#include <omp.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>
#include <vector>

#include "common/parallel.hpp"

namespace fs = std::filesystem;
using brenier::cgroup_cpu_limit;

namespace {

struct CgroupTree : ::testing::Test {
  fs::path root = fs::temp_directory_path() / ("brenier-cgroup-" + std::to_string(::getpid()));
  void SetUp() override { fs::remove_all(root); }
  void TearDown() override { fs::remove_all(root); }
  void put(const fs::path& rel, const std::string& name, const std::string& text) {
    fs::create_directories(root / rel);
    std::ofstream(root / rel / name) << text << "\n";
  }
};

TEST_F(CgroupTree, V2QuotaRoundsUpAndTheSmallestOnThePathBinds) {
  put("kubepods/pod1/c1", "cpu.max", "150000 100000");  // 1.5 CPUs -> 2
  EXPECT_EQ(cgroup_cpu_limit("0::/kubepods/pod1/c1\n", root.string()), 2);
  put("kubepods", "cpu.max", "100000 100000");  // a parent's 1 CPU binds the child too
  EXPECT_EQ(cgroup_cpu_limit("0::/kubepods/pod1/c1\n", root.string()), 1);
  put("", "cpu.max", "max 100000");
  EXPECT_EQ(cgroup_cpu_limit("0::/\n", root.string()), 0) << "no quota";
  put("small", "cpu.max", "50000 100000");  // half a CPU is still one worker
  EXPECT_EQ(cgroup_cpu_limit("0::/small\n", root.string()), 1);
}

TEST_F(CgroupTree, V1QuotaUnderTheCpuController) {
  put("cpu,cpuacct/docker/abc", "cpu.cfs_quota_us", "400000");
  put("cpu,cpuacct/docker/abc", "cpu.cfs_period_us", "100000");
  EXPECT_EQ(cgroup_cpu_limit("5:memory:/docker/abc\n4:cpu,cpuacct:/docker/abc\n", root.string()), 4);
  put("cpu,cpuacct/docker/abc", "cpu.cfs_quota_us", "-1");
  EXPECT_EQ(cgroup_cpu_limit("4:cpu,cpuacct:/docker/abc\n", root.string()), 0) << "-1 is no quota";
  EXPECT_EQ(cgroup_cpu_limit("", root.string()), 0);
  EXPECT_EQ(cgroup_cpu_limit("garbage without colons\n", root.string()), 0);
}

TEST(HardwareThreads, NeverMoreThanTheAffinityMask) {
  cpu_set_t set;
  ASSERT_EQ(sched_getaffinity(0, sizeof set, &set), 0);
  EXPECT_GE(brenier::hardware_threads(), 1);
  EXPECT_LE(brenier::hardware_threads(), CPU_COUNT(&set));
}

}  // namespace

// take_idle_workers: a task still running when the pool's other workers have run out of
// tasks gets their cores as OpenMP threads, each idle worker going to one task only; outside
// a pool nothing changes, and the caller's own OpenMP setting comes back after the pool.
TEST(TakeIdleWorkers, TheLastTaskGetsTheFinishedWorkersCoresOnce) {
  const int caller = omp_get_max_threads();
  brenier::take_idle_workers();
  EXPECT_EQ(omp_get_max_threads(), caller) << "outside a pool";
  std::atomic<int> finished{0};
  std::vector<int> teams(4, 0);
  // Three quick tasks on three workers, then one long one: once the other three workers are
  // idle, the long task's thread has 1 + 3 OpenMP threads.
  brenier::parallel_for(4, 4, [&](int k) {
    if (k != 3) {
      teams[k] = omp_get_max_threads();
      finished.fetch_add(1);
      return;
    }
    EXPECT_EQ(omp_get_max_threads(), 1) << "a pool's task starts on one OpenMP thread";
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
    while (omp_get_max_threads() < 4 && std::chrono::steady_clock::now() < deadline) {
      brenier::take_idle_workers();
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    teams[k] = omp_get_max_threads();
    brenier::take_idle_workers();  // nothing left to claim
    EXPECT_EQ(omp_get_max_threads(), teams[k]);
  });
  EXPECT_EQ(teams[3], 4);
  for (int k = 0; k < 3; ++k) EXPECT_EQ(teams[k], 1) << "task " << k;
  EXPECT_EQ(omp_get_max_threads(), caller) << "the caller's setting is restored";
}

// The work pool's CPU count: the affinity mask and the cgroup's CPU quota (issue 22: worker
// and thread counts follow a container's CPU limit, not the host's cores).
#include <gtest/gtest.h>
#include <sched.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

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

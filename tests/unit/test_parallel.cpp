// The work pool's CPU count: the affinity mask and the cgroup's CPU quota (issue 22: worker
// and thread counts follow a container's CPU limit, not the host's cores).
#include <gtest/gtest.h>
#include <sched.h>
#include <unistd.h>

#include <omp.h>

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCore>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <stdexcept>
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

namespace {

// What a library compiled by GCC (CHOLMOD) calls for `#pragma omp parallel num_threads(4)`:
// libgomp's entry, called here by name so that the clang-built sanitizer tests reach it too.
extern "C" void GOMP_parallel(void (*fn)(void*), void* data, unsigned num_threads, unsigned flags);

struct Region {
  std::atomic<int> bodies{0};  // threads that ran the region's body
  std::atomic<bool> on_caller{false};
  int level = -1;  // omp_get_level() in the caller's run of the body
  std::thread::id caller = std::this_thread::get_id();
};

void region_body(void* p) {
  auto* r = static_cast<Region*>(p);
  ++r->bodies;
  if (std::this_thread::get_id() == r->caller) {
    r->on_caller = true;
    r->level = omp_get_level();
  }
}

// A library's region of four threads, opened where this is called.
Region& library_region(Region& r) {
  GOMP_parallel(region_body, &r, 4, 0);
  return r;
}

// A grid Laplacian (n x n unknowns, a Dirichlet boundary), both triangles.
Eigen::SparseMatrix<double> grid_laplacian(int n) {
  std::vector<Eigen::Triplet<double>> t;
  auto id = [n](int i, int j) { return i * n + j; };
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      t.emplace_back(id(i, j), id(i, j), 4.0 + 1e-3 * ((i * 7 + j * 3) % 11));
      if (i + 1 < n) t.emplace_back(id(i, j), id(i + 1, j), -1.0), t.emplace_back(id(i + 1, j), id(i, j), -1.0);
      if (j + 1 < n) t.emplace_back(id(i, j), id(i, j + 1), -1.0), t.emplace_back(id(i, j + 1), id(i, j), -1.0);
    }
  Eigen::SparseMatrix<double> A(n * n, n * n);
  A.setFromTriplets(t.begin(), t.end());
  return A;
}

// grid_laplacian(n) factored supernodally and solved for one right-hand side.
Eigen::VectorXd grid_solve(int n) {
  const Eigen::SparseMatrix<double> A = grid_laplacian(n);
  brenier::single_threaded_blas();
  Eigen::CholmodSupernodalLLT<Eigen::SparseMatrix<double>> llt;
  llt.cholmod().print = 0;
  llt.compute(A);
  EXPECT_EQ(llt.info(), Eigen::Success);
  return llt.solve(Eigen::VectorXd::LinSpaced(n * n, -1.0, 1.0));
}

}  // namespace

// with_library_loops_serial: a library's OpenMP region inside f runs inline on the calling
// thread (one run of its body, no team: omp_get_level() stays 0, so no barrier and no futex
// call), CHOLMOD's factor comes out bit for bit the same, f's exception reaches the caller,
// and called inside a team it runs f once, the library's regions nested in it.
TEST(LibraryLoopsSerial, ALibrarysRegionsRunInlineAndResultsDoNotChange) {
  if (omp_get_max_active_levels() > 1) GTEST_SKIP() << "OMP_MAX_ACTIVE_LEVELS lets nested teams run in parallel";
  Region outside;
  ASSERT_EQ(library_region(outside).bodies, 4) << "outside, a library's team has the threads it asks for";
  Region inside;
  int calls = 0;
  brenier::with_library_loops_serial([&] {
    library_region(inside);
    ++calls;
  });
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(inside.bodies, 1);
  EXPECT_TRUE(inside.on_caller);
  EXPECT_EQ(inside.level, 0) << "the region made a team";
  Region after;
  EXPECT_EQ(library_region(after).bodies, 4) << "the inline regions outlived with_library_loops_serial";

  const Eigen::VectorXd plain = grid_solve(150);
  Eigen::VectorXd serial;
  brenier::with_library_loops_serial([&] { serial = grid_solve(150); });
  ASSERT_EQ(serial.size(), plain.size());
  EXPECT_TRUE(serial == plain) << "max difference " << (serial - plain).cwiseAbs().maxCoeff();

  try {
    brenier::with_library_loops_serial([] { throw std::runtime_error("the factor is not positive definite"); });
    ADD_FAILURE() << "the exception was lost";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "the factor is not positive definite");
  }

  int nested_calls = 0;
  Region nested;
#pragma omp parallel num_threads(2)
  {
#pragma omp single
    brenier::with_library_loops_serial([&] {
      ++nested_calls;
      nested.caller = std::this_thread::get_id();  // whichever thread took the single
      library_region(nested);
    });
  }
  EXPECT_EQ(nested_calls, 1);
  EXPECT_TRUE(nested.on_caller);
#if defined(__GNUC__) && !defined(__clang__)
  // One runtime (libgomp) for the team and the library: the nested region gets one thread.
  // Under clang the team is libomp's, which libgomp does not see.
  EXPECT_EQ(nested.bodies, 1);
#endif
}

namespace {

// CHOLMOD's nested-dissection ordering (METIS's separators) of grid_laplacian(n)'s pattern:
// the kind of fill-reducing permutation the area refinement factors with.
std::vector<int> nesdis_permutation(int n) {
  Eigen::SparseMatrix<double> A = grid_laplacian(n);
  cholmod_common c;
  cholmod_start(&c);
  c.print = 0;
  c.nmethods = 1;
  c.method[0].ordering = CHOLMOD_NESDIS;
  cholmod_sparse view = Eigen::viewAsCholmod(A);
  view.stype = -1;  // symmetric: its lower triangle is read
  cholmod_factor* L = cholmod_analyze(&view, &c);
  EXPECT_NE(L, nullptr);
  std::vector<int> perm;
  if (L != nullptr) {
    const int* p = static_cast<const int*>(L->Perm);
    perm.assign(p, p + L->n);
  }
  cholmod_free_factor(&L, &c);
  cholmod_finish(&c);
  return perm;
}

}  // namespace

// METIS draws its separators' random choices from the C library's rand(), reseeded at each
// call, and brenierd's other threads call rand() too: the ordering, and through it a map's
// last bits, depended on what those threads did meanwhile (a brenierd job's lion-head
// refinement differed from brenier-compute's by 1e-10 in 3 runs of 80 under load). Our
// programs give every thread a rand() state of its own (library_loops.cpp), so the ordering
// is the same whatever another thread draws.
TEST(LibraryState, AnOrderingIsTheSameWhileAnotherThreadDrawsRandomNumbers) {
  const std::vector<int> alone = nesdis_permutation(120);
  ASSERT_EQ(alone.size(), 120u * 120u);
  std::atomic<bool> stop{false};
  std::atomic<long> draws{0};
  std::thread other([&] {
    std::srand(7);
    while (!stop.load()) {
      (void)std::rand();
      draws.fetch_add(1, std::memory_order_relaxed);
    }
  });
  std::vector<std::vector<int>> busy;
  for (int k = 0; k < 5; ++k) busy.push_back(nesdis_permutation(120));
  stop = true;
  other.join();
  EXPECT_GT(draws.load(), 0);
  for (const std::vector<int>& p : busy) EXPECT_TRUE(p == alone) << "the ordering changed with another thread's draws";
  // And a thread's own sequence is the C library's: srand(s) then rand() repeats exactly.
  std::srand(12345);
  const int a = std::rand(), b = std::rand();
  std::srand(12345);
  EXPECT_EQ(std::rand(), a);
  EXPECT_EQ(std::rand(), b);
}

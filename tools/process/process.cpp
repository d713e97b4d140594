#include "process.hpp"

#include <malloc.h>
#include <unistd.h>

#include <cstdlib>
#include <string>

namespace brenier::process {

void reexec_with_runtime_settings(char** argv) {
  bool changed = false;
  if (std::getenv("OMP_WAIT_POLICY") == nullptr) {
    ::setenv("OMP_WAIT_POLICY", "passive", 1);
    // Our BLAS calls run on one thread each (single_threaded_blas): OpenBLAS's own pool, which
    // it starts when it is loaded, before main, would only idle, and take signals meant for
    // the program's waiter thread.
    ::setenv("OPENBLAS_NUM_THREADS", "1", 0);
    changed = true;
  }
  // Transparent huge pages for malloc's memory (glibc >= 2.35 reads this tunable at start;
  // the kernel's default THP mode, "madvise", gives them only to memory that asks). The
  // regular triangulations, cell arrays and CHOLMOD factors of a large transport are
  // touched all over: at 1M sites this took the page faults from 1.04M to ~38K and the
  // solve from 44.6-57 s to 32-40 s (bench/RESULTS.md). A user's own setting of it is kept.
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  const std::string have = tunables ? tunables : "";
  if (have.find("glibc.malloc.hugetlb") == std::string::npos) {
    const std::string want = (have.empty() ? "" : have + ":") + "glibc.malloc.hugetlb=1";
    ::setenv("GLIBC_TUNABLES", want.c_str(), 1);
    changed = true;
  }
  if (changed) ::execv("/proc/self/exe", argv);  // returns only on failure: then run as we are
}

void tune_allocator() {
  mallopt(M_TRIM_THRESHOLD, 32 << 20);
  mallopt(M_MMAP_THRESHOLD, 16 << 20);
}

}  // namespace brenier::process

#include "process.hpp"

#include <malloc.h>
#include <unistd.h>

#include <cstdlib>

namespace brenier::process {

void reexec_with_passive_openmp(char** argv) {
  if (std::getenv("OMP_WAIT_POLICY") != nullptr) return;
  ::setenv("OMP_WAIT_POLICY", "passive", 1);
  // Our BLAS calls run on one thread each (single_threaded_blas): OpenBLAS's own pool, which
  // it starts when it is loaded, before main, would only idle, and take signals meant for
  // the program's waiter thread.
  ::setenv("OPENBLAS_NUM_THREADS", "1", 0);
  ::execv("/proc/self/exe", argv);  // returns only on failure: then run as we are
}

void tune_allocator() {
  mallopt(M_TRIM_THRESHOLD, 32 << 20);
  mallopt(M_MMAP_THRESHOLD, 16 << 20);
}

}  // namespace brenier::process

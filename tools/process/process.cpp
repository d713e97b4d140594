#include "process.hpp"

#include <dlfcn.h>
#include <malloc.h>
#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <string>

namespace brenier::process {

namespace {

// The OpenBLAS kernels this CPU can run, by the instruction sets its code paths need
// (OpenBLAS's SkylakeX kernels use AVX-512 F/BW/VL/DQ, its Haswell kernels AVX2 and FMA);
// null when it has neither. __builtin_cpu_supports also asks whether the OS saves the
// registers these use.
const char* kernels_this_cpu_runs() {
  __builtin_cpu_init();
  if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
      __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512dq"))
    return "SkylakeX";
  if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) return "Haswell";
  return nullptr;
}

}  // namespace

bool choose_blas_kernels() {
  if (std::getenv("OPENBLAS_CORETYPE") != nullptr) return false;  // the user's choice stands
  // openblas_get_corename is OpenBLAS's own; another BLAS behind libblas.so.3 has none.
  using CoreName = char* (*)();
  auto core_name = reinterpret_cast<CoreName>(::dlsym(RTLD_DEFAULT, "openblas_get_corename"));
  if (core_name == nullptr) return false;
  const char* loaded = core_name();
  if (loaded == nullptr || ::strcasecmp(loaded, "prescott") != 0) return false;
  const char* runnable = kernels_this_cpu_runs();
  if (runnable == nullptr) return false;  // an old CPU: Prescott is right for it
  ::setenv("OPENBLAS_CORETYPE", runnable, 1);
  return true;
}

void reexec_with_runtime_settings(char** argv) {
  bool changed = choose_blas_kernels();
  if (std::getenv("OMP_WAIT_POLICY") == nullptr) {
    ::setenv("OMP_WAIT_POLICY", "passive", 1);
    // Our BLAS calls run on one thread each (single_threaded_blas): OpenBLAS's own pool, which
    // it starts when it is loaded, before main, would only idle, and take signals meant for
    // the program's waiter thread.
    ::setenv("OPENBLAS_NUM_THREADS", "1", 0);
    changed = true;
  }
  // No transparent huge pages are asked for (glibc.malloc.hugetlb stays the user's). Session
  // 27 asked for them and measured the 1M transport 25-30 % faster; on this VM since (a
  // Firecracker guest whose free-page reporting hands freed 8 MB blocks back to the host),
  // a fresh 2 MB page costs ~6 ms to fault (4.6 s for a first 400 MB), and the same commands
  // ran slower with them: 1M equal masses 47.6-49.7 s against 31.4-33.2 s, the 100K disk
  // map 14.2-15.5 s against 11.8-13.2 s, 100K Gaussian 5.2-5.3 s against 4.2-4.7 s
  // (bench/RESULTS.md, session 48). GLIBC_TUNABLES=glibc.malloc.hugetlb=1 turns them on.
  if (changed) ::execv("/proc/self/exe", argv);  // returns only on failure: then run as we are
}

void tune_allocator(Lifetime lifetime) {
  mallopt(M_TRIM_THRESHOLD, 32 << 20);
  mallopt(M_MMAP_THRESHOLD, 16 << 20);
  if (lifetime == Lifetime::kOneShot) mallopt(M_MMAP_MAX, 0);
}

}  // namespace brenier::process

// with_library_loops_serial (parallel.hpp), and the libgomp entry it needs.
//
// Debian's CHOLMOD 3 runs small loops of its supernodal factorization (zeroing, copying and
// scattering each supernode) as `#pragma omp parallel for num_threads(4) if (...)`, and GCC
// compiles every one of them to a call of libgomp's GOMP_parallel, whether the `if` holds or
// not. libgomp then builds a team, even of one thread, and ends it at a barrier whose last
// thread wakes the sleepers by a futex system call, even when there are none. One 100K-vertex
// disk map made 2.2 million futex calls that way (strace -c), 3.2 s of system time on this VM,
// whose system calls are dear (bench/RESULTS.md, session 50).
//
// This file defines GOMP_parallel in our programs. The dynamic linker binds CHOLMOD's call
// (and our own loops') to it before libgomp's; it forwards to libgomp's, except on a thread
// inside with_library_loops_serial and outside any OpenMP team, where it runs the region's
// body at once on the calling thread. To the body that is a team of one, except that
// omp_get_level() and omp_in_parallel() say it is outside any region: it finds itself
// thread 0 of 1 (omp_get_thread_num, omp_get_num_threads), its static loops take every
// index, and its barriers, having no team, return at once. (CHOLMOD's only other OpenMP
// entries are those two queries; nm -D libcholmod.so.3.)
#include <dlfcn.h>
#include <omp.h>

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <functional>
#include <utility>

#include "common/parallel.hpp"

namespace brenier {
namespace {

// Set while this thread, outside every OpenMP team, runs with_library_loops_serial's f.
thread_local bool t_regions_inline = false;

using GompParallel = void (*)(void (*)(void*), void*, unsigned, unsigned);

GompParallel libgomp_parallel() {
  static const GompParallel next = [] {
    auto f = reinterpret_cast<GompParallel>(dlsym(RTLD_NEXT, "GOMP_parallel"));
    if (f == nullptr) {
      std::fputs("brenier: the OpenMP runtime's GOMP_parallel was not found\n", stderr);
      std::abort();
    }
    return f;
  }();
  return next;
}

}  // namespace

void with_library_loops_serial(const std::function<void()>& f) {
  if (omp_get_level() == 0) {
    // Not in a team: the libraries' regions run inline (see above).
    struct Inline {
      bool was = std::exchange(t_regions_inline, true);
      ~Inline() { t_regions_inline = was; }
    } scope;
    return f();
  }
  if (omp_get_active_level() >= omp_get_max_active_levels()) return f();  // nested: serial already
  // Inside a team that may still open active ones: f runs in a team of two where the other
  // thread waits, so the regions it opens are nested, and serial at libgomp's default of one
  // active level.
  std::exception_ptr failure;
#pragma omp parallel num_threads(2)
  {
#pragma omp single
    try {
      f();
    } catch (...) {
      failure = std::current_exception();
    }
  }
  if (failure) std::rethrow_exception(failure);
}

}  // namespace brenier

// libgomp's entry for `#pragma omp parallel` (GCC's ABI, GOMP_4.0).
extern "C" void GOMP_parallel(void (*fn)(void*), void* data, unsigned num_threads, unsigned flags) {
  if (brenier::t_regions_inline) return fn(data);
  brenier::libgomp_parallel()(fn, data, num_threads, flags);
}

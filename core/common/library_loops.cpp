// Two entries of the system's libraries that this file defines in our programs, so that a
// library's work does not depend on what other threads do: libgomp's GOMP_parallel (for
// with_library_loops_serial, parallel.hpp) and the C library's rand()/srand() (below).
//
// ## GOMP_parallel
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
//
// ## rand() and srand(), a state per thread
//
// METIS, through CHOLMOD's nested-dissection ordering (the area refinement's, NESDIS), makes
// its random choices with the C library's rand(), after an srand() of a fixed seed at each
// call: the same graph gives the same ordering only while no other thread draws from the
// process-wide state meanwhile. brenierd's libraries draw from it too (gRPC and c-ares
// import rand), and a job's ordering changed with them: the lion-head refinement's factor
// then differed, and the map by up to 1.5e-10 from brenier-compute's (3 jobs of 81 under
// load; the CI run of session 51's work caught one). Here every thread has its own state,
// the glibc generator's (TYPE_3, 128 bytes of state, seed 1 until srand), so a thread's
// sequence is what rand() gives a program with one thread, whatever others draw. Those
// libraries' draws are no less random for it: none of our programs seeds rand, so its
// sequence was the same in every process already. (nm -D
// libmetis.so.5: rand and srand are its only entries of that kind.) The linker exports both
// (core/CMakeLists.txt), so that METIS binds to them.
#include <dlfcn.h>
#include <stdlib.h>
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

namespace {

// The glibc generator rand() uses, as initstate(1, state, 128) sets it up, per thread.
struct ThreadRandom {
  char state[128];
  random_data data{};
  ThreadRandom() { initstate_r(1, state, sizeof state, &data); }
};

random_data& thread_random() {
  thread_local ThreadRandom r;
  return r.data;
}

}  // namespace

extern "C" int rand() noexcept {
  int32_t r = 0;
  random_r(&thread_random(), &r);
  return r;
}

extern "C" void srand(unsigned seed) noexcept { srandom_r(seed, &thread_random()); }

// A small work pool for coarse-grained tasks (shapes, pairs of a distance matrix), beside
// the OpenMP loops inside each task.
#pragma once

#include <functional>

namespace brenier {

/// Runs task(k) for every k in [0, n) on `workers` threads, each taking the next index as it
/// finishes one. With more than one worker, OpenMP inside a task runs on one thread (the
/// pool already fills the cores). After the first exception no new task starts; once all
/// have stopped, the exception of the lowest index is rethrown (the same one whatever the
/// timing). workers <= 1 runs the tasks in order on the calling thread.
void parallel_for(int n, int workers, const std::function<void(int)>& task);

/// Makes OpenBLAS (CHOLMOD's BLAS) run each call on the calling thread. We install its
/// pthread build because that one locks its shared buffers: the serial build is not safe to
/// call from two threads at once (concurrent factorizations corrupted each other, found as
/// non-deterministic distances and rare "singular Hessian" failures). Its own threads would
/// then compete with OpenMP and our pools, so they are switched off. Idempotent and cheap;
/// every user of CHOLMOD calls it first. A no-op under another BLAS.
void single_threaded_blas();

/// The number of hardware threads (at least 1).
int hardware_threads();

/// Called first in main(): unless OMP_WAIT_POLICY is set, sets it to passive and re-executes
/// the program (libgomp reads it once, when it is loaded, before main). Idle OpenMP threads
/// then sleep instead of spinning through the serial parts (CGAL's regular triangulation,
/// CHOLMOD's ordering): measured 7-8 % faster transports on 2 cores (10K sites 0.549 ->
/// 0.511 s, 100K 7.04 -> 6.47 s, means of 10 and 3 runs), and the spinning no longer takes
/// cores from other jobs and RPC threads of the server. Returns if the exec fails.
void reexec_with_passive_openmp(char** argv);

/// Called first in main(): glibc's malloc keeps up to 32 MB freed at the top of each arena
/// and serves blocks below 16 MB from the arenas instead of returning memory to the kernel
/// as soon as it is freed (its defaults, 128 KB, adapt upwards only slowly). The solvers free
/// and reallocate their per-iteration arrays, and every page given back was faulted in again
/// on the next iteration: a 5K Wasserstein pair went from 0.079 to 0.070 s (medians of 15),
/// page faults having been 7 % of its time. At most 32 MB per arena stays reserved.
void tune_allocator();

}  // namespace brenier

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


}  // namespace brenier

// A small work pool for coarse-grained tasks (shapes, pairs of a distance matrix), beside
// the OpenMP loops inside each task.
#pragma once

#include <functional>
#include <string>

namespace brenier {

/// Runs task(k) for every k in [0, n) on `workers` threads, each taking the next index as it
/// finishes one. With more than one worker, OpenMP inside a task runs on one thread (the
/// pool already fills the cores). After the first exception no new task starts; once all
/// have stopped, the exception of the lowest index is rethrown (the same one whatever the
/// timing). workers <= 1 runs the tasks in order on the calling thread.
void parallel_for(int n, int workers, const std::function<void(int)>& task);

/// Inside a parallel_for task: adds the pool's workers that have run out of tasks since the
/// last call to this thread's OpenMP teams (each idle worker to one task only), so that the
/// last long task of a pool (the slow direction of a distance, the last pairs of a matrix)
/// does not run on one core while the others wait. Long loops call it once per step
/// (the transports' Newton iterations). Elsewhere a no-op. Results do not change: the
/// OpenMP loops it widens sum in a fixed order.
void take_idle_workers();

/// Makes OpenBLAS (CHOLMOD's BLAS) run each call on the calling thread. We install its
/// pthread build because that one locks its shared buffers: the serial build is not safe to
/// call from two threads at once (concurrent factorizations corrupted each other, found as
/// non-deterministic distances and rare "singular Hessian" failures). Its own threads would
/// then compete with OpenMP and our pools, so they are switched off. Idempotent and cheap;
/// every user of CHOLMOD calls it first. A no-op under another BLAS.
void single_threaded_blas();

/// Runs f with the OpenMP loops of the libraries it calls on the calling thread alone, and
/// rethrows f's exception. Debian's CHOLMOD 3 opens an OpenMP region (num_threads(4), most
/// of them with a false `if`) for every supernode's small zeroing, copy and scatter loops of
/// a supernodal factorization: 1.1M regions in one 100K-vertex disk map. Outside any OpenMP
/// team, those regions run inline on this thread, with no team and no system call
/// (library_loops.cpp); inside one, f runs in a nested team, where libgomp's default of one
/// active level makes them serial. Our own OpenMP loops inside f are serialized too: f
/// should be the factorization alone.
void with_library_loops_serial(const std::function<void()>& f);

/// The CPUs this process may use, at least 1: the CPUs of its affinity mask (taskset,
/// cpusets, Slurm's task binding), capped by its cgroup's CPU quota rounded up (a container's
/// or a Kubernetes pod's CPU limit). Worker pools and OpenMP default to it, not to the
/// host's cores.
int hardware_threads();

/// The CPU quota of the cgroup named in `proc_self_cgroup` (the text of /proc/self/cgroup),
/// as whole CPUs rounded up, read under `cgroup_root` (/sys/fs/cgroup): cgroup v2's cpu.max
/// or v1's cpu.cfs_quota_us / cpu.cfs_period_us, the smallest along the path to the root.
/// 0 when there is no quota.
int cgroup_cpu_limit(const std::string& proc_self_cgroup, const std::string& cgroup_root);


}  // namespace brenier

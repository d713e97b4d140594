// Process setup the programs (brenierd, brenier-compute, the benchmarks) do first in main().
// It belongs to a program, not to the numerical library: a library that re-executes its
// host or retunes its allocator would surprise whoever links it.
#pragma once

namespace brenier::process {

/// OpenBLAS picks its kernels when it is loaded, before main, by the CPU's model number. A
/// model it does not know, such as a virtual machine's generic "Intel(R) Xeon(R) Processor",
/// gets the Prescott (SSE3) kernels even where AVX-512 is there. Those are 1.5-2x slower in
/// CHOLMOD's supernodal factorizations, and they round differently: on such a VM man's sphere
/// map kept 3 folded faces, and had none with the SkylakeX kernels (bench/RESULTS.md).
/// When OpenBLAS is loaded with its Prescott kernels, OPENBLAS_CORETYPE is unset and the CPU
/// has AVX-512 (or AVX2 and FMA), this sets OPENBLAS_CORETYPE to SkylakeX (or Haswell) and
/// returns true: the program must then re-execute itself for OpenBLAS to read it.
bool choose_blas_kernels();

/// Called first in main(): sets the runtime's start-up settings that were not set and
/// re-executes the program once for them. Unless OMP_WAIT_POLICY is set, sets it to passive
/// (libgomp reads it once, when it is loaded, before main). Idle OpenMP threads then sleep
/// instead of spinning through the serial parts (CGAL's regular triangulation, CHOLMOD's
/// ordering): faster transports on 2 cores (bench/RESULTS.md), and the spinning no longer
/// takes cores from other jobs and RPC threads of the server. Returns if the exec
/// fails.
/// It also sets OPENBLAS_NUM_THREADS=1 unless set, and OPENBLAS_CORETYPE where
/// choose_blas_kernels() says so; it re-executes when any of these was missing. It leaves
/// malloc's transparent huge pages off (process.cpp says why).
void reexec_with_runtime_settings(char** argv);

/// Who runs: a program that computes one thing and exits (brenier-compute, the benches), or
/// the daemon, which runs job after job.
enum class Lifetime { kOneShot, kDaemon };

/// Called first in main(): glibc's malloc keeps up to 32 MB freed at the top of each arena
/// and serves blocks below 16 MB from the arenas instead of returning memory to the kernel
/// as soon as it is freed (its defaults, 128 KB, adapt upwards only slowly). The solvers free
/// and reallocate their per-iteration arrays, and every page given back was faulted in again
/// on the next iteration (page faults were a noticeable share of a Wasserstein pair's time;
/// bench/RESULTS.md). At most 32 MB per arena stays reserved.
/// kOneShot also serves from the heap the blocks above the mmap threshold (16 MB here; glibc
/// lets it be raised to 32 MB at most): a 1M-site transport's edge lists, Hessians and factors,
/// reallocated at every Newton iteration, are then reused instead of faulted in again.
/// omt-bench's 1M equal masses 20.2 -> 19.2 s (medians of six alternated runs), peak 1.30 ->
/// 1.38 GB; nothing measurable below 1M sites (bench/RESULTS.md, session 78). kDaemon keeps
/// returning such blocks to the kernel: a server would otherwise hold the holes its largest
/// job left for good. Each main() states which it is.
void tune_allocator(Lifetime lifetime);

}  // namespace brenier::process

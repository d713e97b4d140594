// Process setup the programs (brenierd, brenier-compute, the benchmarks) do first in main().
// It belongs to a program, not to the numerical library: a library that re-executes its
// host or retunes its allocator would surprise whoever links it.
#pragma once

namespace brenier::process {

/// Called first in main(): unless OMP_WAIT_POLICY is set, sets it to passive and re-executes
/// the program (libgomp reads it once, when it is loaded, before main). Idle OpenMP threads
/// then sleep instead of spinning through the serial parts (CGAL's regular triangulation,
/// CHOLMOD's ordering): measured 7-8 % faster transports on 2 cores (10K sites 0.549 ->
/// 0.511 s, 100K 7.04 -> 6.47 s, means of 10 and 3 runs), and the spinning no longer takes
/// cores from other jobs and RPC threads of the server. Returns if the exec fails.
/// It also sets OPENBLAS_NUM_THREADS=1 unless set (see process.cpp).
void reexec_with_passive_openmp(char** argv);

/// Called first in main(): glibc's malloc keeps up to 32 MB freed at the top of each arena
/// and serves blocks below 16 MB from the arenas instead of returning memory to the kernel
/// as soon as it is freed (its defaults, 128 KB, adapt upwards only slowly). The solvers free
/// and reallocate their per-iteration arrays, and every page given back was faulted in again
/// on the next iteration: a 5K Wasserstein pair went from 0.079 to 0.070 s (medians of 15),
/// page faults having been 7 % of its time. At most 32 MB per arena stays reserved.
void tune_allocator();

}  // namespace brenier::process

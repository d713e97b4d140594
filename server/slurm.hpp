// The Slurm executor of matrix jobs (brenierd --executor slurm): a matrix job's tiles run as
// one Slurm job array of `brenier-compute matrix --work FILE --tile I/K` tasks on the shared
// --data volume (its shape cache included), which brenierd follows through squeue and the
// tile files the tasks write (whole or absent), then merges exactly as its own pool's tiles.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "distance/matrix.hpp"

namespace brenier::server {

struct SlurmOptions {
  std::vector<std::string> args;  // sbatch options (--slurm-args): partition, account, time, ...
  std::string compute;            // brenier-compute as the nodes run it
  int tile_pairs = 500;           // pairs per array task (minutes of work, not seconds)
  int max_tasks = 1000;           // array tasks per matrix at most (Slurm's MaxArraySize is 1001)
  double poll_seconds = 2;        // squeue and the tile files are looked at this often
  double command_seconds = 60;    // sbatch, squeue and scancel get this long to answer
  double unreachable_seconds = 300;  // squeue failing this long fails the job
};

enum class Executor { kLocal, kSlurm };
struct ExecutorOptions {
  Executor kind = Executor::kLocal;
  SlurmOptions slurm;
};

/// The number of array tasks for `pairs` pairs.
int slurm_tile_count(const SlurmOptions& o, int pairs);

/// What the run asks of the job around it.
struct SlurmRunHooks {
  enum class Go { kOn, kCancel, kLeave };
  /// kCancel: the client cancelled (scancel, then Error(kCancelled)); kLeave: this server
  /// stops following the job (shutdown, another replica took it): the array runs on, and a
  /// later run re-attaches to it.
  std::function<Go()> go;
  std::function<void(int done, int total, const std::string& stage)> progress;
};

/// Runs (or re-attaches to) the array of the job `job_id` whose work file `dir`/matrix-work.json
/// splits the matrix into `tiles`, and returns its tiles once every one is written. A task
/// whose tile is missing when the array has left the queue is run once more (one array of the
/// missing tiles); missing again, the job fails naming the tiles and the last line of their
/// logs. Throws Error: kFailedPrecondition when Slurm refuses the array or its commands are
/// missing, kUnavailable when squeue has failed for unreachable_seconds, kCancelled.
std::vector<distance::MatrixTile> run_tiles_on_slurm(const SlurmOptions& o, const std::string& job_id,
                                                     const std::string& dir, int tiles, const SlurmRunHooks& hooks);

}  // namespace brenier::server

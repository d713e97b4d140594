// Runs an external program (Slurm's sbatch, squeue, scancel) from the server's threads: no
// shell, its output captured, a deadline, and the signal mask brenierd keeps on its own
// threads (main.cpp blocks SIGTERM and SIGINT everywhere) cleared for the child.
#pragma once

#include <string>
#include <vector>

namespace brenier::server {

struct CommandResult {
  bool started = false;   // false: the program could not be run (`error` says why)
  bool timed_out = false; // killed at the deadline
  int exit_code = -1;     // its exit status (128 + the signal when killed by one)
  std::string out, err;   // what it printed
  std::string error;      // why it did not start
  bool ok() const { return started && !timed_out && exit_code == 0; }
  /// One line for messages: the first line of stderr, else of stdout, else the status.
  std::string summary() const;
};

/// Runs argv[0] (looked up on PATH) with argv, stdin from /dev/null, and waits at most
/// `timeout_seconds` (then SIGKILL). Never throws for the program's failures.
CommandResult run_command(const std::vector<std::string>& argv, double timeout_seconds);

/// Splits "--partition=a --time 1:00:00 --comment 'two words'" into arguments: whitespace
/// separates, single and double quotes group, backslash escapes. Error(kInvalidArgument) on
/// an unterminated quote.
std::vector<std::string> split_arguments(const std::string& text);

}  // namespace brenier::server

// The Slurm executor (slurm.hpp). What brenierd knows of an array it keeps in the job's work
// folder (slurm.json: the arrays submitted and which tiles each ran), so that a brenierd
// restarted mid-array, or another replica, follows the same array instead of submitting it
// again. The tile files are the truth about what is done: a task writes its tile whole (a
// rename) as its last act, so a tile present is a task that succeeded, whatever squeue says.
#include "slurm.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>

#include "command.hpp"
#include "common/error.hpp"

namespace fs = std::filesystem;

namespace brenier::server {

int slurm_tile_count(const SlurmOptions& o, int pairs) {
  const int per = std::max(1, o.tile_pairs);
  return std::clamp((pairs + per - 1) / per, 1, std::max(1, o.max_tasks));
}

namespace {

struct Array {
  std::string id;          // the array's base job id
  int attempt = 1;         // 1: every tile; 2: the tiles missing after attempt 1
  std::vector<int> tiles;  // the tiles it runs
};

class SlurmRun {
 public:
  SlurmRun(const SlurmOptions& o, std::string job_id, std::string dir, int tiles, const SlurmRunHooks& hooks)
      : o_(o), job_id_(std::move(job_id)), dir_(std::move(dir)), tiles_(tiles), hooks_(hooks) {}

  std::vector<distance::MatrixTile> run();

 private:
  std::string name() const { return "brenier-" + job_id_; }
  std::string tile_path(int k) const { return dir_ + "/tile-" + std::to_string(k) + ".json"; }
  std::vector<int> missing() const {
    std::vector<int> m;
    for (int k = 0; k < tiles_; ++k)
      if (!fs::exists(tile_path(k))) m.push_back(k);
    return m;
  }
  void load_state();
  void save_state() const;
  void write_script() const;
  void submit(const std::vector<int>& tiles, int attempt);
  std::string find_by_name() const;
  // Tasks of the array still in the queue (pending, running, completing); nothing when squeue failed.
  std::optional<std::pair<int, int>> queued(const std::string& id, std::string* why);
  void cancel_all();
  [[noreturn]] void fail_tiles(const std::vector<int>& tiles) const;

  const SlurmOptions& o_;
  const std::string job_id_, dir_;
  const int tiles_;
  const SlurmRunHooks& hooks_;
  std::vector<Array> arrays_;
};

std::string join(const std::vector<int>& v, const char* sep) {
  std::string s;
  for (size_t k = 0; k < v.size(); ++k) s += (k ? sep : "") + std::to_string(v[k]);
  return s;
}

// A path inside single quotes for sh.
std::string quoted(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

void SlurmRun::load_state() {
  std::ifstream in(dir_ + "/slurm.json");
  if (!in) return;
  try {
    const nlohmann::json j = nlohmann::json::parse(in);
    for (const auto& a : j.at("arrays"))
      arrays_.push_back({a.at("id").get<std::string>(), a.at("attempt").get<int>(), a.at("tiles").get<std::vector<int>>()});
  } catch (const nlohmann::json::exception& e) {
    spdlog::warn("job {}: ignoring an unreadable {}/slurm.json: {}", job_id_, dir_, e.what());
    arrays_.clear();
  }
}

void SlurmRun::save_state() const {
  nlohmann::json arrays = nlohmann::json::array();
  for (const Array& a : arrays_) arrays.push_back({{"id", a.id}, {"attempt", a.attempt}, {"tiles", a.tiles}});
  const std::string tmp = dir_ + "/slurm.json.tmp";
  {
    std::ofstream out(tmp, std::ios::trunc);
    out << nlohmann::json{{"arrays", arrays}}.dump(2) << '\n';
    if (!out) fail(ErrorCode::kInternal, "cannot write " + tmp);
  }
  fs::rename(tmp, dir_ + "/slurm.json");
}

void SlurmRun::write_script() const {
  const std::string path = dir_ + "/tiles.sh";
  {
    std::ofstream out(path, std::ios::trunc);
    out << "#!/bin/sh\n"
        << "# Written by brenierd for matrix job " << job_id_ << ": array task I computes tile I of " << tiles_
        << "\n# (its share of the shapes into the shared cache first, then its pairs).\n"
        << "exec " << quoted(o_.compute) << " matrix --work " << quoted(dir_ + "/matrix-work.json") << " --tile \"$SLURM_ARRAY_TASK_ID/"
        << tiles_ << "\" --jobs \"${SLURM_CPUS_PER_TASK:-1}\" -o " << quoted(dir_) << "/tile-\"$SLURM_ARRAY_TASK_ID\".json\n";
    if (!out) fail(ErrorCode::kInternal, "cannot write " + path);
  }
  fs::permissions(path, fs::perms::owner_all | fs::perms::group_read | fs::perms::group_exec);
}

void SlurmRun::submit(const std::vector<int>& tiles, int attempt) {
  write_script();
  std::vector<std::string> argv = {"sbatch", "--parsable", "--job-name=" + name(), "--array=" + join(tiles, ","),
                                   "--output=" + dir_ + "/slurm-%A_%a.out", "--chdir=" + dir_};
  argv.insert(argv.end(), o_.args.begin(), o_.args.end());
  argv.push_back(dir_ + "/tiles.sh");
  const CommandResult r = run_command(argv, o_.command_seconds);
  if (!r.started)
    fail(ErrorCode::kFailedPrecondition, "--executor slurm needs Slurm's sbatch on brenierd's PATH (" + r.summary() + ")");
  if (!r.ok())
    fail(ErrorCode::kFailedPrecondition, "Slurm refused the matrix's array (sbatch: " + r.summary() + ")");
  std::string id = r.out.substr(0, r.out.find_first_of(";\n"));
  if (id.empty() || id.find_first_not_of("0123456789") != std::string::npos)
    fail(ErrorCode::kFailedPrecondition, "sbatch answered '" + r.summary() + "', not a job id");
  arrays_.push_back({id, attempt, tiles});
  save_state();
  spdlog::info("job {}: Slurm array {} runs {} of {} tiles (attempt {})", job_id_, id, tiles.size(), tiles_, attempt);
}

std::string SlurmRun::find_by_name() const {
  const CommandResult r = run_command({"squeue", "-h", "--name=" + name(), "-o", "%F"}, o_.command_seconds);
  if (!r.ok()) return "";
  const std::string id = r.out.substr(0, r.out.find('\n'));
  return id.find_first_not_of("0123456789") == std::string::npos ? id : "";
}

std::optional<std::pair<int, int>> SlurmRun::queued(const std::string& id, std::string* why) {
  const CommandResult r = run_command({"squeue", "-h", "-r", "-j", id, "-o", "%T"}, o_.command_seconds);
  if (!r.ok()) {
    // A job that has left the queue is unknown to squeue after MinJobAge: finished, not an error.
    if (r.started && !r.timed_out && r.err.find("Invalid job id") != std::string::npos) return std::pair{0, 0};
    *why = r.summary();
    return std::nullopt;
  }
  int pending = 0, running = 0;
  size_t at = 0;
  while (at < r.out.size()) {
    const size_t end = r.out.find('\n', at);
    const std::string state = r.out.substr(at, end == std::string::npos ? std::string::npos : end - at);
    at = end == std::string::npos ? r.out.size() : end + 1;
    if (state == "PENDING" || state == "REQUEUED" || state == "SUSPENDED") ++pending;
    else if (state == "RUNNING" || state == "CONFIGURING" || state == "COMPLETING") ++running;
  }
  return std::pair{pending, running};
}

void SlurmRun::cancel_all() {
  for (const Array& a : arrays_) {
    const CommandResult r = run_command({"scancel", a.id}, o_.command_seconds);
    if (!r.ok()) spdlog::warn("job {}: scancel {}: {}", job_id_, a.id, r.summary());
  }
  // CancelJob answers once none of its tasks is left in the queue (bounded: never hangs).
  const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (std::chrono::steady_clock::now() < until) {
    bool any = false;
    for (const Array& a : arrays_) {
      std::string why;
      const auto q = queued(a.id, &why);
      any = any || !q || q->first + q->second > 0;
    }
    if (!any) return;
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  spdlog::warn("job {}: its Slurm tasks were still queued 30 s after scancel", job_id_);
}

void SlurmRun::fail_tiles(const std::vector<int>& tiles) const {
  std::string last;
  for (int k : tiles) {
    // The last attempt's log of the first failed tile that left one: its last line says why.
    const Array& a = arrays_.back();
    std::ifstream in(dir_ + "/slurm-" + a.id + "_" + std::to_string(k) + ".out");
    std::string line;
    while (std::getline(in, line))
      if (line.find_first_not_of(" \t\r") != std::string::npos) last = line;
    if (!last.empty()) {
      last = " (tile " + std::to_string(k) + "'s log: " + last + ")";
      break;
    }
  }
  fail(ErrorCode::kFailedPrecondition, "matrix tiles " + join(tiles, ", ") + " of " + std::to_string(tiles_) +
                                 " failed twice on Slurm (array " + arrays_.back().id + ")" + last);
}

std::vector<distance::MatrixTile> SlurmRun::run() {
  load_state();
  if (arrays_.empty()) {
    // An array submitted by a run killed before it could write slurm.json down.
    if (const std::string id = find_by_name(); !id.empty()) {
      std::vector<int> all(tiles_);
      for (int k = 0; k < tiles_; ++k) all[k] = k;
      arrays_.push_back({id, 1, all});
      save_state();
    }
  }
  if (arrays_.empty()) {
    std::vector<int> all = missing();
    if (!all.empty()) submit(all, 1);
  } else {
    spdlog::info("job {}: following Slurm array {} (attempt {})", job_id_, arrays_.back().id, arrays_.back().attempt);
  }
  auto failing_since = std::chrono::steady_clock::time_point{};
  for (;;) {
    const std::vector<int> left = missing();
    if (left.empty()) break;
    switch (hooks_.go()) {
      case SlurmRunHooks::Go::kCancel: cancel_all(); fail(ErrorCode::kCancelled, "cancelled");
      case SlurmRunHooks::Go::kLeave: fail(ErrorCode::kCancelled, "interrupted");
      case SlurmRunHooks::Go::kOn: break;
    }
    std::string why;
    const auto q = queued(arrays_.back().id, &why);
    if (!q) {
      const auto now = std::chrono::steady_clock::now();
      if (failing_since == std::chrono::steady_clock::time_point{}) failing_since = now;
      if (now - failing_since > std::chrono::duration<double>(o_.unreachable_seconds))
        fail(ErrorCode::kUnavailable, "Slurm does not answer (squeue: " + why + ")");
      hooks_.progress(tiles_ - static_cast<int>(left.size()), tiles_, "Slurm does not answer: " + why);
    } else {
      failing_since = {};
      const int done = tiles_ - static_cast<int>(left.size());
      if (q->first + q->second == 0) {
        const std::vector<int> still = missing();  // a tile may have landed since
        if (still.empty()) continue;
        if (arrays_.back().attempt >= 2) fail_tiles(still);
        spdlog::warn("job {}: tiles {} missing after Slurm array {}; running them once more", job_id_,
                     join(still, ", "), arrays_.back().id);
        submit(still, 2);
        continue;
      }
      hooks_.progress(done, tiles_,
                      "tiles " + std::to_string(done) + "/" + std::to_string(tiles_) + " on Slurm array " +
                          arrays_.back().id + " (" + std::to_string(q->second) + " running, " +
                          std::to_string(q->first) + " pending)");
    }
    const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(o_.poll_seconds);
    while (std::chrono::steady_clock::now() < until && hooks_.go() == SlurmRunHooks::Go::kOn)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  hooks_.progress(tiles_, tiles_, "tiles " + std::to_string(tiles_) + "/" + std::to_string(tiles_) + " done");
  std::vector<distance::MatrixTile> out(tiles_);
  for (int k = 0; k < tiles_; ++k) {
    out[k] = distance::read_tile(tile_path(k));
    if (out[k].tile.index != k || out[k].tile.count != tiles_)
      fail(ErrorCode::kInternal, tile_path(k) + " is not tile " + std::to_string(k) + " of " + std::to_string(tiles_));
  }
  return out;
}

}  // namespace

std::vector<distance::MatrixTile> run_tiles_on_slurm(const SlurmOptions& o, const std::string& job_id,
                                                     const std::string& dir, int tiles, const SlurmRunHooks& hooks) {
  return SlurmRun(o, job_id, dir, tiles, hooks).run();
}

}  // namespace brenier::server

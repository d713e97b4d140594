// What brenierd does, apart from the wire: uploads made into meshes, jobs accepted, run on
// the pool through core/jobs (the same code as brenier-compute), their progress kept for
// watchers, their state and results persisted. Throws brenier::Error; the handlers turn it
// into a status in one place (status.hpp).
#pragma once

#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <optional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "brenier/v1/brenier.pb.h"
#include "common/error.hpp"
#include "scheduler.hpp"
#include "slurm.hpp"
#include "store.hpp"

namespace brenier::server {

struct ManagerOptions {
  int workers = 0;           // 0: the number of cores
  int queue = 64;            // queued jobs at most (RESOURCE_EXHAUSTED beyond)
  int64_t max_upload_bytes = int64_t{512} << 20;
  int64_t max_vertices = 5'000'000;
  int max_matrix_meshes = 5000;
  int max_jobs_per_tenant = 0;                 // queued and running (0: no quota)
  int64_t max_storage_bytes_per_tenant = 0;    // meshes and results (0: no quota)
  int64_t min_free_bytes = int64_t{256} << 20;  // an upload that would leave less is refused
  double retention_seconds = 30 * 86400.0;     // finished jobs and their results (0: kept)
  double lease_seconds = 30;                   // a shared store: a job's lease without renewal
  ExecutorOptions executor;                    // where matrix tiles run (local pool or Slurm)
};

/// One job's progress as it happens: the events since the job was (re)started, the latest
/// job record, and the flags the numerical loops check.
struct LiveJob {
  std::mutex mutex;
  std::condition_variable changed;
  pb::Job job;                   // latest, with stage and fraction
  std::deque<pb::JobEvent> events;
  uint64_t first_seq = 0;        // sequence number of events.front()
  bool terminal = false;
  std::atomic<bool> cancel{false};       // the client asked
  std::atomic<bool> interrupted{false};  // the server is shutting down: requeue, not cancel
  // The job left this replica without its terminal event here: its lease ran out (another
  // replica holds it now) or its state could not be written (the database was away).
  // Watchers go on from the store.
  std::atomic<bool> detached{false};
  uint64_t end_seq() const { return first_seq + events.size(); }
};

class Manager {
 public:
  Manager(Store& store, const ManagerOptions& options);
  ~Manager();

  /// Requeues the jobs an earlier run left queued or running (a running one runs again).
  void recover();

  /// Turns a finished upload (`bytes`, already checked against the declared size and SHA-256)
  /// into the tenant's mesh: parsed, validated (INVALID_ARGUMENT with the validator's
  /// message), vertex limit (RESOURCE_EXHAUSTED), then stored.
  pb::Mesh add_mesh(const std::string& tenant, const pb::UploadMeshRequest::Header& header, const std::string& bytes);
  /// RESOURCE_EXHAUSTED naming the limit when `bytes` more would put the tenant over its
  /// storage quota or leave the data directory's disk with less than min_free_bytes (with 0
  /// bytes: when the tenant is at its quota or the disk below its reserve already).
  void check_room(const std::string& tenant, int64_t bytes);

  pb::Job submit(const std::string& tenant, const pb::SubmitJobRequest& request);
  pb::Job get(const std::string& tenant, const std::string& id);
  /// A job as stored, with the live stage and fraction while it is queued or running.
  pb::Job with_progress(pb::Job stored);
  pb::Job cancel(const std::string& tenant, const std::string& id);
  /// The live state of a job of the tenant; null when it has finished (read the store).
  /// NOT_FOUND for another tenant's or an unknown job.
  std::shared_ptr<LiveJob> live(const std::string& tenant, const std::string& id, pb::Job& current);

  /// For a job this replica does not hold (another replica runs it): calls `write` with an
  /// event whenever the stored state, stage or fraction changes and at least every 2 s, and
  /// returns after the terminal event, when `write` returns false, or when `stop` returns
  /// true. (Its progress is in the store: the holder writes it every second.)
  void follow(const std::string& tenant, const std::string& id, const std::function<bool(const pb::JobEvent&)>& write,
              const std::function<bool()>& stop);

  /// Stop taking queued jobs; Submit and Upload answer UNAVAILABLE from now on.
  void begin_shutdown();
  bool shutting_down() const { return shutting_down_; }
  /// Waits up to `grace_seconds` for the running jobs, then interrupts the rest (they stay
  /// queued in the store and run again at the next start) and stops the workers.
  void finish_shutdown(double grace_seconds);

  Store& store() { return store_; }
  const ManagerOptions& options() const { return options_; }

 private:
  void run(const std::string& id);
  std::shared_ptr<LiveJob> find_live(const std::string& id);
  void publish(LiveJob& live, const pb::JobEvent& event);
  void finish(const std::shared_ptr<LiveJob>& live, pb::Job job);
  void cancel_live(const std::shared_ptr<LiveJob>& l, pb::Job& current);
  pb::Job record_outcome(const std::shared_ptr<LiveJob>& l, pb::Job job, const std::optional<Error>& error,
                      const pb::JobResult& result, bool requeue);
  void detach(const std::string& id, const std::shared_ptr<LiveJob>& l, const std::string& why);
  // Replicas (a shared store): a thread that renews this replica's leases, claims the jobs
  // whose lease ran out, applies cancellations asked through other replicas and writes the
  // running jobs' progress for their watchers elsewhere.
  void lease_loop();
  void apply_cancels();
  void write_progress(std::map<std::string, std::string>& written);
  void renew_leases();
  void claim_expired();
  void adopt(const std::string& id, const std::string& why);
  std::vector<std::pair<std::string, std::shared_ptr<LiveJob>>> live_jobs();

  Store& store_;
  ManagerOptions options_;
  std::mutex mutex_;
  std::map<std::string, std::shared_ptr<LiveJob>> live_;  // jobs queued or running
  std::atomic<bool> shutting_down_{false};
  std::mutex running_mutex_;
  std::condition_variable running_changed_;
  int running_ = 0;
  // Retention: a thread that expires finished jobs (Store::expire_jobs) now and then.
  void expire_loop();
  // The background threads sleep on this and stop when told.
  std::mutex background_mutex_;
  std::condition_variable background_wake_;
  bool background_stop_ = false;
  std::thread expirer_, leaser_;
  std::unique_ptr<Scheduler> scheduler_;  // last: its workers use the members above
};

/// The event a job's state makes (the first one a watcher gets, and the terminal one).
pb::JobEvent state_event(const pb::Job& job);
bool is_terminal(pb::JobState s);

}  // namespace brenier::server

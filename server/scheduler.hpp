// brenierd's pool: `workers` threads run jobs from a bounded queue. A job may split itself
// into a group of tasks (a matrix's shapes and tiles): idle workers take a running group's
// tasks before they start a new job, and the job's own worker takes them too, so a group
// finishes even with one worker and never waits on a worker that waits on it.
#pragma once

#include <condition_variable>
#include <deque>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace brenier::server {

class Scheduler {
 public:
  using RunJob = std::function<void(const std::string& job_id)>;
  Scheduler(int workers, int queue_capacity, RunJob run);
  ~Scheduler();

  /// A place in the queue held for a job about to be accepted: commit() queues the job in it;
  /// dropped uncommitted, the place is freed. False when the queue was full.
  class Reservation {
   public:
    Reservation() = default;
    explicit Reservation(Scheduler* s) : s_(s) {}
    Reservation(Reservation&& o) noexcept : s_(std::exchange(o.s_, nullptr)) {}
    Reservation& operator=(Reservation&&) = delete;
    ~Reservation();
    explicit operator bool() const { return s_ != nullptr; }
    void commit(const std::string& job_id);

   private:
    Scheduler* s_ = nullptr;
  };
  /// Holds a place when fewer than `queue_capacity` jobs are queued or held.
  Reservation try_reserve();
  /// Queues a job whatever the queue's length (jobs accepted before a restart).
  void enqueue(const std::string& job_id);
  /// Takes a queued job out of the queue (cancelled before it started), freeing its place.
  void remove(const std::string& job_id);
  /// Runs task(k) for k in [0, n) on this thread and any idle worker; returns when all have
  /// finished. After a task throws no new one starts, and the exception of the lowest index
  /// is rethrown. Called from inside a job.
  void run_group(int n, const std::function<void(int)>& task);

  int workers() const { return static_cast<int>(threads_.size()); }
  int queued();
  /// Places left in the queue (neither taken nor held).
  int free_places();
  /// Stops taking queued jobs (they stay queued in the store); running ones go on.
  void stop_taking();
  /// Waits for the running jobs to finish, then joins the workers.
  void join();

 private:
  struct Group;
  void work();
  bool take_task(std::unique_lock<std::mutex>& lock);
  void run_next(Group& g, std::unique_lock<std::mutex>& lock);

  RunJob run_;
  int capacity_;
  int reserved_ = 0;  // places held by Reservations not yet committed
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::string> queue_;
  std::vector<std::shared_ptr<Group>> groups_;  // groups with tasks not yet taken
  bool taking_ = true, stopping_ = false;
  std::vector<std::thread> threads_;
};

}  // namespace brenier::server

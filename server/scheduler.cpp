#include "scheduler.hpp"

#include <algorithm>
#include <omp.h>

#include <spdlog/spdlog.h>

#include "common/parallel.hpp"

namespace brenier::server {

struct Scheduler::Group {
  int n = 0;
  int next = 0;      // the next task to take (guarded by the scheduler's mutex)
  int finished = 0;  // tasks done
  bool stop = false;
  int failed_at = 0;
  std::exception_ptr failure;
  const std::function<void(int)>* task = nullptr;
  std::condition_variable done;
};

Scheduler::Scheduler(int workers, int queue_capacity, RunJob run) : run_(std::move(run)), capacity_(queue_capacity) {
  for (int k = 0; k < std::max(1, workers); ++k) threads_.emplace_back([this] { work(); });
}

Scheduler::~Scheduler() {
  stop_taking();
  join();
}

Scheduler::Reservation Scheduler::try_reserve() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (static_cast<int>(queue_.size()) + reserved_ >= capacity_) return Reservation();
  ++reserved_;
  return Reservation(this);
}

void Scheduler::Reservation::commit(const std::string& id) {
  {
    std::lock_guard<std::mutex> lock(s_->mutex_);
    --s_->reserved_;
    s_->queue_.push_back(id);
    s_->cv_.notify_one();
  }
  s_ = nullptr;
}

Scheduler::Reservation::~Reservation() {
  if (!s_) return;
  std::lock_guard<std::mutex> lock(s_->mutex_);
  --s_->reserved_;
}

void Scheduler::enqueue(const std::string& id) {
  std::lock_guard<std::mutex> lock(mutex_);
  queue_.push_back(id);
  cv_.notify_one();
}

void Scheduler::remove(const std::string& id) {
  std::lock_guard<std::mutex> lock(mutex_);
  std::erase(queue_, id);
}

int Scheduler::queued() {
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<int>(queue_.size());
}

int Scheduler::free_places() {
  std::lock_guard<std::mutex> lock(mutex_);
  return std::max(0, capacity_ - static_cast<int>(queue_.size()) - reserved_);
}

void Scheduler::stop_taking() {
  std::lock_guard<std::mutex> lock(mutex_);
  taking_ = false;
  cv_.notify_all();
}

void Scheduler::join() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
    cv_.notify_all();
  }
  for (std::thread& t : threads_)
    if (t.joinable()) t.join();
}

// Runs the group's next task with the lock released (one OpenMP thread: the pool fills the
// cores), then records its end and the first failure by index.
void Scheduler::run_next(Group& g, std::unique_lock<std::mutex>& lock) {
  const int k = g.next++;
  lock.unlock();
  omp_set_num_threads(1);
  std::exception_ptr failure;
  try {
    (*g.task)(k);
  } catch (...) {
    failure = std::current_exception();
  }
  lock.lock();
  if (failure && (!g.failure || k < g.failed_at)) {
    g.failure = failure;
    g.failed_at = k;
    g.stop = true;
  }
  ++g.finished;
  g.done.notify_all();
}

// Takes one task of the oldest group that has any left and runs it (the lock released
// meanwhile). False when no group has a task to give.
bool Scheduler::take_task(std::unique_lock<std::mutex>& lock) {
  while (!groups_.empty()) {
    std::shared_ptr<Group> g = groups_.front();
    if (g->stop || g->next >= g->n) {
      groups_.erase(groups_.begin());
      continue;
    }
    run_next(*g, lock);
    return true;
  }
  return false;
}

void Scheduler::run_group(int n, const std::function<void(int)>& task) {
  if (n <= 0) return;
  auto g = std::make_shared<Group>();
  g->n = n;
  g->task = &task;
  std::unique_lock<std::mutex> lock(mutex_);
  groups_.push_back(g);
  cv_.notify_all();
  // Help with our own group (others' tasks are left to their workers), then wait for the
  // tasks other workers took.
  while (!g->stop && g->next < g->n) run_next(*g, lock);
  const int started = g->next;
  g->done.wait(lock, [&] { return g->finished >= started; });
  std::erase(groups_, g);
  omp_set_num_threads(hardware_threads());
  if (g->failure) std::rethrow_exception(g->failure);
}

void Scheduler::work() {
  single_threaded_blas();
  // Workers run at the normal priority: at nice 10 (tried, for the submit latency's tail)
  // they got a tenth of a core beside any other busy process, and cancellation, checked per
  // Newton iteration, took fifty times longer (bench/RESULTS.md).
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    if (take_task(lock)) continue;
    if (taking_ && !queue_.empty()) {
      const std::string id = queue_.front();
      queue_.pop_front();
      lock.unlock();
      // A job's numerical loops use the machine's cores (OpenMP), as brenier-compute does;
      // group tasks run one thread each (the pool fills the cores).
      omp_set_num_threads(hardware_threads());
      try {
        run_(id);
      } catch (const std::exception& e) {
        // run_ reports a job's own failures; what reaches here is the bookkeeping's (the
        // store). The job stays as the store has it (requeued at the next start if it was
        // running); the server goes on.
        spdlog::error("job {}: {}", id, e.what());
      } catch (...) {
        spdlog::error("job {}: unknown error", id);
      }
      lock.lock();
      continue;
    }
    if (stopping_ && groups_.empty()) return;
    cv_.wait(lock);
  }
}

}  // namespace brenier::server

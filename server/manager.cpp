#include "manager.hpp"
#include "test_hooks.hpp"

#include <google/protobuf/util/time_util.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>

#include "common/error.hpp"
#include "common/parallel.hpp"
#include "jobs/jobs.hpp"
#include "mesh/topology.hpp"
#include "job_kinds.hpp"
#include "status.hpp"

namespace brenier::server {
namespace fs = std::filesystem;
using google::protobuf::util::TimeUtil;

bool is_terminal(pb::JobState s) { return s == pb::SUCCEEDED || s == pb::FAILED || s == pb::CANCELLED; }

pb::JobEvent state_event(const pb::Job& job) {
  pb::JobEvent e;
  e.set_job_id(job.id());
  e.set_state(job.state());
  e.set_stage(job.stage());
  e.set_fraction(job.fraction());
  *e.mutable_time() = TimeUtil::GetCurrentTime();
  if (job.has_error()) *e.mutable_error() = job.error();
  if (job.state() == pb::SUCCEEDED) e.set_message("succeeded");
  if (job.has_error()) e.set_message(job.error().message());
  return e;
}

namespace {

std::string random_id() {
  static std::mutex m;
  static std::mt19937_64 rng{std::random_device{}()};
  std::lock_guard<std::mutex> lock(m);
  char buf[33];
  std::snprintf(buf, sizeof buf, "%016llx%016llx", static_cast<unsigned long long>(rng()),
                static_cast<unsigned long long>(rng()));
  return buf;
}

pb::TopologyClass topology_class(mesh::MeshClass c) {
  switch (c) {
    case mesh::MeshClass::kDisk: return pb::TOPOLOGICAL_DISK;
    case mesh::MeshClass::kSphere: return pb::TOPOLOGICAL_SPHERE;
    default: return pb::OTHER;
  }
}

}  // namespace

Manager::Manager(Store& store, const ManagerOptions& options) : store_(store), options_(options) {
  if (options_.workers <= 0) options_.workers = hardware_threads();
  if (options_.queue < 1) invalid("the queue must hold at least one job");
  scheduler_ = std::make_unique<Scheduler>(options_.workers, options_.queue, [this](const std::string& id) { run(id); });
  if (options_.retention_seconds > 0) expirer_ = std::thread([this] { expire_loop(); });
  if (store_.shared()) leaser_ = std::thread([this] { lease_loop(); });
}

// Every quarter of the retention period (between a second and an hour), the jobs finished
// longer ago than it go, with their results.
void Manager::expire_loop() {
  const double period = std::clamp(options_.retention_seconds / 4, 1.0, 3600.0);
  const auto spare = std::chrono::seconds(static_cast<int64_t>(std::min(600.0, options_.retention_seconds / 2)));
  std::unique_lock<std::mutex> lock(background_mutex_);
  while (!background_stop_) {
    lock.unlock();
    try {
      const int64_t now = TimeUtil::GetCurrentTime().seconds();
      if (const int n = store_.expire_jobs(now - static_cast<int64_t>(options_.retention_seconds), spare))
        spdlog::info("expired {} finished jobs older than the retention period", n);
      // Replicas do not restart to sweep: blobs an hour old that nothing names (a replica killed
      // between a blob and its row) go now and then.
      if (store_.shared())
        if (const int n = store_.sweep_orphaned_blobs(std::chrono::hours(1)))
          spdlog::info("removed {} orphaned blobs", n);
    } catch (const std::exception& e) {
      spdlog::warn("expiring finished jobs failed: {}", e.what());
    }
    lock.lock();
    background_wake_.wait_for(lock, std::chrono::duration<double>(period), [this] { return background_stop_; });
  }
}

Manager::~Manager() {
  {
    std::lock_guard<std::mutex> lock(background_mutex_);
    background_stop_ = true;
  }
  background_wake_.notify_all();
  if (expirer_.joinable()) expirer_.join();
  if (leaser_.joinable()) leaser_.join();
  if (scheduler_) {
    scheduler_->stop_taking();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      for (auto& [id, l] : live_) l->interrupted = true;
    }
    scheduler_->join();
  }
}

void Manager::recover() {
  if (store_.shared()) {  // replicas: the jobs whose lease has run out, as the lease thread claims them
    claim_expired();
    return;
  }
  for (const std::string& id : store_.unfinished_jobs()) adopt(id, "requeued after a restart");
}

void Manager::check_room(const std::string& tenant, int64_t bytes) {
  if (options_.max_storage_bytes_per_tenant > 0) {
    const int64_t held = store_.storage_bytes(tenant);
    if (held + std::max<int64_t>(bytes, 1) > options_.max_storage_bytes_per_tenant)
      fail(ErrorCode::kResourceExhausted,
           "you hold " + std::to_string(held) + " bytes of meshes and results; " + std::to_string(bytes) +
               " more would pass the quota max_storage_mb_per_tenant of this server (" +
               std::to_string(options_.max_storage_bytes_per_tenant >> 20) + " MB); delete meshes first");
  }
  std::error_code ec;
  const fs::space_info space = fs::space(store_.dir(), ec);
  if (!ec && static_cast<int64_t>(space.available) - bytes < options_.min_free_bytes)
    fail(ErrorCode::kResourceExhausted, "the server's disk has " + std::to_string(space.available >> 20) +
                                            " MB free; storing " + std::to_string(bytes) +
                                            " bytes would leave less than its reserve (min_free_mb)");
}

pb::Mesh Manager::add_mesh(const std::string& tenant, const pb::UploadMeshRequest::Header& h, const std::string& bytes) {
  std::optional<mesh::Format> format;
  if (!h.format().empty()) {
    format = mesh::parse_format(h.format());
    if (!format) invalid("unknown format '" + h.format() + "' (obj, off, ply, stl, freesurfer)");
  }
  if (!format) format = mesh::detect_format(h.name(), std::string_view(bytes).substr(0, 256));
  mesh::ReadLimits limits;
  limits.max_bytes = options_.max_upload_bytes;
  limits.max_vertices = options_.max_vertices;
  const mesh::PolygonSoup soup = mesh::read_soup(bytes, *format, limits);
  const mesh::CleanMesh cm = mesh::clean(soup);
  mesh::require_valid(cm, h.name().empty() ? "the mesh" : h.name());
  if (cm.mesh.num_vertices() > options_.max_vertices)
    fail(ErrorCode::kResourceExhausted, "the mesh has " + std::to_string(cm.mesh.num_vertices()) +
                                            " vertices; this server takes at most " +
                                            std::to_string(options_.max_vertices));
  const mesh::Topology t = mesh::compute_topology(cm.mesh);
  pb::Mesh m;
  m.set_id(h.sha256());
  m.set_name(h.name().empty() ? h.sha256().substr(0, 12) : h.name());
  m.set_format(mesh::format_name(*format));
  m.set_size_bytes(static_cast<int64_t>(bytes.size()));
  m.set_vertices(t.vertices);
  m.set_faces(t.faces);
  m.set_topology_class(topology_class(t.mesh_class));
  m.set_boundary_loops(t.boundary_loops);
  m.set_genus(t.genus);
  *m.mutable_created() = TimeUtil::GetCurrentTime();
  for (const auto& p : cm.report.problems) m.add_warnings(name_options(p.message, OptionStyle::kField));
  if (!store_.get_mesh(tenant, m.id())) check_room(tenant, m.size_bytes());  // before a byte is written
  return store_.put_mesh_with_blob(tenant, m, bytes);
}

pb::Job Manager::submit(const std::string& tenant, const pb::SubmitJobRequest& request) {
  if (shutting_down_) fail(ErrorCode::kUnavailable, "the server is shutting down");
  if (request.request_id().size() > 200) invalid("request_id is longer than 200 characters");
  auto mesh_of = [&](const std::string& id) {
    if (id.empty()) invalid("a mesh id is missing from the spec");
    if (id.size() > 64) invalid("a mesh id of " + std::to_string(id.size()) + " characters; ids are 64 hex digits");
    auto m = store_.get_mesh(tenant, id);
    if (!m) fail(ErrorCode::kNotFound, "no mesh " + id);
    return *m;
  };
  const std::string kind = check_spec(request, mesh_of, SpecLimits{options_.max_vertices, options_.max_matrix_meshes});
  // A tenant at its storage quota, or a full disk, takes no new work (a resubmission of an
  // accepted job is still answered).
  if (request.request_id().empty() || !store_.has_request(tenant, request.request_id())) check_room(tenant, 0);
  pb::Job job;
  job.set_id(random_id());
  job.set_request_id(request.request_id());
  job.set_state(pb::QUEUED);
  job.set_kind(kind);
  job.set_stage("queued");
  *job.mutable_created() = TimeUtil::GetCurrentTime();
  *job.mutable_spec() = request;
  // The queue's place is taken before the row is written, so a refused submission leaves no
  // row behind that a concurrent resubmission with the same request_id could be handed.
  // The live entry goes in first too: whoever sees the row (a resubmission, a watcher) finds
  // the job live.
  Scheduler::Reservation place = scheduler_->try_reserve();
  if (!place)
    fail(ErrorCode::kResourceExhausted, "the job queue is full (" + std::to_string(options_.queue) +
                                            " jobs waiting); try again later");
  auto l = std::make_shared<LiveJob>();
  l->job = job;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    live_[job.id()] = l;
  }
  bool inserted = false;
  pb::Job stored;
  try {
    stored = store_.insert_job(tenant, job, inserted, options_.max_jobs_per_tenant);
  } catch (...) {
    std::lock_guard<std::mutex> lock(mutex_);
    live_.erase(job.id());
    throw;
  }
  if (!inserted) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      live_.erase(job.id());  // nobody saw this id: the earlier job is the answer
    }
    if (stored.spec().SerializeAsString() != request.SerializeAsString())
      invalid("request_id '" + request.request_id() + "' was used for another job spec (job " + stored.id() + ")");
    return with_progress(std::move(stored));
  }
  test_hooks::at(test_hooks::Point::kSubmitAfterInsert);
  place.commit(stored.id());
  spdlog::info("job {} ({}) queued for tenant '{}'", stored.id(), kind, tenant);
  return stored;
}

std::shared_ptr<LiveJob> Manager::find_live(const std::string& id) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = live_.find(id);
  return it == live_.end() ? nullptr : it->second;
}

pb::Job Manager::get(const std::string& tenant, const std::string& id) {
  pb::Job current;
  (void)live(tenant, id, current);
  return current;
}

pb::Job Manager::with_progress(pb::Job stored) {
  if (is_terminal(stored.state())) return stored;
  std::shared_ptr<LiveJob> l = find_live(stored.id());
  if (!l) return stored;
  std::lock_guard<std::mutex> lock(l->mutex);
  return l->job;
}

// Order matters: the live entry is looked up before the store is read. A job leaves the live
// map only after its terminal state is in the store (run, cancel), so either the entry was
// found (and it holds the latest state, the terminal one included) or the store read that
// follows sees the job finished. The other order could read RUNNING from the store, lose the
// entry to a job finishing meanwhile, and hand a watcher a stale state with no terminal event.
std::shared_ptr<LiveJob> Manager::live(const std::string& tenant, const std::string& id, pb::Job& current) {
  std::shared_ptr<LiveJob> l = find_live(id);
  test_hooks::at(test_hooks::Point::kLiveBetweenLookups);
  auto stored = store_.get_job(tenant, id);
  if (!stored) fail(ErrorCode::kNotFound, "no job " + id);  // others' jobs too
  if (!l || is_terminal(stored->state())) {
    current = std::move(*stored);
    return nullptr;
  }
  std::lock_guard<std::mutex> lock(l->mutex);
  current = l->job;
  return l;
}

pb::Job Manager::cancel(const std::string& tenant, const std::string& id) {
  pb::Job current;
  std::shared_ptr<LiveJob> l = live(tenant, id, current);
  if (!l) {
    // Finished: unchanged. Held by another replica: it cancels the job within a second.
    if (!is_terminal(current.state()) && store_.shared()) {
      store_.request_cancel(id);
      spdlog::info("job {} cancel requested (it is held by another replica)", id);
    }
    return current;
  }
  cancel_live(l, current);
  spdlog::info("job {} cancel requested", id);
  return current;
}

// A queued job is cancelled at once (its place in the queue freed); a running one is told to
// stop and ends CANCELLED when its loops next look.
void Manager::cancel_live(const std::shared_ptr<LiveJob>& l, pb::Job& current) {
  bool cancelled_now = false;
  {
    std::lock_guard<std::mutex> lock(l->mutex);
    l->cancel = true;
    if (l->job.state() == pb::QUEUED) {
      l->job.set_state(pb::CANCELLED);
      l->job.set_stage("cancelled");
      l->job.mutable_error()->set_code(static_cast<int>(grpc::StatusCode::CANCELLED));
      l->job.mutable_error()->set_message("cancelled before it started");
      *l->job.mutable_finished() = TimeUtil::GetCurrentTime();
      store_.update_job(l->job);
      cancelled_now = true;
    }
    current = l->job;
  }
  if (cancelled_now) {
    scheduler_->remove(current.id());
    finish(l, current);
  }
}

void Manager::publish(LiveJob& l, const pb::JobEvent& e) {
  std::lock_guard<std::mutex> lock(l.mutex);
  l.events.push_back(e);
  while (l.events.size() > 4096) {
    l.events.pop_front();
    ++l.first_seq;
  }
  l.changed.notify_all();
}

// The terminal event, and the job out of the live map (watchers holding it still read it).
void Manager::finish(const std::shared_ptr<LiveJob>& l, pb::Job job) {
  {
    std::lock_guard<std::mutex> lock(l->mutex);
    l->job = job;
    l->terminal = true;
  }
  publish(*l, state_event(job));
  std::lock_guard<std::mutex> lock(mutex_);
  live_.erase(job.id());
}

void Manager::begin_shutdown() {
  shutting_down_ = true;
  scheduler_->stop_taking();
}

void Manager::finish_shutdown(double grace_seconds) {
  {
    std::unique_lock<std::mutex> lock(running_mutex_);
    running_changed_.wait_for(lock, std::chrono::duration<double>(grace_seconds), [&] { return running_ == 0; });
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (auto& [id, l] : live_) l->interrupted = true;
  }
  scheduler_->join();
  // Jobs still queued here go to the other replicas at once rather than when the lease ends.
  for (const auto& [id, l] : live_jobs()) {
    try {
      store_.release(id);
    } catch (const std::exception& e) {
      spdlog::warn("job {} keeps its lease until it runs out: {}", id, e.what());
    }
  }
}


// ---- replicas ----

std::vector<std::pair<std::string, std::shared_ptr<LiveJob>>> Manager::live_jobs() {
  std::lock_guard<std::mutex> lock(mutex_);
  return {live_.begin(), live_.end()};
}

// Every tick (a tenth of the lease, at most a second): cancellations asked elsewhere, the
// running jobs' progress and claims of jobs whose lease ran out (so a dead replica's jobs
// run again within a tick of their lease's end); every third of the lease: renewals.
void Manager::lease_loop() {
  const double tick = std::clamp(options_.lease_seconds / 10, 0.05, 1.0);
  const int renew_every = std::max(1, static_cast<int>(options_.lease_seconds / 3 / tick));
  std::map<std::string, std::string> written;
  std::string last_error;
  std::unique_lock<std::mutex> lock(background_mutex_);
  for (int n = 0; !background_stop_; ++n) {
    lock.unlock();
    try {
      apply_cancels();
      write_progress(written);
      if (n % renew_every == 0) renew_leases();
      if (!shutting_down_) claim_expired();
      if (!last_error.empty()) spdlog::info("leases: the database answers again");
      last_error.clear();
    } catch (const std::exception& e) {
      if (e.what() != last_error) spdlog::warn("leases: {}", e.what());
      last_error = e.what();
    }
    lock.lock();
    background_wake_.wait_for(lock, std::chrono::duration<double>(tick), [this] { return background_stop_; });
  }
}

void Manager::apply_cancels() {
  for (const std::string& id : store_.cancels_requested()) {
    std::shared_ptr<LiveJob> l = find_live(id);
    if (!l || l->cancel) continue;
    pb::Job current;
    cancel_live(l, current);
    spdlog::info("job {} cancelled through another replica", id);
  }
}

// Running jobs whose stage or fraction moved since the last tick, for watchers elsewhere.
void Manager::write_progress(std::map<std::string, std::string>& written) {
  std::map<std::string, std::string> now;
  for (const auto& [id, l] : live_jobs()) {
    pb::Job j;
    {
      std::lock_guard<std::mutex> lock(l->mutex);
      if (l->terminal || l->job.state() != pb::RUNNING) continue;
      j = l->job;
    }
    std::string mark = j.stage() + " " + std::to_string(j.fraction());
    if (written[j.id()] != mark) store_.update_progress(j);
    now[j.id()] = std::move(mark);
  }
  written.swap(now);
}

// A job whose lease could not be renewed is held by another replica now (this one lost the
// database for longer than the lease): it stops here, unwritten.
void Manager::renew_leases() {
  std::vector<std::string> ids;
  for (const auto& [id, l] : live_jobs()) ids.push_back(id);
  const std::vector<std::string> kept_list = store_.renew_leases(ids);
  const std::set<std::string> kept(kept_list.begin(), kept_list.end());
  for (const std::string& id : ids) {
    if (kept.count(id)) continue;
    std::shared_ptr<LiveJob> l = find_live(id);
    const auto stored = store_.get_job_any(id);
    if (!l || !stored || is_terminal(stored->state())) continue;  // it finished meanwhile
    detach(id, l, "its lease ran out and another replica holds it");
  }
}

// Takes the jobs whose replica stopped renewing them, at most as many as the queue has free
// places (none held meanwhile: a submission racing a claim finds the queue as it is; one that
// takes a place between the count and the claim makes the queue one longer for a moment).
void Manager::claim_expired() {
  const int room = std::min(8, scheduler_->free_places());
  for (const std::string& id : store_.claim_expired(room)) adopt(id, "requeued: the replica running it stopped");
}

// A job queued here that an earlier run (or another replica) left unfinished; a running one
// runs again from the start (a matrix from its finished tiles).
void Manager::adopt(const std::string& id, const std::string& why) {
  auto job = store_.get_job_any(id);
  if (!job || is_terminal(job->state())) return;
  if (job->state() == pb::RUNNING) {
    job->set_state(pb::QUEUED);
    job->set_stage(why);
    store_.update_job(*job);
  }
  auto l = std::make_shared<LiveJob>();
  l->job = *job;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    live_[id] = l;
  }
  scheduler_->enqueue(id);
  spdlog::info("job {} queued: {} ({} attempts so far)", id, why, job->attempts());
}

void Manager::detach(const std::string& id, const std::shared_ptr<LiveJob>& l, const std::string& why) {
  l->interrupted = true;  // a run stops at its next check
  l->detached = true;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    live_.erase(id);
  }
  l->changed.notify_all();
  scheduler_->remove(id);
  spdlog::warn("job {} left this replica: {}", id, why);
}

void Manager::follow(const std::string& tenant, const std::string& id,
                     const std::function<bool(const pb::JobEvent&)>& write, const std::function<bool()>& stop) {
  pb::Job last;
  auto written_at = std::chrono::steady_clock::now();
  for (bool first = true;; first = false) {
    const pb::Job j = get(tenant, id);
    const auto now = std::chrono::steady_clock::now();
    const bool moved = first || j.state() != last.state() || j.stage() != last.stage() || j.fraction() != last.fraction();
    if (moved || now - written_at >= std::chrono::milliseconds(1500)) {
      if (!write(state_event(j))) return;
      written_at = now;
    }
    if (is_terminal(j.state())) return;
    last = j;
    for (int k = 0; k < 5; ++k) {
      if (stop()) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }
}

void Manager::run(const std::string& id) {
  test_hooks::at(test_hooks::Point::kRunStart);
  std::shared_ptr<LiveJob> l = find_live(id);
  if (!l) return;  // cancelled while queued
  std::string tenant;
  pb::Job job;
  try {
    std::lock_guard<std::mutex> lock(l->mutex);
    if (l->job.state() != pb::QUEUED) return;
    auto stored = store_.get_job_any(id, &tenant);
    if (!stored) return;
    job = *stored;
    job.set_state(pb::RUNNING);
    job.set_stage("starting");
    job.set_fraction(0);
    job.set_attempts(job.attempts() + 1);
    *job.mutable_started() = TimeUtil::GetCurrentTime();
    store_.update_job(job);
    l->job = job;
  } catch (const Error& e) {  // the database is away, or another replica holds the job now
    detach(id, l, e.what());
    return;
  }
  {
    std::lock_guard<std::mutex> lock(running_mutex_);
    ++running_;
  }
  // However this run ends (a store failure included), it stops counting as running.
  struct Running {
    Manager& m;
    ~Running() {
      std::lock_guard<std::mutex> lock(m.running_mutex_);
      --m.running_;
      m.running_changed_.notify_all();
    }
  } running_guard{*this};
  publish(*l, state_event(job));
  spdlog::info("job {} ({}) started, attempt {}", id, job.kind(), job.attempts());
  const auto t0 = std::chrono::steady_clock::now();
  JobContext c{store_, *scheduler_, *l, tenant, [&](const pb::JobEvent& e) { publish(*l, e); }, options_.executor};
  pb::JobResult result;
  std::optional<Error> error;
  bool requeue = false;
  try {
    result = run_spec(c, job.spec());
  } catch (const Error& e) {
    if (e.code() == ErrorCode::kCancelled && l->interrupted && !l->cancel) requeue = true;
    error = e;
  } catch (const std::bad_alloc&) {
    error = Error(ErrorCode::kResourceExhausted, "out of memory");
  } catch (const std::exception& e) {
    error = Error(ErrorCode::kInternal, std::string("internal error: ") + e.what());
  }
  if (l->detached) {
    spdlog::warn("job {} stopped here after {:.3f} s: another replica holds it", id,
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    return;
  }
  {
    std::lock_guard<std::mutex> lock(l->mutex);
    job = l->job;
  }
  try {
    job = record_outcome(l, job, error, result, requeue);
  } catch (const Error& e) {
    // Its state could not be written: it is left to the lease (on a shared store another
    // replica, or this one, runs it again once the lease runs out) or to the next start.
    detach(id, l, std::string("its outcome could not be written: ") + e.what());
    return;
  }
  if (!requeue)
    spdlog::info("job {} {} in {:.3f} s{}{}", id, pb::JobState_Name(job.state()),
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), error ? ": " : "",
                 error ? error->what() : "");
}

// The job's end as the store and its watchers get it: requeued (a shutdown interrupted it),
// or succeeded, cancelled or failed.
pb::Job Manager::record_outcome(const std::shared_ptr<LiveJob>& l, pb::Job job, const std::optional<Error>& error,
                                const pb::JobResult& result, bool requeue) {
  if (requeue) {
    // Shutting down: the job stays queued in the store and runs again at the next start (or,
    // on a shared store, at once on another replica: the lease is let go).
    job.set_state(pb::QUEUED);
    job.set_stage("interrupted by a shutdown; runs again at the next start");
    store_.update_job(job);
    store_.release(job.id());
    spdlog::warn("job {} interrupted by the shutdown; requeued", job.id());
    if (store_.shared()) detach(job.id(), l, "let go at the shutdown");  // not renewed any more
    return job;
  }
  if (!error) {
    job.set_state(pb::SUCCEEDED);
    job.set_stage("done");
    job.set_fraction(1);
    *job.mutable_result() = result;
  } else if (error->code() == ErrorCode::kCancelled) {
    job.set_state(pb::CANCELLED);
    job.set_stage("cancelled");
    job.mutable_error()->set_code(static_cast<int>(grpc::StatusCode::CANCELLED));
    job.mutable_error()->set_message("cancelled");
  } else {
    job.set_state(pb::FAILED);
    job.set_stage("failed");
    job.mutable_error()->set_code(static_cast<int>(status_code(error->code())));
    job.mutable_error()->set_message(client_message(*error));
  }
  *job.mutable_finished() = TimeUtil::GetCurrentTime();
  store_.update_job(job);
  finish(l, job);
  return job;
}

}  // namespace brenier::server

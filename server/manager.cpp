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

std::string domain_name(pb::Domain d) { return d == pb::SPHERE ? "sphere" : "disk"; }
std::string map_method_name(pb::MapMethod m) { return m == pb::AREA_PRESERVING ? "area-preserving" : "conformal"; }
std::string distance_method_name(pb::DistanceMethod m) { return m == pb::OMT_LINEAR ? "omt-linear" : "wasserstein"; }

pb::TopologyClass topology_class(mesh::MeshClass c) {
  switch (c) {
    case mesh::MeshClass::kDisk: return pb::TOPOLOGICAL_DISK;
    case mesh::MeshClass::kSphere: return pb::TOPOLOGICAL_SPHERE;
    default: return pb::OTHER;
  }
}

// The same checks the core makes when the job runs, made at submission from the mesh's
// record, so that a spec that cannot run is refused at once.
void require_fits(const pb::Mesh& m, pb::Domain domain, bool cut_hole) {
  const bool sphere = domain == pb::SPHERE;
  const char* cls = m.topology_class() == pb::TOPOLOGICAL_DISK     ? "disk"
                    : m.topology_class() == pb::TOPOLOGICAL_SPHERE ? "sphere"
                                                                   : "other";
  if (sphere && cut_hole) invalid("cut_hole applies to the disk domain");
  if (sphere && m.topology_class() != pb::TOPOLOGICAL_SPHERE)
    invalid("mesh " + m.name() + " (" + m.id().substr(0, 12) + ") is a " + cls +
            " mesh; the sphere domain needs a closed genus-0 surface");
  if (!sphere && m.topology_class() != pb::TOPOLOGICAL_DISK && !(cut_hole && m.topology_class() == pb::TOPOLOGICAL_SPHERE))
    invalid("mesh " + m.name() + " (" + m.id().substr(0, 12) + ") is a " + cls +
            " mesh; the disk domain needs a topological disk" +
            (m.topology_class() == pb::TOPOLOGICAL_SPHERE ? " (set cut_hole to open it)" : ""));
}

jobs::MapRequest map_request(const pb::MapSpec& s) {
  jobs::MapRequest r;
  r.domain = domain_name(s.domain());
  r.method = map_method_name(s.method());
  if (s.domain() == pb::SPHERE) {
    if (!s.markers().empty()) {
      if (s.markers_size() != 3) invalid("sphere markers are three vertices (sent to 0, 1, infinity)");
      r.markers.assign(s.markers().begin(), s.markers().end());
    }
  } else if (!s.markers().empty()) {
    if (s.markers_size() != 2) invalid("disk markers are two vertices: [center, boundary]");
    r.center = s.markers(0);
    r.boundary_marker = s.markers(1);
  }
  r.cut_hole = s.cut_hole();
  if (s.has_hole_vertex()) {
    if (!s.cut_hole()) invalid("hole_vertex goes with cut_hole");
    r.hole_vertex = s.hole_vertex();
    if (r.hole_vertex < 0) invalid("hole_vertex must be a vertex number");
  }
  if (s.max_iterations() < 0 || s.max_iterations() > 100000) invalid("max_iterations must lie in [1, 100000] (0: the default)");
  if (s.max_iterations() > 0) r.max_iterations = s.max_iterations();
  if (!(s.tolerance() >= 0) || !std::isfinite(s.tolerance())) invalid("the tolerance must be a positive number");
  r.tolerance = s.tolerance();
  r.weights.assign(s.weights().begin(), s.weights().end());
  if (!(s.t() >= 0 && s.t() <= 1)) invalid("t must lie in [0, 1]");
  r.t = s.t();
  r.allow_flips = s.allow_flips();
  if (r.method == "conformal" && (r.t > 0 || !r.weights.empty()))
    invalid("t and weights apply to the area-preserving method");
  return r;
}

mesh::Format output_format(const std::string& f) {
  if (f.empty()) return mesh::Format::kObj;
  const auto p = mesh::parse_format(f);
  if (!p || *p == mesh::Format::kStl || *p == mesh::Format::kFreeSurfer)
    invalid("output_format '" + f + "' is not one of obj, ply, off");
  return *p;
}

template <class Spec>
jobs::ShapeRequest shape_request(const Spec& s) {
  jobs::ShapeRequest r;
  r.method = distance_method_name(s.method());
  r.domain = domain_name(s.domain());
  r.cut_hole = s.cut_hole();
  const pb::WassersteinOptions& w = s.wasserstein();
  if (!(w.tolerance() >= 0) || !std::isfinite(w.tolerance())) invalid("the tolerance must be a positive number");
  if (w.tolerance() > 0) r.tolerance = w.tolerance();
  if (!std::isfinite(w.cost_tolerance()) || w.cost_tolerance() > 1)
    invalid("the cost tolerance must be at most 1 (0: the default, negative: off)");
  if (w.cost_tolerance() != 0) r.cost_tolerance = std::max(0.0, w.cost_tolerance());
  r.refine_rotation = w.refine_rotation();
  r.raw = w.raw();
  r.shape_options();  // refuses what the core refuses
  return r;
}

// Markers as (center, boundary), or (-1, -1) when the message is absent.
std::pair<int, int> markers_of(bool has, const pb::DiskMarkers& m) {
  if (!has) return {-1, -1};
  if (m.center() < 0 || m.boundary() < 0) invalid("markers are vertex numbers");
  return {m.center(), m.boundary()};
}

pb::Artifact artifact(Store& store, const std::string& name, const std::string& media, const std::string& filename,
                      const std::string& bytes) {
  pb::Artifact a;
  a.set_name(name);
  a.set_media_type(media);
  a.set_filename(filename);
  a.set_size_bytes(static_cast<int64_t>(bytes.size()));
  a.set_sha256(store.put_blob(Store::Blob::kResult, bytes));
  return a;
}

std::string read_whole(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(ErrorCode::kInternal, "cannot read " + path);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

}  // namespace

Manager::Manager(Store& store, const ManagerOptions& options) : store_(store), options_(options) {
  if (options_.workers <= 0) options_.workers = hardware_threads();
  if (options_.queue < 1) invalid("the queue must hold at least one job");
  scheduler_ = std::make_unique<Scheduler>(options_.workers, options_.queue, [this](const std::string& id) { run(id); });
}

Manager::~Manager() {
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
  for (const std::string& id : store_.unfinished_jobs()) {
    auto job = store_.get_job_any(id);
    if (!job) continue;
    if (job->state() == pb::RUNNING) {
      job->set_state(pb::QUEUED);
      job->set_stage("requeued after a restart");
      store_.update_job(*job);
    }
    auto l = std::make_shared<LiveJob>();
    l->job = *job;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      live_[id] = l;
    }
    scheduler_->enqueue(id);
    spdlog::info("job {} requeued ({} attempts so far)", id, job->attempts());
  }
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
  std::string kind;
  switch (request.spec_case()) {
    case pb::SubmitJobRequest::kMap: {
      const pb::MapSpec& s = request.map();
      kind = "map";
      map_request(s);
      output_format(s.output_format());
      const pb::Mesh m = mesh_of(s.mesh());
      require_fits(m, s.domain(), s.cut_hole());
      // One weight per vertex of the input file, checked when the job reads it; bounded here.
      if (s.weights_size() > options_.max_vertices)
        invalid(std::to_string(s.weights_size()) + " weights; this server takes meshes of at most " +
                std::to_string(options_.max_vertices) + " vertices");
      break;
    }
    case pb::SubmitJobRequest::kDistance: {
      const pb::DistanceSpec& s = request.distance();
      kind = "distance";
      shape_request(s);
      if (s.has_markers_a() != s.has_markers_b()) invalid("give markers for both meshes or neither");
      require_fits(mesh_of(s.a()), s.domain(), s.cut_hole());
      require_fits(mesh_of(s.b()), s.domain(), s.cut_hole());
      break;
    }
    case pb::SubmitJobRequest::kMatrix: {
      const pb::MatrixSpec& s = request.matrix();
      kind = "matrix";
      shape_request(s);
      if (s.markers_size() != 0 && s.markers_size() != s.meshes_size())
        invalid(std::to_string(s.markers_size()) + " markers for " + std::to_string(s.meshes_size()) +
                " meshes (one per mesh, or none)");
      if (s.meshes_size() < 2) invalid("a distance matrix needs at least two meshes");
      if (s.meshes_size() > options_.max_matrix_meshes)
        fail(ErrorCode::kResourceExhausted, "a matrix job takes at most " + std::to_string(options_.max_matrix_meshes) +
                                                " meshes");
      std::set<std::string> seen;
      for (const std::string& id : s.meshes()) {
        if (!seen.insert(id).second) invalid("mesh " + id + " is given twice");
        require_fits(mesh_of(id), s.domain(), s.cut_hole());
      }
      break;
    }
    default:
      invalid("the job has no spec (map, distance or matrix)");
  }
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
    stored = store_.insert_job(tenant, job, inserted);
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
  if (!l) return current;  // finished: unchanged
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
    scheduler_->remove(id);  // its place in the queue is free at once
    finish(l, current);
  }
  spdlog::info("job {} cancel requested", id);
  return current;
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
}

// ---- running a job -----------------------------------------------------------------------

namespace {

// What a running job needs of its surroundings.
struct Context {
  Store& store;
  Scheduler& scheduler;
  LiveJob& live;
  std::string tenant;
  std::function<void(const pb::JobEvent&)> publish;
  bool keep_going() const { return !live.cancel && !live.interrupted; }
  jobs::ProgressSink sink() {
    return [this](const jobs::Progress& p) {
      pb::JobEvent e;
      e.set_job_id(live.job.id());
      e.set_state(pb::RUNNING);
      e.set_stage(p.stage);
      e.set_fraction(p.fraction);
      e.set_iteration(p.iteration);
      e.set_residual(p.residual);
      *e.mutable_time() = TimeUtil::GetCurrentTime();
      {
        std::lock_guard<std::mutex> lock(live.mutex);
        live.job.set_stage(p.stage);
        live.job.set_fraction(p.fraction);
      }
      publish(e);
      return keep_going();
    };
  }
  void check() const {
    if (!keep_going()) fail(ErrorCode::kCancelled, "cancelled");
  }
  mesh::CleanMesh load(const std::string& id, pb::Mesh* record = nullptr) {
    auto m = store.get_mesh(tenant, id);
    if (!m || !store.has_blob(Store::Blob::kMesh, id)) invalid("mesh " + id + " was deleted");
    if (record) *record = *m;
    const auto format = mesh::parse_format(m->format());
    return mesh::clean(mesh::read_soup(read_whole(store.blob_path(Store::Blob::kMesh, id)), *format));
  }
};

pb::JobResult run_map_job(Context& c, const pb::MapSpec& s) {
  pb::Mesh rec;
  const mesh::CleanMesh cm = c.load(s.mesh(), &rec);
  const jobs::MapRequest r = map_request(s);
  const mesh::Format format = output_format(s.output_format());
  const jobs::MapOutcome m = jobs::run_map(cm, rec.name(), r, c.sink());
  c.check();
  pb::JobResult out;
  const std::string ext = mesh::format_name(format);
  const std::string stem = rec.name() + "-" + r.domain + "-" + r.method;
  *out.add_artifacts() = artifact(c.store, "mesh", format == mesh::Format::kObj ? "model/obj" : "application/octet-stream",
                                  stem + "." + ext, jobs::map_mesh_bytes(m, format));
  *out.add_artifacts() = artifact(c.store, "report", "application/json", stem + ".json", m.report.dump(2));
  out.set_converged(true);
  return out;
}

pb::JobResult run_distance_job(Context& c, const pb::DistanceSpec& s) {
  const jobs::ShapeRequest r = shape_request(s);
  pb::Mesh ra, rb;
  const mesh::CleanMesh a = c.load(s.a(), &ra), b = c.load(s.b(), &rb);
  const auto [ca, ba] = markers_of(s.has_markers_a(), s.markers_a());
  const auto [cb, bb] = markers_of(s.has_markers_b(), s.markers_b());
  distance::ShapeInput ia = jobs::shape_input(a, ra.name(), ra.name(), r, ca, ba);
  distance::ShapeInput ib = jobs::shape_input(b, rb.name(), rb.name(), r, cb, bb);
  if (ia.name == ib.name) ib.name += " (b)";
  jobs::DistanceOutcome d = jobs::run_distance(ia, ib, r, hardware_threads(), c.sink());
  c.check();
  if (!d.result.converged) {
    char buf[200];
    std::snprintf(buf, sizeof buf, "the transport did not converge (max relative cell-mass error %.2e)",
                  d.result.max_relative_error);
    fail(ErrorCode::kNotConverged, buf);
  }
  d.report["a"] = s.a();
  d.report["b"] = s.b();
  pb::JobResult out;
  *out.add_artifacts() = artifact(c.store, "report", "application/json", "distance.json", d.report.dump(2));
  out.set_distance(d.result.distance);
  out.set_converged(true);
  return out;
}

// A matrix as groups of tasks on the shared pool: every shape once (cached by content hash
// under DATA/shapes, reused by later jobs), then tiles of pairs, each kept in a work
// directory as it finishes so that a run interrupted by a restart redoes only the missing
// tiles; the tiles are assembled as `brenier-compute merge` does.
pb::JobResult run_matrix_job(Context& c, const pb::MatrixSpec& s, const std::string& job_id) {
  const auto t0 = std::chrono::steady_clock::now();
  const jobs::ShapeRequest r = shape_request(s);
  const int n = s.meshes_size();
  std::vector<distance::ShapeInput> in(n);
  std::map<std::string, int> names;
  c.scheduler.run_group(n, [&](int k) {
    c.check();
    pb::Mesh rec;
    const mesh::CleanMesh cm = c.load(s.meshes(k), &rec);
    const auto [center, boundary] = markers_of(s.markers_size() > 0, s.markers_size() > 0 ? s.markers(k) : pb::DiskMarkers());
    in[k] = jobs::shape_input(cm, rec.name(), rec.name(), r, center, boundary);
  });
  for (int k = 0; k < n; ++k) ++names[in[k].name];
  for (int k = 0; k < n; ++k)
    if (names[in[k].name] > 1) in[k].name += "#" + s.meshes(k).substr(0, 12);
  const std::string cache = c.store.dir() + "/shapes";
  fs::create_directories(cache);
  std::mutex progress_mutex;
  int shapes_done = 0;
  auto cancel_only = [&](int, double) { return c.keep_going(); };
  c.scheduler.run_group(n, [&](int k) {
    c.check();
    distance::cached_shape(in[k], cache, cancel_only);
    std::lock_guard<std::mutex> lock(progress_mutex);
    ++shapes_done;
    c.sink()(jobs::Progress{"shapes", 0.5 * shapes_done / n, shapes_done, 0});
  });
  const int pairs = n * (n - 1) / 2;
  const int tiles = std::max(1, std::min(pairs, 4 * c.scheduler.workers()));
  const std::string work = c.store.dir() + "/work/" + job_id;
  fs::create_directories(work);
  distance::MatrixOptions mo;
  mo.method = distance::parse_method(r.method);
  mo.wasserstein = r.wasserstein();
  mo.jobs = 1;
  mo.cache_dir = cache;
  mo.solver_progress = cancel_only;
  std::vector<distance::MatrixTile> done(tiles);
  int tiles_done = 0;
  c.scheduler.run_group(tiles, [&](int k) {
    c.check();
    const std::string path = work + "/tile-" + std::to_string(k) + ".json";
    distance::MatrixOptions o = mo;
    o.tile = {k, tiles};
    bool reused = false;
    if (fs::exists(path)) {
      try {
        distance::MatrixTile t = distance::read_tile(path);
        if (t.tile.index == k && t.tile.count == tiles && static_cast<int>(t.names.size()) == n &&
            t.keys.front() == distance::shape_key(in.front().mesh, in.front().options)) {
          done[k] = std::move(t);
          reused = true;
        }
      } catch (const Error&) {
      }
    }
    if (!reused) {
      done[k] = distance::compute_tile(in, o);
      distance::write_tile(done[k], path + ".tmp");
      fs::rename(path + ".tmp", path);
    }
    std::lock_guard<std::mutex> lock(progress_mutex);
    ++tiles_done;
    c.sink()(jobs::Progress{"pairs", 0.5 + 0.5 * tiles_done / tiles, tiles_done, 0});
  });
  c.check();
  const Eigen::MatrixXd d = distance::assemble(done);  // checks the tiles belong together
  const std::vector<std::string>& nm = done.front().names;
  nlohmann::json failed = nlohmann::json::array();
  for (const auto& t : done)
    for (const auto& e : t.pairs)
      if (!e.result.converged) failed.push_back({nm[e.i], nm[e.j]});
  pb::JobResult out;
  auto matrix_file = [&](const std::string& ext) {
    const std::string tmp = c.store.temp_path() + "." + ext;
    distance::write_matrix(tmp, nm, d, done.front().method);
    std::string bytes = read_whole(tmp);
    fs::remove(tmp);
    return bytes;
  };
  *out.add_artifacts() = artifact(c.store, "matrix", "text/csv", "matrix.csv", matrix_file("csv"));
  *out.add_artifacts() = artifact(c.store, "matrix.npy", "application/octet-stream", "matrix.npy", matrix_file("npy"));
  nlohmann::json report = {{"method", done.front().method},
                           {"domain", r.domain},
                           {"shapes", nm},
                           {"meshes", std::vector<std::string>(s.meshes().begin(), s.meshes().end())},
                           {"pairs", pairs},
                           {"tiles", tiles},
                           {"not_converged", failed},
                           {"seconds", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()}};
  *out.add_artifacts() = artifact(c.store, "report", "application/json", "matrix.json", report.dump(2));
  out.set_converged(failed.empty());
  std::error_code ec;
  fs::remove_all(work, ec);
  return out;
}

}  // namespace

void Manager::run(const std::string& id) {
  test_hooks::at(test_hooks::Point::kRunStart);
  std::shared_ptr<LiveJob> l = find_live(id);
  if (!l) return;  // cancelled while queued
  std::string tenant;
  pb::Job job;
  {
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
  Context c{store_, *scheduler_, *l, tenant, [&](const pb::JobEvent& e) { publish(*l, e); }};
  pb::JobResult result;
  std::optional<Error> error;
  bool requeue = false;
  try {
    switch (job.spec().spec_case()) {
      case pb::SubmitJobRequest::kMap: result = run_map_job(c, job.spec().map()); break;
      case pb::SubmitJobRequest::kDistance: result = run_distance_job(c, job.spec().distance()); break;
      case pb::SubmitJobRequest::kMatrix: result = run_matrix_job(c, job.spec().matrix(), id); break;
      default: invalid("the job has no spec");
    }
  } catch (const Error& e) {
    if (e.code() == ErrorCode::kCancelled && l->interrupted && !l->cancel) requeue = true;
    error = e;
  } catch (const std::bad_alloc&) {
    error = Error(ErrorCode::kResourceExhausted, "out of memory");
  } catch (const std::exception& e) {
    error = Error(ErrorCode::kInternal, std::string("internal error: ") + e.what());
  }
  {
    std::lock_guard<std::mutex> lock(l->mutex);
    job = l->job;
  }
  if (requeue) {
    // Shutting down: the job stays queued in the store and runs again at the next start.
    job.set_state(pb::QUEUED);
    job.set_stage("interrupted by a shutdown; runs again at the next start");
    store_.update_job(job);
    spdlog::warn("job {} interrupted by the shutdown; requeued", id);
  } else {
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
    spdlog::info("job {} {} in {:.3f} s{}{}", id, pb::JobState_Name(job.state()),
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
                 error ? ": " : "", error ? error->what() : "");
  }
}

}  // namespace brenier::server

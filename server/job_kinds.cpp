#include "job_kinds.hpp"
#include "test_hooks.hpp"

#include <google/protobuf/util/time_util.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <set>

#include <spdlog/spdlog.h>

#include "common/error.hpp"
#include "common/parallel.hpp"
#include "jobs/matrix_work.hpp"
#include "render/render.hpp"
#include "render/report.hpp"
#include "spec.hpp"

namespace brenier::server {
namespace fs = std::filesystem;
using google::protobuf::util::TimeUtil;

namespace {

// The same checks the core makes when the job runs, made at submission from the mesh's
// record, so that a spec that cannot run is refused at once.
void require_fits(const pb::Mesh& m, jobs::Domain domain, bool cut_hole) {
  const bool sphere = domain == jobs::Domain::kSphere;
  const char* cls = m.topology_class() == pb::TOPOLOGICAL_DISK     ? "disk"
                    : m.topology_class() == pb::TOPOLOGICAL_SPHERE ? "sphere"
                                                                   : "other";
  if (sphere && m.topology_class() != pb::TOPOLOGICAL_SPHERE)
    invalid("mesh " + m.name() + " (" + m.id().substr(0, 12) + ") is a " + cls +
            " mesh; the sphere domain needs a closed genus-0 surface");
  if (!sphere && m.topology_class() != pb::TOPOLOGICAL_DISK && !(cut_hole && m.topology_class() == pb::TOPOLOGICAL_SPHERE))
    invalid("mesh " + m.name() + " (" + m.id().substr(0, 12) + ") is a " + cls +
            " mesh; the disk domain needs a topological disk" +
            (m.topology_class() == pb::TOPOLOGICAL_SPHERE ? " (set {cut_hole} to open it)" : ""));
}

mesh::Format output_format(const std::string& f) {
  if (f.empty()) return mesh::Format::kObj;
  const auto p = mesh::parse_format(f);
  if (!p || *p == mesh::Format::kStl || *p == mesh::Format::kFreeSurfer)
    invalid("{output_format} '" + f + "' is not one of obj, ply, off");
  return *p;
}

std::string check_map(const pb::MapSpec& s, const MeshLookup& mesh, const SpecLimits& limits) {
  // One weight per vertex of the input file, checked when the job reads it; bounded here.
  if (s.weights_size() > limits.max_vertices)
    invalid(std::to_string(s.weights_size()) + " {weights}; this server takes meshes of at most " +
            std::to_string(limits.max_vertices) + " vertices");
  const jobs::MapRequest r = spec::from_proto(s);
  output_format(s.output_format());
  require_fits(mesh(s.mesh()), r.domain, r.cut_hole);
  return "map";
}

std::string check_distance(const pb::DistanceSpec& s, const MeshLookup& mesh) {
  const jobs::DistanceRequest r = spec::from_proto(s);
  require_fits(mesh(s.a()), r.shape.domain, r.shape.cut_hole);
  require_fits(mesh(s.b()), r.shape.domain, r.shape.cut_hole);
  return "distance";
}

std::string check_matrix(const pb::MatrixSpec& s, const MeshLookup& mesh, const SpecLimits& limits) {
  if (s.meshes_size() > limits.max_matrix_meshes)
    fail(ErrorCode::kResourceExhausted, "a matrix job takes at most " + std::to_string(limits.max_matrix_meshes) +
                                            " meshes");
  const jobs::MatrixRequest r = spec::from_proto(s);
  std::set<std::string> seen;
  for (const std::string& id : s.meshes()) {
    if (!seen.insert(id).second) invalid("mesh " + id + " is given twice");
    require_fits(mesh(id), r.shape.domain, r.shape.cut_hole);
  }
  return "matrix";
}

std::string check_register(const pb::RegisterSpec& s, const MeshLookup& mesh, const SpecLimits& limits) {
  if (s.source_landmarks_size() > limits.max_vertices || s.target_landmarks_size() > limits.max_vertices)
    invalid("more {landmarks} than this server's meshes have vertices");
  const jobs::RegisterRequest r = spec::from_proto(s);
  output_format(s.output_format());
  const pb::Mesh a = mesh(s.source()), b = mesh(s.target());
  require_fits(a, r.domain, r.cut_hole);
  require_fits(b, r.domain, r.cut_hole);
  if (a.topology_class() != b.topology_class() || a.genus() != b.genus() || a.boundary_loops() != b.boundary_loops())
    invalid("meshes " + a.name() + " and " + b.name() + " are of different topology (genus " + std::to_string(a.genus()) +
            " with " + std::to_string(a.boundary_loops()) + " boundary loops, genus " + std::to_string(b.genus()) + " with " +
            std::to_string(b.boundary_loops()) + "): they cannot be registered");
  return "register";
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

// The pictures and the HTML report of a result (issue 24), after its other artifacts: one
// that cannot be drawn costs only itself (logged), never the result.
void add_drawn(JobContext& c, pb::JobResult& out, const std::string& name, const std::string& media,
               const std::function<std::string()>& draw) {
  try {
    *out.add_artifacts() = artifact(c.store, name, media, name, draw());
  } catch (const Error& e) {
    spdlog::warn("job {}: no {}: {}", c.live.job.id(), name, e.what());
  }
}

std::string read_whole(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(ErrorCode::kInternal, "cannot read " + path);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

}  // namespace

std::string check_spec(const pb::SubmitJobRequest& request, const MeshLookup& mesh, const SpecLimits& limits) {
  switch (request.spec_case()) {
    case pb::SubmitJobRequest::kMap: return check_map(request.map(), mesh, limits);
    case pb::SubmitJobRequest::kDistance: return check_distance(request.distance(), mesh);
    case pb::SubmitJobRequest::kMatrix: return check_matrix(request.matrix(), mesh, limits);
    case pb::SubmitJobRequest::kRegistration: return check_register(request.registration(), mesh, limits);
    default: invalid("the job has no spec (map, distance, matrix or registration)");
  }
}

jobs::ProgressSink JobContext::sink() {
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

void JobContext::check() const {
  if (!keep_going()) fail(ErrorCode::kCancelled, "cancelled");
}

mesh::CleanMesh JobContext::load(const std::string& id, pb::Mesh* record) {
  const auto m = store.get_mesh(tenant, id);
  test_hooks::at(test_hooks::Point::kLoadAfterRow);
  const auto bytes = m ? store.read_blob(Store::Blob::kMesh, id) : std::nullopt;
  if (!bytes) invalid("mesh " + id + " was deleted");
  if (record) *record = *m;
  const auto format = mesh::parse_format(m->format());
  return mesh::clean(mesh::read_soup(*bytes, *format));
}

namespace {

pb::JobResult run_map_job(JobContext& c, const pb::MapSpec& s) {
  pb::Mesh rec;
  const mesh::CleanMesh cm = c.load(s.mesh(), &rec);
  const jobs::MapRequest r = spec::from_proto(s);
  const mesh::Format format = output_format(s.output_format());
  const jobs::MapOutcome m = jobs::run_map(cm, rec.name(), r, c.sink());
  c.check();
  pb::JobResult out;
  const std::string ext = mesh::format_name(format);
  const std::string stem = rec.name() + "-" + jobs::domain_name(r.domain) + "-" + jobs::map_method_name(r.method);
  *out.add_artifacts() = artifact(c.store, "mesh", format == mesh::Format::kObj ? "model/obj" : "application/octet-stream",
                                  stem + "." + ext, jobs::map_mesh_bytes(m, format));
  *out.add_artifacts() = artifact(c.store, "report", "application/json", stem + ".json", m.report.dump(2));
  const std::vector<render::MapFigure> rows = render::map_figures(m, rec.name());
  std::optional<render::Picture> png;  // drawn once: the preview and the report's picture
  add_drawn(c, out, "preview.png", "image/png", [&] {
    png = render::default_map_picture(rows, render::Format::kPng);
    return png->bytes;
  });
  add_drawn(c, out, "preview.svg", "image/svg+xml",
            [&] { return render::default_map_picture(rows, render::Format::kSvg).bytes; });
  add_drawn(c, out, "report.html", "text/html",
            [&] { return render::map_report_html(m, rec.name(), png ? &*png : nullptr); });
  out.set_converged(true);
  return out;
}

pb::JobResult run_distance_job(JobContext& c, const pb::DistanceSpec& s) {
  const jobs::DistanceRequest r = spec::from_proto(s);
  pb::Mesh ra, rb;
  const mesh::CleanMesh a = c.load(s.a(), &ra), b = c.load(s.b(), &rb);
  distance::ShapeInput ia = jobs::shape_input(a, ra.name(), ra.name(), r.shape, r.a);
  distance::ShapeInput ib = jobs::shape_input(b, rb.name(), rb.name(), r.shape, r.b);
  if (ia.name == ib.name) ib.name += " (b)";
  jobs::DistanceOutcome d = jobs::run_distance(ia, ib, r.shape, hardware_threads(), c.sink());
  c.check();
  if (!d.result.converged) fail(ErrorCode::kNotConverged, jobs::not_converged_message(d.result));
  d.report["a"] = s.a();
  d.report["b"] = s.b();
  pb::JobResult out;
  *out.add_artifacts() = artifact(c.store, "report", "application/json", "distance.json", d.report.dump(2));
  add_drawn(c, out, "report.html", "text/html", [&] {
    return render::figures_report_html("brenier: distance of " + ra.name() + " and " + rb.name(), d.report);
  });
  out.set_distance(d.result.distance);
  out.set_converged(true);
  return out;
}

// Registration (Alg. 7): the correspondence CSV, the morph and the report.
pb::JobResult run_register_job(JobContext& c, const pb::RegisterSpec& s) {
  const jobs::RegisterRequest r = spec::from_proto(s);
  const mesh::Format format = output_format(s.output_format());
  pb::Mesh ra, rb;
  const mesh::CleanMesh a = c.load(s.source(), &ra), b = c.load(s.target(), &rb);
  jobs::RegisterOutcome reg = jobs::run_register(a, b, ra.name(), rb.name(), r, 1, c.sink());
  c.check();
  reg.report["source"]["id"] = s.source();
  reg.report["target"]["id"] = s.target();
  const std::string stem = ra.name() + "-to-" + rb.name();
  pb::JobResult out;
  *out.add_artifacts() = artifact(c.store, "correspondence", "text/csv", stem + ".csv", jobs::correspondence_csv(reg));
  *out.add_artifacts() = artifact(c.store, "morph", format == mesh::Format::kObj ? "model/obj" : "application/octet-stream",
                                  stem + "." + mesh::format_name(format), mesh::write_mesh_string(reg.morph, format));
  *out.add_artifacts() = artifact(c.store, "report", "application/json", stem + ".json", reg.report.dump(2));
  out.set_converged(true);
  return out;
}

// The tiles of a matrix on the shared pool: every shape once (cached by content hash under
// DATA/shapes, reused by later jobs), then tiles of pairs, each kept in the work directory as
// it finishes so that a run interrupted by a restart redoes only the missing tiles.
std::vector<distance::MatrixTile> local_tiles(JobContext& c, const pb::MatrixSpec& s, const std::string& work) {
  const jobs::MatrixRequest request = spec::from_proto(s);
  const jobs::ShapeRequest& r = request.shape;
  const int n = s.meshes_size();
  std::vector<distance::ShapeInput> in(n);
  c.scheduler.run_group(n, [&](int k) {
    c.check();
    pb::Mesh rec;
    const mesh::CleanMesh cm = c.load(s.meshes(k), &rec);
    in[k] = jobs::shape_input(cm, rec.name(), rec.name(), r,
                              request.markers.empty() ? jobs::DiskMarkers{} : request.markers[k]);
  });
  std::vector<std::string> names(n);
  for (int k = 0; k < n; ++k) names[k] = in[k].name;
  jobs::unique_names(names, {s.meshes().begin(), s.meshes().end()});
  for (int k = 0; k < n; ++k) in[k].name = names[k];
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
  distance::MatrixOptions mo;
  mo.method = r.method;
  mo.wasserstein = jobs::wasserstein_options(r);
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
  return done;
}

// The tiles of a matrix as one Slurm array (slurm.hpp): the work file names the tenant's
// meshes by their blobs on the shared --data volume, with the names and options this server
// would use itself, so that the tiles are the local pool's bit for bit.
std::vector<distance::MatrixTile> slurm_tiles(JobContext& c, const pb::MatrixSpec& s, const std::string& work) {
  jobs::MatrixWork w;
  w.request = spec::from_proto(s);
  w.cache = fs::absolute(c.store.dir() + "/shapes").string();  // the tasks run in other folders
  const int n = s.meshes_size();
  std::vector<std::string> names(n);
  for (int k = 0; k < n; ++k) {
    const auto m = c.store.get_mesh(c.tenant, s.meshes(k));
    if (!m || !c.store.has_blob(Store::Blob::kMesh, s.meshes(k))) invalid("mesh " + s.meshes(k) + " was deleted");
    names[k] = m->name();
    w.shapes.push_back({"", fs::absolute(c.store.blob_path(Store::Blob::kMesh, s.meshes(k))).string(), m->format()});
  }
  jobs::unique_names(names, {s.meshes().begin(), s.meshes().end()});
  for (int k = 0; k < n; ++k) w.shapes[k].name = names[k];
  w.tiles = slurm_tile_count(c.executor.slurm, n * (n - 1) / 2);
  fs::create_directories(w.cache);
  const std::string work_file = work + "/matrix-work.json";
  if (!fs::exists(work_file)) jobs::write_matrix_work(w, work_file);
  else w.tiles = jobs::read_matrix_work(work_file).tiles;  // a run re-attaching keeps the split
  SlurmRunHooks hooks;
  hooks.go = [&c] {
    if (c.live.cancel) return SlurmRunHooks::Go::kCancel;
    return c.live.interrupted ? SlurmRunHooks::Go::kLeave : SlurmRunHooks::Go::kOn;
  };
  hooks.progress = [&c](int done, int total, const std::string& stage) {
    c.sink()(jobs::Progress{stage, static_cast<double>(done) / total, done, 0});
  };
  return run_tiles_on_slurm(c.executor.slurm, c.live.job.id(), fs::absolute(work).string(), w.tiles, hooks);
}

// A matrix job: its tiles from the executor, assembled as `brenier-compute merge` does.
pb::JobResult run_matrix_job(JobContext& c, const pb::MatrixSpec& s) {
  const auto t0 = std::chrono::steady_clock::now();
  const jobs::ShapeRequest r = spec::from_proto(s).shape;
  const int n = s.meshes_size();
  const int pairs = n * (n - 1) / 2;
  const std::string work = c.store.dir() + "/work/" + c.live.job.id();
  fs::create_directories(work);
  std::vector<distance::MatrixTile> done;
  try {
    done = c.executor.kind == Executor::kSlurm ? slurm_tiles(c, s, work) : local_tiles(c, s, work);
  } catch (const Error& e) {
    // Cancelled by its client: nothing of it will be asked for again. (Interrupted by a
    // shutdown, its finished tiles stay for the next run; failed, its logs stay for a look.)
    std::error_code ec;
    if (e.code() == ErrorCode::kCancelled && c.live.cancel) fs::remove_all(work, ec);
    throw;
  }
  const int tiles = static_cast<int>(done.size());
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
                           {"domain", jobs::domain_name(r.domain)},
                           {"shapes", nm},
                           {"meshes", std::vector<std::string>(s.meshes().begin(), s.meshes().end())},
                           {"pairs", pairs},
                           {"tiles", tiles},
                           {"executor", c.executor.kind == Executor::kSlurm ? "slurm" : "local"},
                           {"not_converged", failed},
                           {"seconds", std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()}};
  *out.add_artifacts() = artifact(c.store, "report", "application/json", "matrix.json", report.dump(2));
  const render::MatrixFigure figure{d, nm, {}};
  for (const render::Format f : {render::Format::kPng, render::Format::kSvg})
    add_drawn(c, out, f == render::Format::kPng ? "preview.png" : "preview.svg",
              f == render::Format::kPng ? "image/png" : "image/svg+xml", [&] {
                return render::matrix_picture(figure, f, render::kMatrixPictureWidth, render::kMatrixPictureHeight).bytes;
              });
  add_drawn(c, out, "report.html", "text/html", [&] { return render::matrix_report_html(figure, report); });
  out.set_converged(failed.empty());
  std::error_code ec;
  fs::remove_all(work, ec);
  return out;
}

}  // namespace

pb::JobResult run_spec(JobContext& c, const pb::SubmitJobRequest& spec) {
  switch (spec.spec_case()) {
    case pb::SubmitJobRequest::kMap: return run_map_job(c, spec.map());
    case pb::SubmitJobRequest::kDistance: return run_distance_job(c, spec.distance());
    case pb::SubmitJobRequest::kMatrix: return run_matrix_job(c, spec.matrix());
    case pb::SubmitJobRequest::kRegistration: return run_register_job(c, spec.registration());
    default: invalid("the job has no spec");
  }
}

}  // namespace brenier::server

// brenier: the thin command-line client of brenierd. Exit codes: 0 success, 2 invalid input,
// 3 the job failed, 4 the server is unreachable, 5 the job was cancelled, 1 anything else.
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <nlohmann/json.hpp>

#include "client.hpp"

namespace {

using brenier::client::Client;
using brenier::client::Error;
namespace pb = brenier::v1;

constexpr int kOk = 0, kFailure = 1, kInvalid = 2, kJobFailed = 3, kUnreachable = 4, kCancelled = 5;

struct Global {
  brenier::client::Options options;
  bool json = false;
};

// A mesh argument: an id the server has (64 hex digits, or a 12-digit prefix of one of ours
// is not accepted: ids are exact) or a file to upload.
std::string mesh_id(Client& c, const std::string& arg) {
  if (arg.size() == 64 && arg.find_first_not_of("0123456789abcdef") == std::string::npos &&
      !std::filesystem::exists(arg))
    return arg;
  if (!std::filesystem::exists(arg)) throw Error(grpc::StatusCode::INVALID_ARGUMENT, "no file " + arg);
  return c.upload(arg).id();
}

pb::Domain domain_of(const std::string& d) { return d == "sphere" ? pb::SPHERE : pb::DISK; }
pb::DistanceMethod distance_method(const std::string& m) { return m == "omt-linear" ? pb::OMT_LINEAR : pb::WASSERSTEIN; }

nlohmann::json job_json(const pb::Job& j) {
  nlohmann::json out = {{"id", j.id()},
                        {"kind", j.kind()},
                        {"state", pb::JobState_Name(j.state())},
                        {"stage", j.stage()},
                        {"fraction", j.fraction()},
                        {"attempts", j.attempts()}};
  if (j.has_error()) out["error"] = {{"code", j.error().code()}, {"message", j.error().message()}};
  if (j.state() == pb::SUCCEEDED) {
    out["converged"] = j.result().converged();
    if (j.kind() == "distance") out["distance"] = j.result().distance();
    for (const auto& a : j.result().artifacts())
      out["artifacts"].push_back({{"name", a.name()}, {"size_bytes", a.size_bytes()}, {"filename", a.filename()}});
  }
  return out;
}

// A live progress bar on stderr when it is a terminal; elsewhere a line per stage with
// --progress, nothing otherwise (so that an error stays one line).
bool g_progress_lines = false;
std::function<void(const pb::JobEvent&)> progress_printer(bool quiet) {
  const bool tty = isatty(STDERR_FILENO);
  if (quiet || (!tty && !g_progress_lines)) return {};
  auto last_stage = std::make_shared<std::string>();
  return [tty, last_stage](const pb::JobEvent& e) {
    if (tty) {
      const int width = 30, filled = static_cast<int>(e.fraction() * width + 0.5);
      std::fprintf(stderr, "\r[%-*s] %3d%% %-10s", width, std::string(std::clamp(filled, 0, width), '#').c_str(),
                   static_cast<int>(e.fraction() * 100 + 0.5), e.stage().c_str());
      if (e.iteration() > 0) std::fprintf(stderr, " it %d", e.iteration());
      if (e.residual() > 0) std::fprintf(stderr, " residual %.2e", e.residual());
      std::fprintf(stderr, "\033[K");
      if (e.state() != pb::RUNNING && e.state() != pb::QUEUED) std::fprintf(stderr, "\n");
    } else if (e.stage() != *last_stage) {
      *last_stage = e.stage();
      std::fprintf(stderr, "%s: %s (%d%%)\n", pb::JobState_Name(e.state()).c_str(), e.stage().c_str(),
                   static_cast<int>(e.fraction() * 100 + 0.5));
    }
  };
}

// Meshes as a JSON array or one line each: id, name, vertices, class.
void print_meshes(const std::vector<pb::Mesh>& meshes, bool json) {
  nlohmann::json out = nlohmann::json::array();
  for (const pb::Mesh& m : meshes) {
    if (json)
      out.push_back({{"id", m.id()}, {"name", m.name()}, {"vertices", m.vertices()}, {"faces", m.faces()},
                     {"class", pb::TopologyClass_Name(m.topology_class())}});
    else
      std::printf("%s %s %d vertices %s\n", m.id().c_str(), m.name().c_str(), m.vertices(),
                  pb::TopologyClass_Name(m.topology_class()).c_str());
  }
  if (json) std::cout << out.dump(2) << std::endl;
}

int job_exit(const pb::Job& j) {
  switch (j.state()) {
    case pb::SUCCEEDED: return j.result().converged() ? kOk : kJobFailed;
    case pb::CANCELLED: return kCancelled;
    case pb::FAILED: return j.error().code() == static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT) ? kInvalid : kJobFailed;
    default: return kOk;
  }
}

// Submits, then (unless no_wait) watches with a progress line and returns the final job.
pb::Job run_job(Client& c, const Global& g, const pb::SubmitJobRequest& r, bool no_wait, bool* done) {
  pb::Job j = c.submit(r);
  *done = false;
  if (no_wait) return j;
  j = c.watch(j.id(), progress_printer(g.json));
  *done = true;
  if (j.state() == pb::FAILED) {
    const bool input = j.error().code() == static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT) ||
                       j.error().code() == static_cast<int>(grpc::StatusCode::NOT_FOUND);
    throw Error(input ? grpc::StatusCode::INVALID_ARGUMENT : grpc::StatusCode::ABORTED,
                "job " + j.id() + " failed: " + j.error().message());
  }
  return j;
}

int print_submitted(const Global& g, const pb::Job& j) {
  if (g.json)
    std::cout << nlohmann::json{{"id", j.id()}, {"state", pb::JobState_Name(j.state())}}.dump() << std::endl;
  else
    std::printf("%s\n", j.id().c_str());
  return kOk;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"brenier: client of brenierd (conformal and area-preserving maps, shape distances)"};
  app.require_subcommand(1);
  Global g;
  app.add_option("--server", g.options.server, "HOST:PORT of brenierd (default: $BRENIER_SERVER, else 127.0.0.1:50051)");
  app.add_option("--token", g.options.token, "bearer token (default: $BRENIER_TOKEN)");
  app.add_option("--tls-ca", g.options.tls_ca_file, "PEM CA of the server's certificate: use TLS");
  app.add_flag("--tls", g.options.tls, "use TLS with the system's CAs");
  app.add_option("--tls-cert", g.options.tls_cert_file, "client certificate (PEM) for servers that require one");
  app.add_option("--tls-key", g.options.tls_key_file, "client key (PEM)");
  app.add_flag("--json", g.json, "machine-readable output");
  app.add_flag("--progress", g_progress_lines, "report each stage on stderr even when it is not a terminal");

  std::function<int(Client&)> action;

  std::vector<std::string> files;
  auto* up = app.add_subcommand("upload", "upload mesh files; prints their ids");
  up->add_option("files", files, "mesh files")->required();
  up->callback([&] {
    action = [&](Client& c) {
      std::vector<pb::Mesh> uploaded;
      for (const std::string& f : files) uploaded.push_back(c.upload(f));
      print_meshes(uploaded, g.json);
      return kOk;
    };
  });

  struct MapArgs {
    std::string mesh, domain = "disk", method = "conformal", output, report, weights, format;
    std::vector<int> markers;
    double t = 0, tolerance = 0;
    int hole_vertex = -1, max_iterations = 0;
    bool cut = false, no_wait = false, allow_flips = false;
  } m;
  auto* map = app.add_subcommand("map", "map a mesh (file or id) onto the unit disk or sphere");
  map->add_option("mesh", m.mesh, "mesh file or id")->required();
  map->add_option("--domain", m.domain, "disk or sphere")->check(CLI::IsMember({"disk", "sphere"}));
  map->add_option("--method", m.method, "conformal or area-preserving")
      ->check(CLI::IsMember({"conformal", "area-preserving"}));
  map->add_option("-o,--output", m.output, "write the mapped mesh here (.obj, .ply, .off)");
  map->add_option("--report", m.report, "write the JSON report here");
  map->add_option("--t", m.t, "area-preserving: phi_t, 0 area-preserving .. 1 conformal")->check(CLI::Range(0.0, 1.0));
  map->add_option("--weights", m.weights, "area-preserving: file of one positive weight per input vertex");
  map->add_option("--markers", m.markers, "disk: center,boundary; sphere: v0,v1,vinf")->delimiter(',');
  map->add_flag("--cut-hole", m.cut, "disk: open a closed genus-0 mesh");
  map->add_option("--hole-vertex", m.hole_vertex, "with --cut-hole: the vertex whose star is removed")
      ->check(CLI::NonNegativeNumber);
  map->add_option("--max-iterations", m.max_iterations, "Newton iterations")->check(CLI::PositiveNumber);
  map->add_option("--tolerance", m.tolerance, "solver tolerance (default: the method's)")->check(CLI::PositiveNumber);
  map->add_flag("--allow-flips", m.allow_flips, "return a map even if it folds faces");
  map->add_flag("--no-wait", m.no_wait, "print the job and return at once");
  map->callback([&] {
    action = [&](Client& c) {
      pb::SubmitJobRequest r;
      pb::MapSpec* s = r.mutable_map();
      s->set_mesh(mesh_id(c, m.mesh));
      s->set_domain(domain_of(m.domain));
      s->set_method(m.method == "area-preserving" ? pb::AREA_PRESERVING : pb::CONFORMAL);
      s->set_t(m.t);
      s->set_cut_hole(m.cut);
      s->set_tolerance(m.tolerance);
      s->set_max_iterations(m.max_iterations);
      s->set_allow_flips(m.allow_flips);
      if (m.hole_vertex >= 0) {
        s->set_has_hole_vertex(true);
        s->set_hole_vertex(m.hole_vertex);
      }
      for (int v : m.markers) s->add_markers(v);
      if (!m.output.empty()) {
        const std::string ext = std::filesystem::path(m.output).extension().string();
        s->set_output_format(ext.empty() ? "obj" : ext.substr(1));
      }
      if (!m.weights.empty()) {
        std::ifstream in(m.weights);
        if (!in) throw Error(grpc::StatusCode::INVALID_ARGUMENT, "cannot read the weights file " + m.weights);
        double w;
        while (in >> w) s->add_weights(w);
        if (!in.eof()) throw Error(grpc::StatusCode::INVALID_ARGUMENT, m.weights + ": weights must be numbers");
      }
      bool done = false;
      const pb::Job j = run_job(c, g, r, m.no_wait, &done);
      if (!done) return print_submitted(g, j);
      if (j.state() != pb::SUCCEEDED) return job_exit(j);
      if (!m.output.empty()) c.download(j.id(), m.output, "mesh");
      const std::string report = c.fetch(j.id(), "report");
      if (!m.report.empty()) std::ofstream(m.report) << report;
      if (g.json) {
        nlohmann::json out = nlohmann::json::parse(report);
        out["job"] = j.id();
        std::cout << out.dump(2) << std::endl;
      } else {
        const auto q = nlohmann::json::parse(report)["quality"];
        std::printf("job %s: %s; flipped faces %d, angle distortion mean %.3f deg, |log area ratio| mean %.3f\n",
                    j.id().c_str(), m.output.empty() ? "done" : ("wrote " + m.output).c_str(),
                    q["flipped_faces"].get<int>(), q["angle_distortion_deg"]["mean"].get<double>(),
                    q["area_distortion_log"]["mean_abs"].get<double>());
      }
      return kOk;
    };
  });

  // Options of the Wasserstein transports, shared by distance and matrix.
  struct TransportArgs {
    double tolerance = 0;
    std::optional<double> cost_tolerance;
    bool refine = false, raw = false;
    void add_to(CLI::App* cmd) {
      cmd->add_option("--tolerance", tolerance, "wasserstein: the transports' max relative cell-mass error (default 1e-3)")
          ->check(CLI::PositiveNumber);
      cmd->add_option("--cost-tolerance", cost_tolerance,
                      "wasserstein: or stop each transport once its cost is known to this relative accuracy "
                      "(default 1e-6, 0: off)")
          ->check(CLI::Range(0.0, 1.0));
      cmd->add_flag("--refine-rotation", refine, "wasserstein: refine the best turn by exact evaluations");
      cmd->add_flag("--raw", raw, "wasserstein: eq. 3.31 as it stands, without removing the quantization bias");
    }
    void set(pb::WassersteinOptions* w) const {
      w->set_tolerance(tolerance);
      if (cost_tolerance) w->set_cost_tolerance(*cost_tolerance > 0 ? *cost_tolerance : -1.0);
      w->set_refine_rotation(refine);
      w->set_raw(raw);
    }
  };
  struct DistArgs {
    std::string a, b, method = "wasserstein", domain = "disk";
    int center_a = -1, boundary_a = -1, center_b = -1, boundary_b = -1;
    bool cut = false, no_wait = false;
    TransportArgs transport;
  } d;
  auto* dist = app.add_subcommand("distance", "shape distance between two meshes (files or ids)");
  dist->add_option("a", d.a, "first mesh")->required();
  dist->add_option("b", d.b, "second mesh")->required();
  dist->add_option("--method", d.method, "wasserstein or omt-linear")->check(CLI::IsMember({"wasserstein", "omt-linear"}));
  dist->add_option("--domain", d.domain, "disk or sphere")->check(CLI::IsMember({"disk", "sphere"}));
  dist->add_flag("--cut-hole", d.cut, "open closed genus-0 meshes onto the disk");
  dist->add_flag("--no-wait", d.no_wait, "print the job and return at once");
  dist->add_option("--center-a", d.center_a, "interior marker of the first mesh (sent to 0)");
  dist->add_option("--boundary-a", d.boundary_a, "boundary marker of the first mesh (sent to 1)");
  dist->add_option("--center-b", d.center_b, "interior marker of the second mesh");
  dist->add_option("--boundary-b", d.boundary_b, "boundary marker of the second mesh");
  d.transport.add_to(dist);
  dist->callback([&] {
    action = [&](Client& c) {
      pb::SubmitJobRequest r;
      pb::DistanceSpec* s = r.mutable_distance();
      s->set_a(mesh_id(c, d.a));
      s->set_b(mesh_id(c, d.b));
      s->set_method(distance_method(d.method));
      s->set_domain(domain_of(d.domain));
      s->set_cut_hole(d.cut);
      if (d.center_a >= 0 || d.boundary_a >= 0 || d.center_b >= 0 || d.boundary_b >= 0) {
        s->mutable_markers_a()->set_center(d.center_a);
        s->mutable_markers_a()->set_boundary(d.boundary_a);
        s->mutable_markers_b()->set_center(d.center_b);
        s->mutable_markers_b()->set_boundary(d.boundary_b);
      }
      d.transport.set(s->mutable_wasserstein());
      bool done = false;
      const pb::Job j = run_job(c, g, r, d.no_wait, &done);
      if (!done) return print_submitted(g, j);
      if (j.state() != pb::SUCCEEDED) return job_exit(j);
      if (g.json) {
        nlohmann::json out = nlohmann::json::parse(c.fetch(j.id(), "report"));
        out["job"] = j.id();
        std::cout << out.dump(2) << std::endl;
      } else {
        std::printf("%s %s %s: %.10g\n", d.method.c_str(), d.a.c_str(), d.b.c_str(), j.result().distance());
      }
      return kOk;
    };
  });

  struct MatrixArgs {
    std::vector<std::string> meshes;
    std::string output, method = "wasserstein", domain = "disk", report, markers;
    bool cut = false, no_wait = false;
    TransportArgs transport;
  } x;
  auto* mat = app.add_subcommand("matrix", "distance matrix over meshes (files or ids)");
  mat->add_option("meshes", x.meshes, "meshes")->required();
  mat->add_option("-o,--output", x.output, "matrix file: .csv or .npy");
  mat->add_option("--report", x.report, "write the JSON report here");
  mat->add_option("--method", x.method, "wasserstein or omt-linear")->check(CLI::IsMember({"wasserstein", "omt-linear"}));
  mat->add_option("--domain", x.domain, "disk or sphere")->check(CLI::IsMember({"disk", "sphere"}));
  mat->add_flag("--cut-hole", x.cut, "open closed genus-0 meshes onto the disk");
  mat->add_flag("--no-wait", x.no_wait, "print the job and return at once");
  mat->add_option("--markers", x.markers, "file of lines file,center_vertex,boundary_vertex (every mesh)");
  x.transport.add_to(mat);
  mat->callback([&] {
    action = [&](Client& c) {
      if (x.output.empty() && !x.no_wait) throw Error(grpc::StatusCode::INVALID_ARGUMENT, "give -o D.csv or D.npy");
      pb::SubmitJobRequest r;
      pb::MatrixSpec* s = r.mutable_matrix();
      for (const std::string& f : x.meshes) s->add_meshes(mesh_id(c, f));
      if (!x.markers.empty()) {
        std::ifstream in(x.markers);
        if (!in) throw Error(grpc::StatusCode::INVALID_ARGUMENT, "cannot read the markers file " + x.markers);
        std::map<std::string, std::pair<int, int>> byname;
        std::string line;
        for (int n = 1; std::getline(in, line); ++n) {
          if (line.empty() || line[0] == '#') continue;
          const size_t c1 = line.find(','), c2 = line.find(',', c1 + 1);
          int center = -1, boundary = -1;
          if (c1 == std::string::npos || c2 == std::string::npos ||
              std::sscanf(line.c_str() + c1 + 1, "%d", &center) != 1 || std::sscanf(line.c_str() + c2 + 1, "%d", &boundary) != 1)
            throw Error(grpc::StatusCode::INVALID_ARGUMENT, x.markers + ":" + std::to_string(n) +
                                                                ": expected file,center_vertex,boundary_vertex");
          byname[line.substr(0, c1)] = {center, boundary};
        }
        for (const std::string& f : x.meshes) {
          auto it = byname.find(f);
          if (it == byname.end()) it = byname.find(std::filesystem::path(f).stem().string());
          if (it == byname.end()) throw Error(grpc::StatusCode::INVALID_ARGUMENT, x.markers + " has no markers for " + f);
          pb::DiskMarkers* mk = s->add_markers();
          mk->set_center(it->second.first);
          mk->set_boundary(it->second.second);
        }
      }
      x.transport.set(s->mutable_wasserstein());
      s->set_method(distance_method(x.method));
      s->set_domain(domain_of(x.domain));
      s->set_cut_hole(x.cut);
      bool done = false;
      const pb::Job j = run_job(c, g, r, x.no_wait, &done);
      if (!done) return print_submitted(g, j);
      if (j.state() != pb::SUCCEEDED) return job_exit(j);
      const bool npy = std::filesystem::path(x.output).extension() == ".npy";
      c.download(j.id(), x.output, npy ? "matrix.npy" : "matrix");
      const std::string report = c.fetch(j.id(), "report");
      if (!x.report.empty()) std::ofstream(x.report) << report;
      const auto rep = nlohmann::json::parse(report);
      if (g.json) {
        std::cout << nlohmann::json{{"job", j.id()}, {"output", x.output}, {"report", rep}}.dump(2) << std::endl;
      } else {
        std::printf("job %s: wrote %s (%zu shapes, %s)\n", j.id().c_str(), x.output.c_str(), rep["shapes"].size(),
                    x.method.c_str());
        if (!rep["not_converged"].empty())
          std::fprintf(stderr, "brenier: %zu pairs did not converge (written as nan)\n", rep["not_converged"].size());
      }
      return job_exit(j);
    };
  });

  auto* meshes = app.add_subcommand("meshes", "list your meshes");
  meshes->callback([&] {
    action = [&](Client& c) {
      print_meshes(c.list_meshes(), g.json);
      return kOk;
    };
  });
  std::string delete_id;
  auto* del = app.add_subcommand("delete", "delete one of your meshes");
  del->add_option("id", delete_id, "mesh id")->required();
  del->callback([&] {
    action = [&](Client& c) {
      c.delete_mesh(delete_id);
      return kOk;
    };
  });

  std::string state;
  auto* jobs = app.add_subcommand("jobs", "list your jobs");
  jobs->add_option("--state", state, "QUEUED, RUNNING, SUCCEEDED, FAILED or CANCELLED");
  jobs->callback([&] {
    action = [&](Client& c) {
      pb::JobState s = pb::JOB_STATE_UNSPECIFIED;
      if (!state.empty() && !pb::JobState_Parse(state, &s))
        throw Error(grpc::StatusCode::INVALID_ARGUMENT, "unknown state " + state);
      nlohmann::json out = nlohmann::json::array();
      for (const pb::Job& j : c.list_jobs(s)) {
        if (g.json)
          out.push_back(job_json(j));
        else
          std::printf("%s %-8s %-10s %3d%% %s\n", j.id().c_str(), j.kind().c_str(), pb::JobState_Name(j.state()).c_str(),
                      static_cast<int>(j.fraction() * 100 + 0.5), j.has_error() ? j.error().message().c_str() : j.stage().c_str());
      }
      if (g.json) std::cout << out.dump(2) << std::endl;
      return kOk;
    };
  });

  std::string job_id;
  auto* watch = app.add_subcommand("watch", "follow a job's progress until it ends");
  watch->add_option("id", job_id, "job id")->required();
  watch->callback([&] {
    action = [&](Client& c) {
      std::function<void(const pb::JobEvent&)> print = progress_printer(false);
      if (g.json)
        print = [](const pb::JobEvent& e) {
          std::cout << nlohmann::json{{"state", pb::JobState_Name(e.state())}, {"stage", e.stage()},
                                      {"fraction", e.fraction()}, {"iteration", e.iteration()},
                                      {"residual", e.residual()}, {"message", e.message()}}
                           .dump()
                    << std::endl;
        };
      const pb::Job j = c.watch(job_id, print);
      if (!g.json) std::printf("%s %s\n", j.id().c_str(), pb::JobState_Name(j.state()).c_str());
      if (j.has_error()) std::fprintf(stderr, "brenier: %s\n", j.error().message().c_str());
      return job_exit(j);
    };
  });

  std::string out_path, artifact;
  auto* result = app.add_subcommand("result", "download a finished job's artifact");
  result->add_option("id", job_id, "job id")->required();
  result->add_option("-o,--output", out_path, "file to write")->required();
  result->add_option("--artifact", artifact, "mesh, report, matrix, matrix.npy (default: the main one)");
  result->callback([&] {
    action = [&](Client& c) {
      const pb::Artifact a = c.download(job_id, out_path, artifact);
      if (g.json)
        std::cout << nlohmann::json{{"output", out_path}, {"artifact", a.name()}, {"size_bytes", a.size_bytes()}}.dump()
                  << std::endl;
      else
        std::printf("wrote %s (%s, %lld bytes)\n", out_path.c_str(), a.name().c_str(), static_cast<long long>(a.size_bytes()));
      return kOk;
    };
  });

  auto* cancel = app.add_subcommand("cancel", "cancel a queued or running job");
  cancel->add_option("id", job_id, "job id")->required();
  cancel->callback([&] {
    action = [&](Client& c) {
      const pb::Job j = c.cancel(job_id);
      if (g.json)
        std::cout << job_json(j).dump(2) << std::endl;
      else
        std::printf("%s %s\n", j.id().c_str(), pb::JobState_Name(j.state()).c_str());
      return kOk;
    };
  });

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "brenier: usage: %s\n", e.what());
    return kInvalid;
  }
  if (g.options.token.empty())
    if (const char* t = std::getenv("BRENIER_TOKEN")) g.options.token = t;
  try {
    Client c(g.options);
    return action(c);
  } catch (const Error& e) {
    std::fprintf(stderr, "brenier: %s\n", e.what());
    switch (e.code()) {
      case grpc::StatusCode::UNAVAILABLE:
      case grpc::StatusCode::DEADLINE_EXCEEDED: return kUnreachable;
      case grpc::StatusCode::ABORTED: return kJobFailed;
      case grpc::StatusCode::CANCELLED: return kCancelled;
      case grpc::StatusCode::INTERNAL:
      case grpc::StatusCode::UNKNOWN:
      case grpc::StatusCode::DATA_LOSS: return kFailure;
      default: return kInvalid;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "brenier: %s\n", e.what());
    return kFailure;
  }
}

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
#include "common/error.hpp"
#include "request_flags.hpp"
#include "spec.hpp"

namespace {

using brenier::client::Client;
using brenier::client::Error;
namespace pb = brenier::v1;

constexpr int kOk = 0, kFailure = 1, kInvalid = 2, kJobFailed = 3, kUnreachable = 4, kCancelled = 5;

struct Global {
  brenier::client::Options options;
  bool json = false;
};
// What a subcommand runs once CLI11 has parsed its options; returns the exit code.
using Action = std::function<int(Client&)>;

// A mesh argument: an id the server has (64 hex digits, or a 12-digit prefix of one of ours
// is not accepted: ids are exact) or a file to upload.
std::string mesh_id(Client& c, const std::string& arg) {
  if (arg.size() == 64 && arg.find_first_not_of("0123456789abcdef") == std::string::npos &&
      !std::filesystem::exists(arg))
    return arg;
  if (!std::filesystem::exists(arg)) throw Error(grpc::StatusCode::INVALID_ARGUMENT, "no file " + arg);
  return c.upload(arg).id();
}

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



// The job's report printed as JSON with the job's id, or handed to `summary`.
void print_report(const Global& g, const pb::Job& j, const std::string& report,
                  const std::function<void(const nlohmann::json&)>& summary) {
  nlohmann::json out = nlohmann::json::parse(report);
  if (g.json) {
    out["job"] = j.id();
    std::cout << out.dump(2) << std::endl;
  } else {
    summary(out);
  }
}

void add_upload(CLI::App& app, const Global& g, Action& action) {
  auto files = std::make_shared<std::vector<std::string>>();
  auto* cmd = app.add_subcommand("upload", "upload mesh files; prints their ids");
  cmd->add_option("files", *files, "mesh files")->required();
  cmd->callback([&g, &action, files] {
    action = [&g, files](Client& c) {
      std::vector<pb::Mesh> uploaded;
      for (const std::string& f : *files) uploaded.push_back(c.upload(f));
      print_meshes(uploaded, g.json);
      return kOk;
    };
  });
}

struct MapArgs {
  std::string mesh, output, report;
  brenier::options::MapFlags flags;
  bool no_wait = false;
};

int run_map(Client& c, const Global& g, const MapArgs& m) {
  pb::SubmitJobRequest r;
  pb::MapSpec* s = r.mutable_map();
  brenier::spec::to_proto(m.flags.resolve(), s);
  s->set_mesh(mesh_id(c, m.mesh));
  if (!m.output.empty()) {
    const std::string ext = std::filesystem::path(m.output).extension().string();
    s->set_output_format(ext.empty() ? "obj" : ext.substr(1));
  }
  bool done = false;
  const pb::Job j = run_job(c, g, r, m.no_wait, &done);
  if (!done) return print_submitted(g, j);
  if (j.state() != pb::SUCCEEDED) return job_exit(j);
  if (!m.output.empty()) c.download(j.id(), m.output, "mesh");
  const std::string report = c.fetch(j.id(), "report");
  if (!m.report.empty()) std::ofstream(m.report) << report;
  print_report(g, j, report, [&](const nlohmann::json& rep) {
    const auto& q = rep["quality"];
    std::printf("job %s: %s; flipped faces %d, angle distortion mean %.3f deg, |log area ratio| mean %.3f\n",
                j.id().c_str(), m.output.empty() ? "done" : ("wrote " + m.output).c_str(), q["flipped_faces"].get<int>(),
                q["angle_distortion_deg"]["mean"].get<double>(), q["area_distortion_log"]["mean_abs"].get<double>());
  });
  return kOk;
}

void add_map(CLI::App& app, const Global& g, Action& action) {
  auto m = std::make_shared<MapArgs>();
  auto* cmd = app.add_subcommand("map", "map a mesh (file or id) onto the unit disk or sphere");
  cmd->add_option("mesh", m->mesh, "mesh file or id")->required();
  m->flags.add_to(cmd);
  cmd->add_option("-o,--output", m->output, "write the mapped mesh here (.obj, .ply, .off)");
  cmd->add_option("--report", m->report, "write the JSON report here");
  cmd->add_flag("--no-wait", m->no_wait, "print the job and return at once");
  cmd->callback([&g, &action, m] { action = [&g, m](Client& c) { return run_map(c, g, *m); }; });
}

struct RegisterArgs {
  std::string source, target, output, morph, report;
  brenier::options::RegisterFlags flags;
  bool no_wait = false;
};

int run_register(Client& c, const Global& g, const RegisterArgs& a) {
  pb::SubmitJobRequest r;
  pb::RegisterSpec* s = r.mutable_registration();
  brenier::spec::to_proto(a.flags.resolve(), s);
  s->set_source(mesh_id(c, a.source));
  s->set_target(mesh_id(c, a.target));
  if (!a.morph.empty()) {
    const std::string ext = std::filesystem::path(a.morph).extension().string();
    s->set_output_format(ext.empty() ? "obj" : ext.substr(1));
  }
  bool done = false;
  const pb::Job j = run_job(c, g, r, a.no_wait, &done);
  if (!done) return print_submitted(g, j);
  if (j.state() != pb::SUCCEEDED) return job_exit(j);
  if (!a.output.empty()) c.download(j.id(), a.output, "correspondence");
  if (!a.morph.empty()) c.download(j.id(), a.morph, "morph");
  const std::string report = c.fetch(j.id(), "report");
  if (!a.report.empty()) std::ofstream(a.report) << report;
  print_report(g, j, report, [&](const nlohmann::json& rep) {
    std::printf("job %s: %s; %d domain folds, %d flipped morph faces\n", j.id().c_str(),
                a.output.empty() ? "done" : ("wrote " + a.output).c_str(), rep["domain_folded_faces"].get<int>(),
                rep["morph_flipped_faces"].get<int>());
  });
  return kOk;
}

void add_register(CLI::App& app, const Global& g, Action& action) {
  auto a = std::make_shared<RegisterArgs>();
  auto* cmd = app.add_subcommand("register", "register a mesh onto another (Alg. 7; files or ids)");
  cmd->add_option("source", a->source, "source mesh file or id")->required();
  cmd->add_option("target", a->target, "target mesh file or id")->required();
  a->flags.add_to(cmd);
  cmd->add_option("-o,--output", a->output, "write the correspondence CSV here");
  cmd->add_option("--morph", a->morph, "write the source placed on the target here (.obj, .ply, .off)");
  cmd->add_option("--report", a->report, "write the JSON report here");
  cmd->add_flag("--no-wait", a->no_wait, "print the job and return at once");
  cmd->callback([&g, &action, a] { action = [&g, a](Client& c) { return run_register(c, g, *a); }; });
}

struct DistanceArgs {
  std::string a, b;
  brenier::options::DistanceFlags flags;
  bool no_wait = false;
};

int run_distance(Client& c, const Global& g, const DistanceArgs& d) {
  pb::SubmitJobRequest r;
  pb::DistanceSpec* s = r.mutable_distance();
  const brenier::jobs::DistanceRequest request = d.flags.resolve();
  brenier::spec::to_proto(request, s);
  s->set_a(mesh_id(c, d.a));
  s->set_b(mesh_id(c, d.b));
  bool done = false;
  const pb::Job j = run_job(c, g, r, d.no_wait, &done);
  if (!done) return print_submitted(g, j);
  if (j.state() != pb::SUCCEEDED) return job_exit(j);
  print_report(g, j, c.fetch(j.id(), "report"), [&](const nlohmann::json&) {
    std::printf("%s %s %s: %.10g\n", brenier::distance::method_name(request.shape.method), d.a.c_str(), d.b.c_str(),
                j.result().distance());
  });
  return kOk;
}

void add_distance(CLI::App& app, const Global& g, Action& action) {
  auto d = std::make_shared<DistanceArgs>();
  auto* cmd = app.add_subcommand("distance", "shape distance between two meshes (files or ids)");
  cmd->add_option("a", d->a, "first mesh")->required();
  cmd->add_option("b", d->b, "second mesh")->required();
  d->flags.add_to(cmd);
  cmd->add_flag("--no-wait", d->no_wait, "print the job and return at once");
  cmd->callback([&g, &action, d] { action = [&g, d](Client& c) { return run_distance(c, g, *d); }; });
}

struct MatrixArgs {
  std::vector<std::string> meshes;
  std::string output, report;
  brenier::options::MatrixFlags flags;
  bool no_wait = false;
};

int run_matrix(Client& c, const Global& g, const MatrixArgs& x) {
  if (x.output.empty() && !x.no_wait) throw Error(grpc::StatusCode::INVALID_ARGUMENT, "give -o D.csv or D.npy");
  pb::SubmitJobRequest r;
  pb::MatrixSpec* s = r.mutable_matrix();
  const brenier::jobs::MatrixRequest request = x.flags.resolve(x.meshes);
  brenier::spec::to_proto(request, s);
  for (const std::string& f : x.meshes) s->add_meshes(mesh_id(c, f));
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
                brenier::distance::method_name(request.shape.method));
    if (!rep["not_converged"].empty())
      std::fprintf(stderr, "brenier: %zu pairs did not converge (written as nan)\n", rep["not_converged"].size());
  }
  return job_exit(j);
}

void add_matrix(CLI::App& app, const Global& g, Action& action) {
  auto x = std::make_shared<MatrixArgs>();
  auto* cmd = app.add_subcommand("matrix", "distance matrix over meshes (files or ids)");
  cmd->add_option("meshes", x->meshes, "meshes")->required();
  cmd->add_option("-o,--output", x->output, "matrix file: .csv or .npy");
  cmd->add_option("--report", x->report, "write the JSON report here");
  x->flags.add_to(cmd);
  cmd->add_flag("--no-wait", x->no_wait, "print the job and return at once");
  cmd->callback([&g, &action, x] { action = [&g, x](Client& c) { return run_matrix(c, g, *x); }; });
}

// meshes, delete: the tenant's meshes.
void add_mesh_commands(CLI::App& app, const Global& g, Action& action) {
  auto* meshes = app.add_subcommand("meshes", "list your meshes");
  meshes->callback([&g, &action] {
    action = [&g](Client& c) {
      print_meshes(c.list_meshes(), g.json);
      return kOk;
    };
  });
  auto id = std::make_shared<std::string>();
  auto* del = app.add_subcommand("delete", "delete one of your meshes");
  del->add_option("id", *id, "mesh id")->required();
  del->callback([&action, id] {
    action = [id](Client& c) {
      c.delete_mesh(*id);
      return kOk;
    };
  });
}

int list_jobs(Client& c, const Global& g, const std::string& state) {
  pb::JobState s = pb::JOB_STATE_UNSPECIFIED;
  if (!state.empty() && !pb::JobState_Parse(state, &s)) throw Error(grpc::StatusCode::INVALID_ARGUMENT, "unknown state " + state);
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
}

int watch_job(Client& c, const Global& g, const std::string& id) {
  std::function<void(const pb::JobEvent&)> print = progress_printer(false);
  if (g.json)
    print = [](const pb::JobEvent& e) {
      std::cout << nlohmann::json{{"state", pb::JobState_Name(e.state())}, {"stage", e.stage()},
                                  {"fraction", e.fraction()}, {"iteration", e.iteration()},
                                  {"residual", e.residual()}, {"message", e.message()}}
                       .dump()
                << std::endl;
    };
  const pb::Job j = c.watch(id, print);
  if (!g.json) std::printf("%s %s\n", j.id().c_str(), pb::JobState_Name(j.state()).c_str());
  if (j.has_error()) std::fprintf(stderr, "brenier: %s\n", j.error().message().c_str());
  return job_exit(j);
}

int download_result(Client& c, const Global& g, const std::string& id, const std::string& out_path,
                    const std::string& artifact) {
  const pb::Artifact a = c.download(id, out_path, artifact);
  if (g.json)
    std::cout << nlohmann::json{{"output", out_path}, {"artifact", a.name()}, {"size_bytes", a.size_bytes()}}.dump()
              << std::endl;
  else
    std::printf("wrote %s (%s, %lld bytes)\n", out_path.c_str(), a.name().c_str(), static_cast<long long>(a.size_bytes()));
  return kOk;
}

// jobs, watch, result, cancel: the tenant's jobs.
void add_job_commands(CLI::App& app, const Global& g, Action& action) {
  struct Args {
    std::string state, id, output, artifact;
  };
  auto a = std::make_shared<Args>();
  auto* jobs = app.add_subcommand("jobs", "list your jobs");
  jobs->add_option("--state", a->state, "QUEUED, RUNNING, SUCCEEDED, FAILED or CANCELLED");
  jobs->callback([&g, &action, a] { action = [&g, a](Client& c) { return list_jobs(c, g, a->state); }; });

  auto* watch = app.add_subcommand("watch", "follow a job's progress until it ends");
  watch->add_option("id", a->id, "job id")->required();
  watch->callback([&g, &action, a] { action = [&g, a](Client& c) { return watch_job(c, g, a->id); }; });

  auto* result = app.add_subcommand("result", "download a finished job's artifact");
  result->add_option("id", a->id, "job id")->required();
  result->add_option("-o,--output", a->output, "file to write")->required();
  result->add_option("--artifact", a->artifact, "mesh, report, matrix, matrix.npy, preview.png, preview.svg (default: the main one)");
  result->callback([&g, &action, a] {
    action = [&g, a](Client& c) { return download_result(c, g, a->id, a->output, a->artifact); };
  });

  auto* cancel = app.add_subcommand("cancel", "cancel a queued or running job");
  cancel->add_option("id", a->id, "job id")->required();
  cancel->callback([&g, &action, a] {
    action = [&g, a](Client& c) {
      const pb::Job j = c.cancel(a->id);
      if (g.json)
        std::cout << job_json(j).dump(2) << std::endl;
      else
        std::printf("%s %s\n", j.id().c_str(), pb::JobState_Name(j.state()).c_str());
      return kOk;
    };
  });
}

// health: the server's grpc.health.v1 status (a container's HEALTHCHECK, a probe by hand).
void add_health(CLI::App& app, const Global& g, Action& action) {
  auto service = std::make_shared<std::string>();
  auto* cmd = app.add_subcommand("health", "ask the server's health (exit 0 when SERVING)");
  cmd->add_option("--service", *service, "a service's status instead of the whole server's");
  cmd->callback([&g, &action, service] {
    action = [&g, service](Client& c) {
      const std::string status = c.health(*service);
      if (g.json)
        std::cout << nlohmann::json{{"server", c.server()}, {"status", status}}.dump() << std::endl;
      else
        std::printf("%s\n", status.c_str());
      return status == "SERVING" ? kOk : kFailure;
    };
  });
}

// The exit code of an error: the server's status, or one of our own request checks.
int error_exit(grpc::StatusCode code) {
  switch (code) {
    case grpc::StatusCode::UNAVAILABLE:
    case grpc::StatusCode::DEADLINE_EXCEEDED: return kUnreachable;
    case grpc::StatusCode::ABORTED: return kJobFailed;
    case grpc::StatusCode::CANCELLED: return kCancelled;
    case grpc::StatusCode::INTERNAL:
    case grpc::StatusCode::UNKNOWN:
    case grpc::StatusCode::DATA_LOSS: return kFailure;
    default: return kInvalid;
  }
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
  Action action;
  add_upload(app, g, action);
  add_map(app, g, action);
  add_register(app, g, action);
  add_distance(app, g, action);
  add_matrix(app, g, action);
  add_mesh_commands(app, g, action);
  add_job_commands(app, g, action);
  add_health(app, g, action);
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
    return error_exit(e.code());
  } catch (const brenier::Error& e) {  // a request our flags describe but cannot be sent
    std::fprintf(stderr, "brenier: %s\n", brenier::name_options(e.what(), brenier::OptionStyle::kFlag).c_str());
    return e.code() == brenier::ErrorCode::kInvalidArgument ? kInvalid : kFailure;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "brenier: %s\n", e.what());
    return kFailure;
  }
}

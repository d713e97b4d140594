// brenierd: the gRPC server (DESIGN.md "Service"). Flags may also come from a config file
// (--config FILE, TOML or INI, keys as the long flag names).
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <atomic>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <cerrno>
#include <fcntl.h>
#include <pthread.h>
#include <unistd.h>

#include "auth.hpp"
#include "command.hpp"
#include "common/error.hpp"
#include "common/parallel.hpp"
#include "process.hpp"
#include "manager.hpp"
#include "service.hpp"

namespace {

std::string read_file(const std::string& path, const char* what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) brenier::invalid(std::string("cannot read the ") + what + " file " + path);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// Stopping on SIGTERM or SIGINT. install_stop_handlers() runs first in main(), before any
// thread of ours exists, and blocks both signals there: every thread started from then on
// (gRPC's, the workers, OpenMP's) inherits the mask, and the waiter thread takes them with
// sigtimedwait(). No handler has to run on a thread that is busy elsewhere: under
// ThreadSanitizer, which defers a handler until its thread next enters the runtime, a SIGTERM
// taken by a thread parked in a library call was never handled. A library may still start
// threads before main where the signals are not blocked (OpenBLAS does unless
// OPENBLAS_NUM_THREADS=1, which the re-exec in main sets): for those a handler writes the
// signal into a pipe that the waiter also looks at (write() is async-signal-safe).
int stop_pipe[2] = {-1, -1};

void on_stop_signal(int sig) {
  const char c = static_cast<char>(sig);
  [[maybe_unused]] const ssize_t n = ::write(stop_pipe[1], &c, 1);
}

sigset_t stop_signals() {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGINT);
  return set;
}

void install_stop_handlers() {
  if (::pipe(stop_pipe) != 0) brenier::fail(brenier::ErrorCode::kInternal, "cannot create a pipe");
  ::fcntl(stop_pipe[0], F_SETFL, O_NONBLOCK);
  struct sigaction sa {};
  sa.sa_handler = on_stop_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;
  sigaction(SIGTERM, &sa, nullptr);
  sigaction(SIGINT, &sa, nullptr);
  const sigset_t set = stop_signals();
  pthread_sigmask(SIG_BLOCK, &set, nullptr);
}

int wait_stop_signal() {
  const sigset_t set = stop_signals();
  for (;;) {
    const timespec tick{0, 200'000'000};
    const int sig = sigtimedwait(&set, nullptr, &tick);
    if (sig > 0) return sig;
    char c = 0;
    if (::read(stop_pipe[0], &c, 1) == 1) return c;
  }
}

struct Flags {
  std::string listen = "127.0.0.1:50051";
  std::string data = "brenier-data";
  std::string database;  // empty: SQLite in --data
  int workers = 0, queue = 64;
  int64_t max_upload_mb = 512, max_vertices = 5'000'000;
  int max_watches = 128, max_uploads = 32;
  int max_jobs_per_tenant = 0;
  int64_t max_storage_mb_per_tenant = 0, min_free_mb = 256;
  double retention_days = 30;
  double lease_seconds = 30;
  std::string tokens, tls_cert, tls_key, tls_client_ca, port_file;
  double grace = 30;
  std::string log_level = "info";
  std::string executor = "local", slurm_args, slurm_compute;
  int slurm_tile_pairs = 500;
  double slurm_poll_seconds = 2;
};

// Where matrix tiles run. Slurm's nodes run brenier-compute from the same path as this
// server's (the one installed beside brenierd unless --slurm-compute says otherwise).
brenier::server::ExecutorOptions executor_options(const Flags& f) {
  brenier::server::ExecutorOptions e;
  if (f.executor != "slurm") return e;
  e.kind = brenier::server::Executor::kSlurm;
  e.slurm.args = brenier::server::split_arguments(f.slurm_args);
  e.slurm.compute = f.slurm_compute;
  if (e.slurm.compute.empty()) {
    std::error_code ec;
    e.slurm.compute = (std::filesystem::read_symlink("/proc/self/exe", ec).parent_path() / "brenier-compute").string();
  }
  if (::access(e.slurm.compute.c_str(), X_OK) != 0)
    brenier::invalid("--executor slurm: " + e.slurm.compute + " is not an executable brenier-compute (--slurm-compute)");
  e.slurm.tile_pairs = f.slurm_tile_pairs;
  e.slurm.poll_seconds = f.slurm_poll_seconds;
  const brenier::server::CommandResult r = brenier::server::run_command({"sbatch", "--version"}, 30);
  if (!r.ok()) spdlog::warn("--executor slurm: sbatch does not run here ({}); matrix jobs will fail", r.summary());
  else spdlog::info("matrix tiles run on Slurm ({}), {} pairs per task", r.summary(), e.slurm.tile_pairs);
  return e;
}

int serve(const Flags& f) {
  // Logs go to stderr (stdout stays free for whoever runs us), one line per event.
  spdlog::set_default_logger(spdlog::stderr_color_mt("brenierd"));
  spdlog::set_level(spdlog::level::from_str(f.log_level));

  brenier::server::Auth auth = f.tokens.empty() ? brenier::server::Auth() : brenier::server::Auth::from_file(f.tokens);
  std::shared_ptr<grpc::ServerCredentials> creds = grpc::InsecureServerCredentials();
  if (!f.tls_cert.empty() || !f.tls_key.empty()) {
    if (f.tls_cert.empty() || f.tls_key.empty()) brenier::invalid("--tls-cert and --tls-key go together");
    grpc::SslServerCredentialsOptions o(f.tls_client_ca.empty()
                                           ? GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE
                                           : GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY);
    brenier::server::require_private_file(f.tls_key, "TLS key");
    // gRPC's TLS servers refuse versions below 1.2 (checked by the service tests with openssl).
    o.pem_key_cert_pairs.push_back({read_file(f.tls_key, "TLS key"), read_file(f.tls_cert, "TLS certificate")});
    if (!f.tls_client_ca.empty()) o.pem_root_certs = read_file(f.tls_client_ca, "client CA");
    creds = grpc::SslServerCredentials(o);
  } else if (!f.tls_client_ca.empty()) {
    brenier::invalid("--tls-client-ca needs --tls-cert and --tls-key");
  }

  const std::unique_ptr<brenier::server::Store> opened = brenier::server::open_store(f.data, f.database, f.lease_seconds);
  brenier::server::Store& store = *opened;
  // Replicas share --data: another one may be between a blob and its row right now.
  const auto orphan_age = f.database.empty() ? std::chrono::seconds(0) : std::chrono::hours(1);
  if (const int swept = store.sweep_orphaned_blobs(orphan_age)) spdlog::info("removed {} orphaned blobs", swept);
  brenier::server::ManagerOptions mo;
  mo.workers = f.workers;
  mo.queue = f.queue;
  mo.max_upload_bytes = f.max_upload_mb << 20;
  mo.max_vertices = f.max_vertices;
  mo.max_jobs_per_tenant = f.max_jobs_per_tenant;
  mo.max_storage_bytes_per_tenant = f.max_storage_mb_per_tenant << 20;
  mo.min_free_bytes = f.min_free_mb << 20;
  mo.retention_seconds = f.retention_days * 86400;
  mo.lease_seconds = f.lease_seconds;
  mo.executor = executor_options(f);
  brenier::server::Manager manager(store, mo);
  brenier::server::Service service(manager, std::move(auth),
                                  {.max_watches_per_tenant = f.max_watches, .max_uploads_per_tenant = f.max_uploads});

  // The jobs an earlier run left are queued before the port opens: recovered after, a job
  // submitted in between (its row already QUEUED) was queued twice and ran twice.
  manager.recover();

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(f.listen, creds, &port);
  builder.SetMaxReceiveMessageSize(16 << 20);  // chunks are 64 KiB; a map's weights may be larger
  // Handler threads stay around between bursts (gRPC's default keeps 2 and re-creates the
  // rest per burst), which shortens bursts of submissions and their latency's tail
  // (bench/RESULTS.md).
  builder.SetSyncServerOption(grpc::ServerBuilder::MIN_POLLERS, 2);
  builder.SetSyncServerOption(grpc::ServerBuilder::MAX_POLLERS, 64);
  builder.RegisterService(&service);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (!server || port == 0) brenier::invalid("cannot listen on " + f.listen);
  server->GetHealthCheckService()->SetServingStatus(true);
  const std::string host = f.listen.substr(0, f.listen.rfind(':'));
  spdlog::info("brenierd listening on {}:{} (data {}, database {} {}, {} workers, queue {}, tokens {}, TLS {})", host,
               port, f.data, store.backend(), brenier::server::elide_password(f.database),
               manager.options().workers, f.queue, f.tokens.empty() ? "off" : "on", f.tls_cert.empty() ? "off" : "on");
  if (!f.port_file.empty()) {
    const std::string tmp = f.port_file + ".tmp";
    std::ofstream(tmp) << port << "\n";
    std::rename(tmp.c_str(), f.port_file.c_str());
  }
  // The health service follows the database: NOT_SERVING while it is away (calls meanwhile
  // answer UNAVAILABLE), SERVING again when it is back.
  std::mutex health_mutex;
  std::condition_variable health_wake;
  bool stopping = false;
  std::thread health([&] {
    bool serving = true;
    std::unique_lock<std::mutex> lock(health_mutex);
    while (!health_wake.wait_for(lock, std::chrono::milliseconds(500), [&] { return stopping; })) {
      lock.unlock();
      const bool now = store.healthy();
      lock.lock();
      if (now != serving && !stopping) {  // under the lock: never SERVING again once stopping
        server->GetHealthCheckService()->SetServingStatus(now);
        if (now) spdlog::info("the database answers again: serving");
        else spdlog::error("the database does not answer: NOT_SERVING until it does");
        serving = now;
      }
    }
  });

  std::thread waiter([&] {
    const int sig = wait_stop_signal();
    spdlog::info("signal {}: shutting down (grace {} s)", sig, f.grace);
    {
      std::lock_guard<std::mutex> lock(health_mutex);
      stopping = true;
    }
    health_wake.notify_all();
    server->GetHealthCheckService()->SetServingStatus(false);
    manager.begin_shutdown();
    manager.finish_shutdown(f.grace);
    server->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(2));
  });
  server->Wait();
  waiter.join();
  health.join();
  spdlog::info("brenierd stopped");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  brenier::process::reexec_with_runtime_settings(argv);
  brenier::process::tune_allocator(brenier::process::Lifetime::kDaemon);
  install_stop_handlers();
  CLI::App app{"brenierd: conformal maps, optimal-transport maps and shape distances as a gRPC service"};
  Flags f;
  app.set_config("--config", "", "read flags from a TOML/INI file (keys: the long flag names)");
  app.add_option("--listen", f.listen, "HOST:PORT to listen on (port 0: any free port)");
  app.add_option("--data", f.data, "data directory (blobs; the SQLite database unless --database)");
  app.add_option("--database", f.database,
                 "postgresql://USER[:PASS]@HOST:PORT/DB: keep the metadata in PostgreSQL (replicas share it and --data)")
      ->envname("BRENIER_DATABASE");
  app.add_option("--workers", f.workers, "worker threads (default: the number of cores)")->check(CLI::Range(0, 1024));
  app.add_option("--queue", f.queue, "queued jobs at most before RESOURCE_EXHAUSTED")->check(CLI::Range(1, 1000000));
  app.add_option("--max-upload-mb", f.max_upload_mb, "largest upload in MiB")->check(CLI::Range(1, 1 << 20));
  app.add_option("--max-vertices", f.max_vertices, "largest mesh in vertices")->check(CLI::Range(3, 100'000'000));
  app.add_option("--max-jobs-per-tenant", f.max_jobs_per_tenant, "jobs queued or running per tenant at most (0: no quota)")
      ->check(CLI::Range(0, 10'000'000));
  app.add_option("--max-storage-mb-per-tenant", f.max_storage_mb_per_tenant,
                 "MB of meshes and results per tenant at most (0: no quota)")
      ->check(CLI::Range(int64_t{0}, int64_t{1} << 40));
  app.add_option("--retention-days", f.retention_days,
                 "finished jobs and their results are removed this long after they finish (0: kept)")
      ->check(CLI::Range(0.0, 36500.0));
  app.add_option("--lease-seconds", f.lease_seconds,
                 "with --database: a replica's claim on a job lasts this long unless renewed (renewed every third)")
      ->check(CLI::Range(0.5, 3600.0));
  app.add_option("--min-free-mb", f.min_free_mb, "uploads that would leave less free disk under --data are refused")
      ->check(CLI::Range(int64_t{0}, int64_t{1} << 40));
  app.add_option("--max-watches", f.max_watches, "open WatchJob streams per tenant at most")->check(CLI::Range(1, 100000));
  app.add_option("--max-uploads", f.max_uploads, "concurrent uploads per tenant at most")->check(CLI::Range(1, 100000));
  app.add_option("--tokens", f.tokens, "file of 'TOKEN TENANT' lines: bearer tokens required");
  app.add_option("--tls-cert", f.tls_cert, "PEM certificate chain (TLS)");
  app.add_option("--tls-key", f.tls_key, "PEM private key (TLS)");
  app.add_option("--tls-client-ca", f.tls_client_ca, "PEM CA: require client certificates signed by it");
  app.add_option("--grace", f.grace, "seconds running jobs get to finish on SIGTERM")->check(CLI::Range(0.0, 86400.0));
  app.add_option("--port-file", f.port_file, "write the port listened on to this file");
  app.add_option("--executor", f.executor, "where matrix tiles run: local (the worker pool) or slurm (a job array)")
      ->check(CLI::IsMember({"local", "slurm"}));
  app.add_option("--slurm-args", f.slurm_args, "sbatch options of the arrays, e.g. \"--partition=cpu --time=4:00:00\"");
  app.add_option("--slurm-compute", f.slurm_compute, "brenier-compute as the nodes run it (default: beside brenierd)");
  app.add_option("--slurm-tile-pairs", f.slurm_tile_pairs, "pairs per array task (default 500: minutes of work)")
      ->check(CLI::Range(1, 100000000));
  app.add_option("--slurm-poll-seconds", f.slurm_poll_seconds, "how often squeue and the tiles are looked at")
      ->check(CLI::Range(0.1, 600.0));
  app.add_option("--log-level", f.log_level, "trace, debug, info, warn, error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}));
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "brenierd: usage: %s\n", e.what());
    return 2;
  }
  try {
    return serve(f);
  } catch (const brenier::Error& e) {
    std::fprintf(stderr, "brenierd: %s\n", e.what());
    return e.code() == brenier::ErrorCode::kInternal ? 1 : 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "brenierd: internal error: %s\n", e.what());
    return 1;
  }
}

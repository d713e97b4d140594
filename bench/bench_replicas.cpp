// Timed harness for issue 21's targets (figures in bench/RESULTS.md):
//   bench_replicas BRENIERD POSTGRES_SH [PAUSE_MS]
// starts a PostgreSQL 15 of its own (tests/service/postgres.sh) and brenierd processes on
// loopback, and measures, SQLite and PostgreSQL in the same run:
//  1. SubmitJob latency at ~300 submissions/s: 32 clients each sending a Poisson gap of
//     PAUSE_MS (default 85 ms, ~300/s on 2 cores with the jobs running) after its last answer, from one driver thread (submit_load.hpp, as bench_service), the
//     small map jobs running meanwhile on the two cores;
//  2. the end-to-end time of a small map job on an idle server (submit, watch to the end,
//     download the result), median of 15;
// then, on PostgreSQL, 3. the takeover time: two replicas, a long job running on A, A killed
// with -9, until B runs the job (attempt 2), for leases of 5, 10 and 30 s (target: lease + 2 s).
#include <libpq-fe.h>
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "child_process.hpp"
#include "submit_load.hpp"
#include "mesh/io.hpp"
#include "mesh/shapes.hpp"

namespace pb = brenier::v1;
using brenier::bench::Server;
using Clock = std::chrono::steady_clock;

namespace {

double ms_since(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

double at(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))];
}

// A fresh database on the harness's PostgreSQL; its URL.
std::string create_database(const std::string& admin, const std::string& name) {
  PGconn* c = PQconnectdb(admin.c_str());
  if (PQstatus(c) != CONNECTION_OK) throw std::runtime_error(std::string("PostgreSQL: ") + PQerrorMessage(c));
  PQclear(PQexec(c, "SET client_min_messages = warning"));
  PQclear(PQexec(c, ("DROP DATABASE IF EXISTS " + name).c_str()));
  PGresult* r = PQexec(c, ("CREATE DATABASE " + name).c_str());
  const bool ok = PQresultStatus(r) == PGRES_COMMAND_OK;
  PQclear(r);
  PQfinish(c);
  if (!ok) throw std::runtime_error("cannot create database " + name);
  return admin.substr(0, admin.rfind('/') + 1) + name;
}

pb::SubmitJobRequest small_map(const std::string& mesh) {
  pb::SubmitJobRequest r;
  r.mutable_map()->set_mesh(mesh);
  return r;
}

std::string small_mesh(brenier::client::Client& c) {
  return c.upload_bytes(brenier::mesh::write_mesh_string(brenier::mesh::make_disk(6), brenier::mesh::Format::kOff),
                        "small.off")
      .id();
}

// 1: 32 clients, each submitting a Poisson gap of `pause_ms` after its last answer, 100
// submissions each, from one driver thread (submit_load.hpp); then the queue drains.
void paced_submissions(const Server& s, const char* label, double pause_ms) {
  auto c0 = s.client();
  const std::string mesh = small_mesh(c0);
  double wall = 0;
  const std::vector<double> ms = brenier::bench::submit_with_driver(s.address, mesh, 32, 100, pause_ms, wall);
  std::printf("%-10s SubmitJob, 32 clients each every %.0f ms (Poisson): %zu in %.2f s (%.0f/s); p50 %.2f ms, "
              "p99 %.2f ms, max %.2f ms\n",
              label, pause_ms, ms.size(), wall, static_cast<double>(ms.size()) / wall, at(ms, 0.5), at(ms, 0.99), at(ms, 1.0));
  for (int k = 0; k < 6000; ++k) {
    pb::ListJobsRequest r;
    r.set_state(pb::QUEUED);
    r.set_page_size(1);
    grpc::ClientContext ctx;
    pb::ListJobsResponse l;
    if (c0.stub().ListJobs(&ctx, r, &l).ok() && l.jobs_size() == 0) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

// 2: a small map job from submission to its downloaded result, median of 15.
void end_to_end(const Server& s, const char* label) {
  auto c = s.client();
  const std::string mesh = small_mesh(c);
  std::vector<double> ms;
  for (int k = 0; k < 15; ++k) {
    const auto t0 = Clock::now();
    const pb::Job j = c.watch(c.submit(small_map(mesh)).id());
    if (j.state() != pb::SUCCEEDED) throw std::runtime_error("a small map job failed: " + j.error().message());
    (void)c.fetch(j.id());
    ms.push_back(ms_since(t0));
  }
  std::printf("%-10s small map job end to end (submit, watch, download): median %.1f ms, min %.1f ms\n", label,
              at(ms, 0.5), at(ms, 0.0));
}

// 3: kill -9 of the replica running a job, until the other runs it.
void takeover(const std::string& brenierd, const std::string& data, const std::string& db, double lease) {
  const std::vector<std::string> flags = {"--database", db, "--workers", "1", "--lease-seconds", std::to_string(lease)};
  Server a(brenierd, data, flags, "a");
  Server b(brenierd, data, flags, "b", /*keep=*/true);
  auto ca = a.client(), cb = b.client();
  const std::string big =
      ca.upload_bytes(brenier::mesh::write_mesh_string(brenier::mesh::make_hemisphere(250), brenier::mesh::Format::kOff),
                      "big.off")
          .id();
  pb::SubmitJobRequest r = small_map(big);
  r.mutable_map()->set_method(pb::AREA_PRESERVING);
  const std::string id = ca.submit(r).id();
  for (int k = 0; k < 3000 && cb.get(id).state() != pb::RUNNING; ++k) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  a.kill9();
  const auto t0 = Clock::now();
  for (;;) {
    const pb::Job j = cb.get(id);
    if (j.attempts() >= 2 || ms_since(t0) > 1000 * (lease + 60)) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::printf("takeover after kill -9 with a %.0f s lease: the other replica ran the job %.2f s after the kill "
              "(target %.0f s)\n",
              lease, ms_since(t0) / 1000, lease + 2);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s BRENIERD POSTGRES_SH [PAUSE_MS]\n", argv[0]);
    return 2;
  }
  const std::string brenierd = argv[1], pg_sh = argv[2];
  const double pause_ms = argc > 3 ? std::atof(argv[3]) : 85;
  const std::string work = std::filesystem::temp_directory_path().string() + "/bench_replicas";
  std::filesystem::create_directories(work);
  const std::string state = work + "/pg/url";
  if (std::system((pg_sh + " start " + state + " > /dev/null").c_str()) != 0) {
    std::fprintf(stderr, "bench_replicas: cannot start PostgreSQL with %s\n", pg_sh.c_str());
    return 1;
  }
  int status = 0;
  try {
    std::ifstream in(state);
    std::string admin;
    in >> admin;
    const std::vector<std::string> busy = {"--queue", "100000"};
    {
      Server s(brenierd, work + "/sqlite", busy);
      paced_submissions(s, "SQLite", pause_ms);
      end_to_end(s, "SQLite");
    }
    {
      std::vector<std::string> flags = busy;
      flags.insert(flags.end(), {"--database", create_database(admin, "bench_submit")});
      Server s(brenierd, work + "/postgres", flags);
      paced_submissions(s, "PostgreSQL", pause_ms);
      end_to_end(s, "PostgreSQL");
    }
    for (const double lease : {5.0, 10.0, 30.0})
      takeover(brenierd, work + "/takeover", create_database(admin, "bench_takeover"), lease);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_replicas: %s\n", e.what());
    status = 1;
  }
  (void)std::system((pg_sh + " stop " + state).c_str());
  return status;
}

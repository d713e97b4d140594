// Timed harness for the service targets of issue 6 (figures in bench/RESULTS.md):
//   bench_service BRENIERD BRENIER_COMPUTE [MESH]
// starts its own brenierd on loopback and measures
//  1. uploading a 1M-vertex mesh as binary PLY (chunked, SHA-256 checked, parsed, validated);
//  2. SubmitJob latency with 32 concurrent clients (p50/p99 over 32 x 50 submissions);
//  3. progress events per Newton iteration seen by a watcher of an area-preserving map;
//  4. the server's overhead on a map job against brenier-compute on the same mesh (MESH,
//     default data/meshes/lion-head.off): submit to downloaded result, against the
//     offline command's wall time, medians of 9.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <condition_variable>
#include <map>
#include <mutex>
#include <queue>
#include <random>
#include <nlohmann/json.hpp>
#include <set>
#include <thread>

#include <grpcpp/grpcpp.h>

#include "child_process.hpp"
#include "submit_load.hpp"
#include "client.hpp"
#include "mesh/io.hpp"
#include "mesh/shapes.hpp"

namespace pb = brenier::v1;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

using brenier::bench::Server;

// The small disk every submission maps.
std::string upload_small(brenier::client::Client& c) {
  return c.upload_bytes(brenier::mesh::write_mesh_string(brenier::mesh::make_disk(6), brenier::mesh::Format::kOff),
                        "small.off")
      .id();
}

void report(const char* label, int clients, const char* what, double wall, std::vector<double> ms) {
  std::sort(ms.begin(), ms.end());
  std::printf("%s: %d clients x 50 submissions (%s) in %.2f s: p50 %.2f ms, p99 %.2f ms, max %.2f ms\n", label,
              clients, what, wall, ms[ms.size() / 2], ms[static_cast<size_t>(ms.size() * 0.99)], ms.back());
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s BRENIERD BRENIER_COMPUTE [MESH]\n", argv[0]);
    return 2;
  }
  const std::string brenierd = argv[1], compute = argv[2];
  const std::string mesh_path = argc > 3 ? argv[3] : std::string(BRENIER_DATA_DIR) + "/lion-head.off";
  const std::string work = std::filesystem::temp_directory_path().string() + "/bench_service";
  std::filesystem::create_directories(work);

  {  // 1. upload
    Server s(brenierd, work + "/data1", {"--max-upload-mb", "1024"});
    auto c = s.client();
    const brenier::mesh::TriMesh grid = brenier::mesh::make_grid(1000);
    const std::string ply = brenier::mesh::write_mesh_string(grid, brenier::mesh::Format::kPly);
    std::vector<double> t;
    for (int k = 0; k < 3; ++k) {
      if (k > 0) c.delete_mesh(brenier::client::sha256_hex(ply));
      const auto t0 = Clock::now();
      const pb::Mesh m = c.upload_bytes(ply, "grid1M.ply", "ply");
      t.push_back(since(t0));
      if (m.vertices() != 1'000'000) throw std::runtime_error("upload lost vertices");
    }
    std::printf("upload: 1,000,000-vertex binary PLY (%.1f MB): median %.2f s (runs %.2f %.2f %.2f)\n",
                ply.size() / 1e6, median(t), t[0], t[1], t[2]);
  }

  // 2. submit latency: `clients` concurrent clients, 50 submissions each
  auto submit_latency = [&](int clients, double pause_ms, const std::vector<std::string>& flags, const char* what,
                            bool one_long_job = false) {
    Server s(brenierd, work + "/data2", flags);
    auto c0 = s.client();
    if (one_long_job) {  // the one worker busy with a long transport while the submissions queue
      pb::SubmitJobRequest r;
      r.mutable_map()->set_mesh(
          c0.upload_bytes(brenier::mesh::write_mesh_string(brenier::mesh::make_hemisphere(200), brenier::mesh::Format::kOff),
                          "big.off")
              .id());
      r.mutable_map()->set_method(pb::AREA_PRESERVING);
      c0.submit(r);
    }
    const std::string id = upload_small(c0);
    std::vector<std::vector<double>> lat(clients);
    std::vector<std::thread> th;
    const auto t0 = Clock::now();
    for (int t = 0; t < clients; ++t)
      th.emplace_back([&, t] {
        auto c = s.client();
        std::mt19937 rng(1000 + t);
        std::exponential_distribution<double> gap(1.0 / std::max(pause_ms, 1e-9));  // Poisson arrivals
        c.get_mesh(id);  // the channel connected first: latency of submissions, not of TCP and HTTP/2 setup
        for (int k = 0; k < 50; ++k) {
          pb::SubmitJobRequest r;
          r.mutable_map()->set_mesh(id);
          const auto a = Clock::now();
          c.submit(r);
          lat[t].push_back(since(a) * 1e3);
          if (pause_ms > 0) std::this_thread::sleep_for(std::chrono::microseconds(static_cast<int>(gap(rng) * 1000)));
        }
      });
    for (auto& x : th) x.join();
    const double wall = since(t0);
    std::vector<double> all;
    for (auto& v : lat) all.insert(all.end(), v.begin(), v.end());
    report("submit", clients, what, wall, all);
  };
  // 2b. the same with a load generator that does not compete for the cores: 32 clients, each its own
  // channel and TCP connection (a local subchannel pool), whose calls are issued from one driver
  // thread through gRPC's callback API; each client sends its next submission a Poisson gap after
  // its previous one returned, as above. The 32-thread figures above measure as much the 32 client
  // threads' scheduling on the server's two cores as the server.
  auto submit_latency_async = [&](int clients, double pause_ms, const std::vector<std::string>& flags,
                                  const char* what) {
    Server s(brenierd, work + "/data2", flags);
    auto c0 = s.client();
    const std::string id = upload_small(c0);
    double wall = 0;
    const std::vector<double> lat = brenier::bench::submit_with_driver(s.address, id, clients, 50, pause_ms, wall);
    report("submit, one driver thread", clients, what, wall, lat);
  };
  submit_latency_async(32, 100, {"--queue", "100000"}, "each every 0.1 s on average (Poisson): 320 submissions/s");
  submit_latency_async(32, 20, {"--queue", "100000"}, "each every 20 ms on average: 1,600 submissions/s");
  submit_latency_async(32, 0, {"--queue", "100000"}, "back to back: saturating the 2 cores");
  submit_latency(1, 0, {"--queue", "100000"}, "back to back, jobs running meanwhile");
  submit_latency(32, 0, {"--queue", "100000"}, "back to back: saturating the 2 cores");
  submit_latency(32, 100, {"--queue", "100000"}, "each client every 0.1 s on average (Poisson): 320 submissions/s");
  submit_latency(32, 20, {"--queue", "100000"}, "each client every 20 ms on average: 1,600 submissions/s");
  submit_latency(32, 0, {"--queue", "100000", "--workers", "1"}, "back to back, one worker busy with a transport",
                 true);
  submit_latency(32, 100, {"--queue", "100000", "--workers", "1"},
                 "every 0.1 s on average, one worker busy with a transport", true);

  {  // 3 and 4. progress events and overhead on a map job
    Server s(brenierd, work + "/data3", {});
    auto c = s.client();
    const pb::Mesh m = c.upload(mesh_path);
    for (const char* method : {"conformal", "area-preserving"}) {
      std::vector<double> served, offline;
      int events = 0, newton = 0;
      std::set<std::pair<std::string, int>> iterations;
      for (int k = 0; k < 9; ++k) {
        pb::SubmitJobRequest r;
        r.mutable_map()->set_mesh(m.id());
        r.mutable_map()->set_method(std::string(method) == "conformal" ? pb::CONFORMAL : pb::AREA_PRESERVING);
        const auto t0 = Clock::now();
        const pb::Job j = c.submit(r);
        events = 0;
        iterations.clear();
        c.watch(j.id(), [&](const pb::JobEvent& e) {
          ++events;
          if (e.iteration() > 0) iterations.insert({e.stage(), e.iteration()});
        });
        c.fetch(j.id(), "mesh");
        served.push_back(since(t0));
        const auto rep = nlohmann::json::parse(c.fetch(j.id(), "report"));
        newton = rep["conformal"]["newton_iterations"].get<int>() +
                 (rep.contains("omt") ? rep["omt"]["newton_iterations"].get<int>() : 0);
        const std::string cmd = compute + " map " + mesh_path + " --method " + method + " -o " + work +
                                "/offline.obj > /dev/null";
        const auto t1 = Clock::now();
        if (std::system(cmd.c_str()) != 0) throw std::runtime_error("brenier-compute failed");
        offline.push_back(since(t1));
      }
      std::printf("map %s of %s (%d vertices): served %.3f s, brenier-compute %.3f s: overhead %+.1f %% "
                  "(medians of 9); watcher saw %d events, %zu distinct Newton iterations of %d\n",
                  method, std::filesystem::path(mesh_path).filename().c_str(), m.vertices(), median(served),
                  median(offline), 100 * (median(served) / median(offline) - 1), events, iterations.size(), newton);
    }
  }
  return 0;
}

// A load generator for SubmitJob that does not compete for the server's cores (bench_service,
// bench_replicas): `clients` clients, each its own channel and TCP connection (a local
// subchannel pool), whose calls are issued from one driver thread through gRPC's callback
// API; each client sends its next submission a Poisson gap (mean `pause_ms`) after its
// previous one returned. Client threads of their own would measure as much their scheduling
// on the server's two cores as the server (bench/RESULTS.md, issue 6).
#pragma once

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <queue>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "brenier/v1/brenier.grpc.pb.h"

namespace brenier::bench {

/// Latencies in ms of `clients` x `per_client` submissions of a conformal map of `mesh_id`;
/// `wall` gets the seconds they took. Throws when a submission fails.
inline std::vector<double> submit_with_driver(const std::string& address, const std::string& mesh_id, int clients,
                                              int per_client, double pause_ms, double& wall) {
  namespace pb = ::brenier::v1;
  using Clock = std::chrono::steady_clock;
  std::vector<std::unique_ptr<pb::Brenier::Stub>> stubs;
  for (int t = 0; t < clients; ++t) {
    grpc::ChannelArguments args;
    args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    stubs.push_back(pb::Brenier::NewStub(grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args)));
    grpc::ClientContext ctx;
    pb::GetMeshRequest r;
    r.set_id(mesh_id);
    pb::Mesh m;
    if (!stubs.back()->GetMesh(&ctx, r, &m).ok()) throw std::runtime_error("GetMesh failed");  // connected first
  }
  struct Call {
    grpc::ClientContext ctx;
    pb::SubmitJobRequest req;
    pb::Job job;
    Clock::time_point sent;
  };
  std::mutex mu;
  std::condition_variable cv;
  using Due = std::pair<Clock::time_point, int>;
  std::priority_queue<Due, std::vector<Due>, std::greater<Due>> due;  // (when, client)
  std::vector<int> sent(static_cast<size_t>(clients), 0);
  std::vector<double> lat;
  int done = 0, failed = 0;
  std::mt19937 rng(7);
  std::exponential_distribution<double> gap(1.0 / std::max(pause_ms, 1e-9));
  auto after_gap = [&] {
    return Clock::now() + std::chrono::microseconds(pause_ms > 0 ? static_cast<int64_t>(gap(rng) * 1000) : 0);
  };
  const auto t0 = Clock::now();
  for (int t = 0; t < clients; ++t) due.push({after_gap(), t});
  std::unique_lock<std::mutex> lock(mu);
  while (done < clients * per_client) {
    if (due.empty() || due.top().first > Clock::now()) {
      if (due.empty()) cv.wait(lock);
      else cv.wait_until(lock, due.top().first);
      continue;
    }
    const int t = due.top().second;
    due.pop();
    ++sent[static_cast<size_t>(t)];
    auto* call = new Call;
    call->req.mutable_map()->set_mesh(mesh_id);
    call->sent = Clock::now();
    stubs[static_cast<size_t>(t)]->async()->SubmitJob(&call->ctx, &call->req, &call->job, [&, call, t](grpc::Status st) {
      const double ms = std::chrono::duration<double, std::milli>(Clock::now() - call->sent).count();
      delete call;
      std::lock_guard<std::mutex> g(mu);
      lat.push_back(ms);
      failed += st.ok() ? 0 : 1;
      ++done;
      if (sent[static_cast<size_t>(t)] < per_client) due.push({after_gap(), t});
      cv.notify_one();
    });
  }
  lock.unlock();
  wall = std::chrono::duration<double>(Clock::now() - t0).count();
  if (failed) throw std::runtime_error(std::to_string(failed) + " submissions failed");
  return lat;
}

}  // namespace brenier::bench

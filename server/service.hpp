// The gRPC handlers of brenier.v1.Brenier: each turns a request into a Manager or Store call
// and its result or error into a reply (errors through guarded(), status.hpp).
#pragma once

#include <map>
#include <mutex>
#include <string>
#include <utility>

#include "auth.hpp"
#include "brenier/v1/brenier.grpc.pb.h"
#include "manager.hpp"

namespace brenier::server {

struct ServiceOptions {
  int max_watches_per_tenant = 128; // concurrent WatchJob streams of one tenant
  int max_uploads_per_tenant = 32;  // concurrent UploadMesh streams of one tenant
};

/// Per-tenant counts of open streams: a tenant cannot hold every handler thread (or every
/// upload's memory) of the server, whatever the others do.
class StreamCaps {
 public:
  /// Counts one more stream of `tenant` of this kind, or fails with kResourceExhausted when
  /// it already holds `limit`; the returned guard gives the place back.
  class Slot {
   public:
    Slot(StreamCaps* caps, std::string key) : caps_(caps), key_(std::move(key)) {}
    Slot(Slot&& o) noexcept : caps_(std::exchange(o.caps_, nullptr)), key_(std::move(o.key_)) {}
    Slot& operator=(Slot&&) = delete;
    ~Slot();

   private:
    StreamCaps* caps_;
    std::string key_;
  };
  Slot take(const std::string& tenant, const char* kind, int limit);

 private:
  std::mutex mutex_;
  std::map<std::string, int> open_;  // "kind/tenant" -> streams open
};

class Service final : public pb::Brenier::Service {
 public:
  Service(Manager& manager, Auth auth, ServiceOptions options = {})
      : manager_(manager), auth_(std::move(auth)), options_(options) {}

  grpc::Status UploadMesh(grpc::ServerContext* ctx, grpc::ServerReader<pb::UploadMeshRequest>* reader,
                          pb::Mesh* reply) override;
  grpc::Status GetMesh(grpc::ServerContext* ctx, const pb::GetMeshRequest* req, pb::Mesh* reply) override;
  grpc::Status ListMeshes(grpc::ServerContext* ctx, const pb::ListMeshesRequest* req,
                          pb::ListMeshesResponse* reply) override;
  grpc::Status DeleteMesh(grpc::ServerContext* ctx, const pb::DeleteMeshRequest* req,
                          pb::DeleteMeshResponse* reply) override;
  grpc::Status SubmitJob(grpc::ServerContext* ctx, const pb::SubmitJobRequest* req, pb::Job* reply) override;
  grpc::Status GetJob(grpc::ServerContext* ctx, const pb::GetJobRequest* req, pb::Job* reply) override;
  grpc::Status ListJobs(grpc::ServerContext* ctx, const pb::ListJobsRequest* req, pb::ListJobsResponse* reply) override;
  grpc::Status CancelJob(grpc::ServerContext* ctx, const pb::CancelJobRequest* req, pb::Job* reply) override;
  grpc::Status WatchJob(grpc::ServerContext* ctx, const pb::WatchJobRequest* req,
                        grpc::ServerWriter<pb::JobEvent>* writer) override;
  grpc::Status GetResult(grpc::ServerContext* ctx, const pb::GetResultRequest* req,
                         grpc::ServerWriter<pb::ResultChunk>* writer) override;

 private:
  Manager& manager_;
  Auth auth_;
  ServiceOptions options_;
  StreamCaps caps_;
};

}  // namespace brenier::server

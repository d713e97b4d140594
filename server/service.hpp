// The gRPC handlers of brenier.v1.Brenier: each turns a request into a Manager or Store call
// and its result or error into a reply (errors through guarded(), status.hpp).
#pragma once

#include "auth.hpp"
#include "brenier/v1/brenier.grpc.pb.h"
#include "manager.hpp"

namespace brenier::server {

class Service final : public pb::Brenier::Service {
 public:
  Service(Manager& manager, Auth auth) : manager_(manager), auth_(std::move(auth)) {}

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
};

}  // namespace brenier::server

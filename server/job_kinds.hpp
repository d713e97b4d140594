// What each kind of job (map, distance, matrix) is to brenierd: its spec checked at
// submission (translated into the typed request of core/jobs by proto/spec.hpp, then
// checked against the meshes' records), and its run (meshes read from the store, the
// computation of core/jobs, results stored as artifacts). The lifecycle around them (queue,
// live progress, cancel, restart) is the Manager's (manager.cpp).
#pragma once

#include <functional>
#include <string>

#include "brenier/v1/brenier.pb.h"
#include "jobs/jobs.hpp"
#include "manager.hpp"

namespace brenier::server {

struct SpecLimits {
  int64_t max_vertices = 0;  // also bounds the weights of a map
  int max_matrix_meshes = 0;
};

/// The tenant's record of a mesh id (NOT_FOUND and INVALID_ARGUMENT are the lookup's).
using MeshLookup = std::function<pb::Mesh(const std::string& id)>;

/// Checks a submission: the spec valid, its meshes the tenant's and of the class the domain
/// needs, counts within the limits. Returns the job's kind ("map", "distance", "matrix").
std::string check_spec(const pb::SubmitJobRequest& request, const MeshLookup& mesh, const SpecLimits& limits);

/// What a running job needs of its surroundings.
struct JobContext {
  Store& store;
  Scheduler& scheduler;
  LiveJob& live;
  std::string tenant;
  std::function<void(const pb::JobEvent&)> publish;
  const ExecutorOptions& executor;  // where matrix tiles run

  bool keep_going() const { return !live.cancel && !live.interrupted; }
  /// Progress of the core's loops as RUNNING events (and the live job's stage); false once
  /// the job is cancelled or interrupted, which stops the loop.
  jobs::ProgressSink sink();
  /// Error(kCancelled) once the job is cancelled or interrupted.
  void check() const;
  /// The tenant's mesh, read from its blob and cleaned (INVALID_ARGUMENT once deleted).
  mesh::CleanMesh load(const std::string& id, pb::Mesh* record = nullptr);
};

/// Runs a job's spec to its result (artifacts stored as blobs). Throws brenier::Error.
pb::JobResult run_spec(JobContext& c, const pb::SubmitJobRequest& spec);

}  // namespace brenier::server

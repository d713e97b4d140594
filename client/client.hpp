// brenier::Client: the C++ client library of brenierd (gRPC only; it never links the
// numerical core). Every call throws brenier::client::Error carrying the gRPC status.
#pragma once

#include <grpcpp/grpcpp.h>

#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "brenier/v1/brenier.grpc.pb.h"

namespace brenier::client {

namespace pb = ::brenier::v1;

struct Options {
  /// HOST:PORT; empty: $BRENIER_SERVER, else 127.0.0.1:50051.
  std::string server;
  /// Bearer token sent as `authorization: Bearer TOKEN` (empty: none).
  std::string token;
  /// TLS: the PEM CA that signed the server's certificate (empty with tls = false: plaintext).
  std::string tls_ca_file;
  bool tls = false;
  /// Client certificate and key for servers that require them (PEM files; optional).
  std::string tls_cert_file, tls_key_file;
  /// Deadline of each unary call, in seconds (streams of results and watches have none).
  double call_timeout = 60;
};

class Error : public std::runtime_error {
 public:
  Error(grpc::StatusCode code, const std::string& message) : std::runtime_error(message), code_(code) {}
  grpc::StatusCode code() const { return code_; }

 private:
  grpc::StatusCode code_;
};

/// Lower-case hex SHA-256 of bytes.
std::string sha256_hex(const std::string& bytes);

class Client {
 public:
  explicit Client(const Options& options = {});

  /// Uploads a mesh file in 64 KiB chunks (format from the extension unless given) and
  /// returns the server's record; the id is the SHA-256 of the bytes, and bytes the server
  /// already holds for this tenant are not sent again (GetMesh first).
  pb::Mesh upload(const std::string& path, const std::string& name = "", const std::string& format = "");
  pb::Mesh upload_bytes(const std::string& bytes, const std::string& name, const std::string& format = "");
  pb::Mesh get_mesh(const std::string& id);
  std::vector<pb::Mesh> list_meshes();
  void delete_mesh(const std::string& id);

  /// Submits a job; a request without request_id gets a fresh random one (so a retried call
  /// of this function is not run twice).
  pb::Job submit(pb::SubmitJobRequest request);
  pb::Job get(const std::string& job_id);
  pb::Job cancel(const std::string& job_id);
  std::vector<pb::Job> list_jobs(pb::JobState state = pb::JOB_STATE_UNSPECIFIED);
  /// Streams the job's events to `on_event` until the terminal one; returns the final job.
  pb::Job watch(const std::string& job_id, const std::function<void(const pb::JobEvent&)>& on_event = {});
  /// Fetches an artifact of a succeeded job (empty name: the main one).
  std::string fetch(const std::string& job_id, const std::string& artifact = "", pb::Artifact* meta = nullptr);
  /// The same into a file (written whole, then renamed); returns its metadata.
  pb::Artifact download(const std::string& job_id, const std::string& path, const std::string& artifact = "");

  /// The server's grpc.health.v1 status for `service` ("" : the whole server): "SERVING",
  /// "NOT_SERVING", ... Throws Error (UNAVAILABLE when nothing answers).
  std::string health(const std::string& service = "");

  pb::Brenier::Stub& stub() { return *stub_; }
  const std::string& server() const { return server_; }

 private:
  std::unique_ptr<grpc::ClientContext> context(bool deadline = true) const;
  Options options_;
  std::string server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<pb::Brenier::Stub> stub_;
};

}  // namespace brenier::client

#include "service.hpp"

#include <spdlog/spdlog.h>

#include <cctype>
#include <chrono>
#include <filesystem>
#include <fstream>

#include "common/error.hpp"
#include "common/hash.hpp"
#include "status.hpp"

namespace brenier::server {
namespace {

constexpr size_t kChunk = 64 * 1024;

int page_size(int requested) {
  if (requested < 0) invalid("page_size must not be negative");
  return requested == 0 ? 100 : std::min(requested, 1000);
}

// Every string a client sends that names something is bounded before it is looked up or
// echoed in a message: mesh ids are 64 hex digits, job ids 32, page tokens a number.
const std::string& bounded(const std::string& s, const char* what) {
  if (s.size() > 128) invalid(std::string(what) + " of " + std::to_string(s.size()) + " characters; at most 128");
  return s;
}

}  // namespace

StreamCaps::Slot StreamCaps::take(const std::string& tenant, const char* kind, int limit) {
  std::string key = std::string(kind) + "/" + tenant;
  std::lock_guard<std::mutex> lock(mutex_);
  int& n = open_[key];
  if (n >= limit)
    fail(ErrorCode::kResourceExhausted, "you have " + std::to_string(n) + " " + kind +
                                            " streams open, the most this server allows per tenant; close one first");
  ++n;
  return Slot(this, std::move(key));
}

StreamCaps::Slot::~Slot() {
  if (!caps_) return;
  std::lock_guard<std::mutex> lock(caps_->mutex_);
  auto it = caps_->open_.find(key_);
  if (--it->second == 0) caps_->open_.erase(it);
}

grpc::Status Service::UploadMesh(grpc::ServerContext* ctx, grpc::ServerReader<pb::UploadMeshRequest>* reader,
                                 pb::Mesh* reply) {
  return guarded([&] {
    const std::string tenant = auth_.tenant(ctx);
    if (manager_.shutting_down()) fail(ErrorCode::kUnavailable, "the server is shutting down");
    const StreamCaps::Slot slot = caps_.take(tenant, "upload", options_.max_uploads_per_tenant);
    pb::UploadMeshRequest msg;
    if (!reader->Read(&msg)) invalid("the upload is empty: the first message must carry the header");
    if (!msg.has_header()) invalid("the first message of an upload must carry the header (name, format, size, sha256)");
    const pb::UploadMeshRequest::Header h = msg.header();
    if (!is_sha256_hex(h.sha256())) invalid("the header's sha256 must be 64 lower-case hex digits");
    if (h.size_bytes() <= 0) invalid("the header's size_bytes must be positive");
    if (h.name().size() > 256) invalid("the mesh name is longer than 256 characters");
    // The name becomes part of the results' suggested file names: nothing that leaves a folder.
    for (char ch : h.name())
      if (ch == '/' || ch == '\\' || static_cast<unsigned char>(ch) < 0x20 || ch == 0x7f)
        invalid("the mesh name may not contain '/', '\\' or control characters (give the file's own name)");
    if (h.name() == "." || h.name() == "..") invalid("the mesh name may not be '.' or '..'");
    const int64_t limit = manager_.options().max_upload_bytes;
    if (h.size_bytes() > limit)
      fail(ErrorCode::kResourceExhausted, "the upload is " + std::to_string(h.size_bytes()) +
                                              " bytes; this server takes at most " + std::to_string(limit));
    // Quota and disk, before the bytes are sent (and again before they are written).
    if (!manager_.store().get_mesh(tenant, h.sha256())) manager_.check_room(tenant, h.size_bytes());
    // The bytes are kept in memory (they are parsed whole; the declared size is within the
    // limit) and stored as a blob only once they have checked out.
    std::string bytes;
    bytes.reserve(static_cast<size_t>(std::min<int64_t>(h.size_bytes(), int64_t{64} << 20)));
    Sha256 sha;
    int64_t received = 0;
    while (reader->Read(&msg)) {
      if (msg.has_header()) invalid("an upload carries one header, first");
      const std::string& c = msg.chunk();
      if (c.size() > kChunk) invalid("a chunk of " + std::to_string(c.size()) + " bytes; chunks are at most 65536");
      received += static_cast<int64_t>(c.size());
      if (received > h.size_bytes())
        invalid("more bytes than the declared " + std::to_string(h.size_bytes()));
      sha.update(c);
      bytes += c;
    }
    if (ctx->IsCancelled()) fail(ErrorCode::kCancelled, "the client cancelled the upload");
    if (received != h.size_bytes())
      invalid("truncated upload: " + std::to_string(received) + " of " + std::to_string(h.size_bytes()) + " bytes");
    const std::string got = sha.hex();
    if (got != h.sha256()) invalid("SHA-256 mismatch: the header says " + h.sha256() + ", the bytes hash to " + got);
    *reply = manager_.add_mesh(tenant, h, bytes);
    spdlog::info("mesh {} '{}' uploaded by '{}': {} vertices", reply->id().substr(0, 12), reply->name(), tenant,
                 reply->vertices());
    return grpc::Status::OK;
  });
}

grpc::Status Service::GetMesh(grpc::ServerContext* ctx, const pb::GetMeshRequest* req, pb::Mesh* reply) {
  return guarded([&] {
    auto m = manager_.store().get_mesh(auth_.tenant(ctx), bounded(req->id(), "an id"));
    if (!m) fail(ErrorCode::kNotFound, "no mesh " + req->id());
    *reply = *m;
    return grpc::Status::OK;
  });
}

grpc::Status Service::ListMeshes(grpc::ServerContext* ctx, const pb::ListMeshesRequest* req,
                                 pb::ListMeshesResponse* reply) {
  return guarded([&] {
    std::string next;
    for (auto& m : manager_.store().list_meshes(auth_.tenant(ctx), bounded(req->page_token(), "a page_token"), page_size(req->page_size()), next))
      *reply->add_meshes() = std::move(m);
    reply->set_next_page_token(next);
    return grpc::Status::OK;
  });
}

grpc::Status Service::DeleteMesh(grpc::ServerContext* ctx, const pb::DeleteMeshRequest* req, pb::DeleteMeshResponse*) {
  return guarded([&] {
    if (!manager_.store().delete_mesh(auth_.tenant(ctx), bounded(req->id(), "an id"))) fail(ErrorCode::kNotFound, "no mesh " + req->id());
    return grpc::Status::OK;
  });
}

grpc::Status Service::SubmitJob(grpc::ServerContext* ctx, const pb::SubmitJobRequest* req, pb::Job* reply) {
  return guarded([&] {
    *reply = manager_.submit(auth_.tenant(ctx), *req);
    return grpc::Status::OK;
  });
}

grpc::Status Service::GetJob(grpc::ServerContext* ctx, const pb::GetJobRequest* req, pb::Job* reply) {
  return guarded([&] {
    *reply = manager_.get(auth_.tenant(ctx), bounded(req->id(), "an id"));
    return grpc::Status::OK;
  });
}

grpc::Status Service::ListJobs(grpc::ServerContext* ctx, const pb::ListJobsRequest* req, pb::ListJobsResponse* reply) {
  return guarded([&] {
    const std::string tenant = auth_.tenant(ctx);
    std::string next;
    for (auto& j : manager_.store().list_jobs(tenant, req->state(), bounded(req->page_token(), "a page_token"), page_size(req->page_size()), next))
      *reply->add_jobs() = manager_.with_progress(std::move(j));
    reply->set_next_page_token(next);
    return grpc::Status::OK;
  });
}

grpc::Status Service::CancelJob(grpc::ServerContext* ctx, const pb::CancelJobRequest* req, pb::Job* reply) {
  return guarded([&] {
    *reply = manager_.cancel(auth_.tenant(ctx), bounded(req->id(), "an id"));
    return grpc::Status::OK;
  });
}

grpc::Status Service::WatchJob(grpc::ServerContext* ctx, const pb::WatchJobRequest* req,
                               grpc::ServerWriter<pb::JobEvent>* writer) {
  return guarded([&] {
    pb::Job current;
    const std::string tenant = auth_.tenant(ctx);
    std::shared_ptr<LiveJob> l = manager_.live(tenant, bounded(req->id(), "an id"), current);
    if (!l && (is_terminal(current.state()) || !manager_.store().shared())) {
      writer->Write(state_event(current));
      return grpc::Status::OK;
    }
    const StreamCaps::Slot slot = caps_.take(tenant, "watch", options_.max_watches_per_tenant);
    // A job another replica holds (or that left this one): followed in the store.
    auto follow = [&] {
      manager_.follow(
          tenant, req->id(), [&](const pb::JobEvent& e) { return writer->Write(e); },
          [&] { return ctx->IsCancelled() || manager_.shutting_down(); });
      if (manager_.shutting_down() && !ctx->IsCancelled())
        fail(ErrorCode::kUnavailable, "the server is shutting down; watch the job through another replica");
      return grpc::Status::OK;
    };
    if (!l) return follow();
    uint64_t next = 0;
    pb::JobEvent first;
    {
      std::lock_guard<std::mutex> lock(l->mutex);
      first = state_event(l->job);
      next = l->end_seq();
    }
    if (!writer->Write(first) || is_terminal(first.state())) return grpc::Status::OK;
    std::vector<pb::JobEvent> batch;
    for (;;) {
      {
        std::unique_lock<std::mutex> lock(l->mutex);
        l->changed.wait_for(lock, std::chrono::milliseconds(200), [&] { return l->end_seq() > next; });
        next = std::max(next, l->first_seq);  // a watcher that fell 4096 events behind skips ahead
        for (; next < l->end_seq(); ++next) batch.push_back(l->events[next - l->first_seq]);
      }
      for (const pb::JobEvent& e : batch) {
        if (!writer->Write(e)) return grpc::Status::OK;  // the client went away
        if (is_terminal(e.state())) return grpc::Status::OK;
      }
      batch.clear();
      if (l->detached) return follow();
      if (ctx->IsCancelled()) return grpc::Status(grpc::StatusCode::CANCELLED, "the watch was cancelled");
      if (manager_.shutting_down() && l->interrupted)
        fail(ErrorCode::kUnavailable, "the server is shutting down; the job runs again when it restarts");
    }
  });
}

grpc::Status Service::GetResult(grpc::ServerContext* ctx, const pb::GetResultRequest* req,
                                grpc::ServerWriter<pb::ResultChunk>* writer) {
  return guarded([&] {
    const pb::Job job = manager_.get(auth_.tenant(ctx), bounded(req->id(), "an id"));
    if (job.state() != pb::SUCCEEDED) {
      std::string why = "job " + job.id() + " is " + pb::JobState_Name(job.state());
      if (job.has_error()) why += ": " + job.error().message();
      fail(ErrorCode::kFailedPrecondition, why + "; results come once it has succeeded");
    }
    const pb::Artifact* a = nullptr;
    std::string names;
    bounded(req->artifact(), "an artifact name");
    for (const pb::Artifact& x : job.result().artifacts()) {
      names += (names.empty() ? "" : ", ") + x.name();
      if (req->artifact().empty() ? a == nullptr : x.name() == req->artifact()) a = &x;
    }
    if (!a) fail(ErrorCode::kNotFound, "job " + job.id() + " has no artifact '" + req->artifact() + "' (it has " + names + ")");
    std::ifstream in(manager_.store().blob_path(Store::Blob::kResult, a->sha256()), std::ios::binary);
    if (!in) fail(ErrorCode::kInternal, "the artifact's blob is missing");
    pb::ResultChunk head;
    *head.mutable_artifact() = *a;
    if (!writer->Write(head)) return grpc::Status::OK;
    std::string buf(kChunk, '\0');
    while (in) {
      in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
      const std::streamsize got = in.gcount();
      if (got <= 0) break;
      pb::ResultChunk c;
      c.set_chunk(buf.data(), static_cast<size_t>(got));
      if (!writer->Write(c)) return grpc::Status::OK;
    }
    return grpc::Status::OK;
  });
}

}  // namespace brenier::server

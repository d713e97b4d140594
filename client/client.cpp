#include "client.hpp"

#include "grpc/health/v1/health.grpc.pb.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>

#include "common/hash.hpp"

namespace brenier::client {
namespace {

void check(const grpc::Status& s) {
  if (!s.ok()) throw Error(s.error_code(), s.error_message());
}

std::string read_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(grpc::StatusCode::INVALID_ARGUMENT, "cannot read " + path);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

std::string random_request_id() {
  std::random_device rd;
  char buf[40];
  std::snprintf(buf, sizeof buf, "c-%08x%08x%08x%08x", rd(), rd(), rd(), rd());
  return buf;
}

}  // namespace

std::string sha256_hex(const std::string& bytes) { return brenier::sha256_hex(bytes); }

Client::Client(const Options& o) : options_(o) {
  server_ = o.server;
  if (server_.empty()) {
    const char* env = std::getenv("BRENIER_SERVER");
    server_ = env && *env ? env : "127.0.0.1:50051";
  }
  std::shared_ptr<grpc::ChannelCredentials> creds = grpc::InsecureChannelCredentials();
  if (o.tls || !o.tls_ca_file.empty()) {
    grpc::SslCredentialsOptions ssl;
    if (!o.tls_ca_file.empty()) ssl.pem_root_certs = read_file(o.tls_ca_file);
    if (!o.tls_cert_file.empty()) ssl.pem_cert_chain = read_file(o.tls_cert_file);
    if (!o.tls_key_file.empty()) ssl.pem_private_key = read_file(o.tls_key_file);
    creds = grpc::SslCredentials(ssl);
  }
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(16 << 20);
  channel_ = grpc::CreateCustomChannel(server_, creds, args);
  stub_ = pb::Brenier::NewStub(channel_);
}

std::unique_ptr<grpc::ClientContext> Client::context(bool deadline) const {
  auto c = std::make_unique<grpc::ClientContext>();
  if (!options_.token.empty()) c->AddMetadata("authorization", "Bearer " + options_.token);
  if (deadline && options_.call_timeout > 0)
    c->set_deadline(std::chrono::system_clock::now() +
                    std::chrono::milliseconds(static_cast<int64_t>(options_.call_timeout * 1000)));
  return c;
}

std::string Client::health(const std::string& service) {
  auto stub = grpc::health::v1::Health::NewStub(channel_);
  grpc::health::v1::HealthCheckRequest r;
  r.set_service(service);
  grpc::health::v1::HealthCheckResponse a;
  check(stub->Check(context().get(), r, &a));
  return grpc::health::v1::HealthCheckResponse::ServingStatus_Name(a.status());
}

pb::Mesh Client::upload(const std::string& path, const std::string& name, const std::string& format) {
  const std::string bytes = read_file(path);
  return upload_bytes(bytes, name.empty() ? std::filesystem::path(path).filename().string() : name, format);
}

pb::Mesh Client::upload_bytes(const std::string& bytes, const std::string& name, const std::string& format) {
  // The id is the content's hash: a mesh the server already holds for us is not sent again.
  const std::string sha = sha256_hex(bytes);
  {
    pb::GetMeshRequest r;
    r.set_id(sha);
    pb::Mesh m;
    const grpc::Status s = stub_->GetMesh(context().get(), r, &m);
    if (s.ok()) return m;
    if (s.error_code() != grpc::StatusCode::NOT_FOUND) check(s);
  }
  auto ctx = context(false);
  pb::Mesh reply;
  auto writer = stub_->UploadMesh(ctx.get(), &reply);
  pb::UploadMeshRequest m;
  auto* h = m.mutable_header();
  h->set_name(name);
  h->set_format(format);
  h->set_size_bytes(static_cast<int64_t>(bytes.size()));
  h->set_sha256(sha);
  bool ok = writer->Write(m);
  constexpr size_t kChunk = 64 * 1024;
  for (size_t at = 0; ok && at < bytes.size(); at += kChunk) {
    pb::UploadMeshRequest c;
    c.set_chunk(bytes.data() + at, std::min(kChunk, bytes.size() - at));
    ok = writer->Write(c);
  }
  writer->WritesDone();
  check(writer->Finish());
  return reply;
}

pb::Mesh Client::get_mesh(const std::string& id) {
  pb::GetMeshRequest r;
  r.set_id(id);
  pb::Mesh m;
  check(stub_->GetMesh(context().get(), r, &m));
  return m;
}

namespace {

// Every page of a paged list: `call(request, page)` fetches one, `items(page)` its entries.
template <class Request, class Page, class Call, class Items>
auto all_pages(Request r, Call call, Items items) {
  std::vector<typename std::decay_t<decltype(items(Page()))>::value_type> out;
  r.set_page_size(1000);
  do {
    Page page;
    call(r, page);
    out.insert(out.end(), items(page).begin(), items(page).end());
    r.set_page_token(page.next_page_token());
  } while (!r.page_token().empty());
  return out;
}

}  // namespace

std::vector<pb::Mesh> Client::list_meshes() {
  return all_pages<pb::ListMeshesRequest, pb::ListMeshesResponse>(
      pb::ListMeshesRequest(),
      [&](const pb::ListMeshesRequest& r, pb::ListMeshesResponse& page) {
        check(stub_->ListMeshes(context().get(), r, &page));
      },
      [](const pb::ListMeshesResponse& page) -> const auto& { return page.meshes(); });
}

void Client::delete_mesh(const std::string& id) {
  pb::DeleteMeshRequest r;
  r.set_id(id);
  pb::DeleteMeshResponse out;
  check(stub_->DeleteMesh(context().get(), r, &out));
}

pb::Job Client::submit(pb::SubmitJobRequest request) {
  if (request.request_id().empty()) request.set_request_id(random_request_id());
  pb::Job job;
  // Idempotent: a call that failed in transport is retried once with the same request_id.
  grpc::Status s = stub_->SubmitJob(context().get(), request, &job);
  if (s.error_code() == grpc::StatusCode::UNAVAILABLE && s.error_message().find("shutting down") == std::string::npos)
    s = stub_->SubmitJob(context().get(), request, &job);
  check(s);
  return job;
}

pb::Job Client::get(const std::string& id) {
  pb::GetJobRequest r;
  r.set_id(id);
  pb::Job j;
  check(stub_->GetJob(context().get(), r, &j));
  return j;
}

pb::Job Client::cancel(const std::string& id) {
  pb::CancelJobRequest r;
  r.set_id(id);
  pb::Job j;
  check(stub_->CancelJob(context().get(), r, &j));
  return j;
}

std::vector<pb::Job> Client::list_jobs(pb::JobState state) {
  pb::ListJobsRequest r;
  r.set_state(state);
  return all_pages<pb::ListJobsRequest, pb::ListJobsResponse>(
      r,
      [&](const pb::ListJobsRequest& q, pb::ListJobsResponse& page) {
        check(stub_->ListJobs(context().get(), q, &page));
      },
      [](const pb::ListJobsResponse& page) -> const auto& { return page.jobs(); });
}

pb::Job Client::watch(const std::string& id, const std::function<void(const pb::JobEvent&)>& on_event) {
  pb::WatchJobRequest r;
  r.set_id(id);
  auto ctx = context(false);
  auto reader = stub_->WatchJob(ctx.get(), r);
  pb::JobEvent e;
  while (reader->Read(&e))
    if (on_event) on_event(e);
  check(reader->Finish());
  return get(id);
}

std::string Client::fetch(const std::string& id, const std::string& artifact, pb::Artifact* meta) {
  pb::GetResultRequest r;
  r.set_id(id);
  r.set_artifact(artifact);
  auto ctx = context(false);
  auto reader = stub_->GetResult(ctx.get(), r);
  pb::ResultChunk c;
  pb::Artifact a;
  std::string bytes;
  while (reader->Read(&c)) {
    if (c.has_artifact()) {
      a = c.artifact();
      bytes.reserve(static_cast<size_t>(a.size_bytes()));
    } else {
      bytes += c.chunk();
    }
  }
  check(reader->Finish());
  if (static_cast<int64_t>(bytes.size()) != a.size_bytes() || sha256_hex(bytes) != a.sha256())
    throw Error(grpc::StatusCode::DATA_LOSS, "the artifact arrived damaged (size or SHA-256 differs)");
  if (meta) *meta = a;
  return bytes;
}

pb::Artifact Client::download(const std::string& id, const std::string& path, const std::string& artifact) {
  pb::Artifact a;
  const std::string bytes = fetch(id, artifact, &a);
  const std::string tmp = path + ".part";
  {
    std::ofstream os(tmp, std::ios::binary | std::ios::trunc);
    if (!os || !os.write(bytes.data(), static_cast<std::streamsize>(bytes.size())) || !os.flush())
      throw Error(grpc::StatusCode::INVALID_ARGUMENT, "cannot write " + path);
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw Error(grpc::StatusCode::INVALID_ARGUMENT, "cannot write " + path + ": " + ec.message());
  return a;
}

}  // namespace brenier::client

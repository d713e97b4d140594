// libFuzzer target for the gRPC handlers: the input is decoded (FuzzedDataProvider) into a
// sequence of calls against one in-process brenierd (Store + Manager + Service, two workers,
// a small queue): uploads of small valid meshes or fuzzed bytes with right or wrong headers
// and chunking, SubmitJob specs of every kind with fuzzed fields (ids, enums, markers,
// weights, tolerances, t, request ids), and Get/List/Cancel/Watch/GetResult/Delete of ids
// seen or made up. What must hold for any input: no crash or sanitizer report, no status
// outside those a client may get for its own mistakes (INTERNAL or UNKNOWN is a bug), and a
// job that fails never fails with INTERNAL.
#include <fuzzer/FuzzedDataProvider.h>
#include <grpcpp/grpcpp.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "brenier/v1/brenier.grpc.pb.h"
#include "common/hash.hpp"
#include "manager.hpp"
#include "mesh/io.hpp"
#include "mesh/shapes.hpp"
#include "service.hpp"
#include "store.hpp"

namespace {

using namespace brenier;
using namespace brenier::server;

struct InProcess {
  std::string dir;
  std::unique_ptr<Store> store;
  std::unique_ptr<Manager> manager;
  std::unique_ptr<Service> service;
  std::unique_ptr<grpc::Server> server;
  std::unique_ptr<pb::Brenier::Stub> stub;
  std::vector<std::string> meshes;  // small valid meshes: two disks, a sphere
  std::vector<std::string> ids;     // mesh and job ids seen, to refer to

  InProcess() {
    char tmpl[] = "/tmp/brenier-fuzz-service-XXXXXX";
    if (!mkdtemp(tmpl)) std::abort();
    dir = tmpl;
    store = open_store(dir);
    manager = std::make_unique<Manager>(*store, ManagerOptions{.workers = 2, .queue = 8, .max_upload_bytes = 1 << 20,
                                                               .max_vertices = 2000, .max_matrix_meshes = 6});
    service = std::make_unique<Service>(*manager, Auth());
    grpc::ServerBuilder builder;
    builder.RegisterService(service.get());
    server = builder.BuildAndStart();
    stub = pb::Brenier::NewStub(server->InProcessChannel(grpc::ChannelArguments()));
    meshes = {mesh::write_mesh_string(mesh::make_disk(2), mesh::Format::kOff),
              mesh::write_mesh_string(mesh::make_disk(3), mesh::Format::kObj),
              mesh::write_mesh_string(mesh::make_icosphere(1), mesh::Format::kPly)};
  }
};

InProcess& env() {
  static InProcess* e = new InProcess();  // never destroyed: workers may still run at exit
  return *e;
}

// Statuses a client may get for what it sent; anything else is a server bug.
void check(const grpc::Status& s, const char* call) {
  switch (s.error_code()) {
    case grpc::StatusCode::OK:
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::NOT_FOUND:
    case grpc::StatusCode::FAILED_PRECONDITION:
    case grpc::StatusCode::RESOURCE_EXHAUSTED:
    case grpc::StatusCode::DEADLINE_EXCEEDED:
    case grpc::StatusCode::CANCELLED:
      return;
    default:
      std::fprintf(stderr, "%s answered %d: %s\n", call, static_cast<int>(s.error_code()), s.error_message().c_str());
      std::abort();
  }
}

// A string field's value: 7-bit bytes, control characters included. (Invalid UTF-8 in a proto3
// string field never reaches a handler: gRPC's own parser refuses the message with INTERNAL
// "failed to parse", which is not ours to change; the server stays up.)
std::string text(FuzzedDataProvider& in, size_t max_length) {
  std::string s = in.ConsumeRandomLengthString(max_length);
  for (char& c : s) c = static_cast<char>(c & 0x7f);
  return s;
}

std::string pick_id(FuzzedDataProvider& in, InProcess& e) {
  if (!e.ids.empty() && in.ConsumeBool()) return e.ids[in.ConsumeIntegralInRange<size_t>(0, e.ids.size() - 1)];
  return text(in, 160);
}

double fuzz_double(FuzzedDataProvider& in) {
  switch (in.ConsumeIntegralInRange(0, 4)) {
    case 0: return 0;
    case 1: return in.ConsumeFloatingPointInRange(-2.0, 2.0);
    case 2: return std::numeric_limits<double>::quiet_NaN();
    case 3: return in.ConsumeBool() ? HUGE_VAL : -HUGE_VAL;
    default: return in.ConsumeFloatingPoint<double>();
  }
}

void upload(FuzzedDataProvider& in, InProcess& e) {
  std::string bytes = in.ConsumeBool() ? e.meshes[in.ConsumeIntegralInRange<size_t>(0, e.meshes.size() - 1)]
                                       : in.ConsumeRandomLengthString(4096);
  pb::UploadMeshRequest::Header h;
  const char* names[] = {"m.off", "m.obj", "m.ply", "m.stl", "lh.pial", "noext", "../../etc/passwd"};
  h.set_name(names[in.ConsumeIntegralInRange(0, 6)]);
  const char* formats[] = {"", "off", "obj", "ply", "stl", "freesurfer", "xyz"};
  h.set_format(formats[in.ConsumeIntegralInRange(0, 6)]);
  h.set_sha256(in.ConsumeIntegralInRange(0, 7) == 0 ? std::string(64, 'a') : sha256_hex(bytes));
  h.set_size_bytes(static_cast<int64_t>(bytes.size()) + (in.ConsumeIntegralInRange(0, 7) == 0 ? in.ConsumeIntegralInRange(-2, 2) : 0));
  grpc::ClientContext ctx;
  pb::Mesh reply;
  auto w = e.stub->UploadMesh(&ctx, &reply);
  pb::UploadMeshRequest m;
  if (in.ConsumeIntegralInRange(0, 15) != 0) {
    *m.mutable_header() = h;
    w->Write(m);
  }
  size_t at = 0;
  while (at < bytes.size()) {
    const size_t n = std::min(bytes.size() - at, in.ConsumeIntegralInRange<size_t>(1, 70000));
    pb::UploadMeshRequest c;
    c.set_chunk(bytes.substr(at, n));
    if (!w->Write(c)) break;
    at += n;
  }
  w->WritesDone();
  const grpc::Status s = w->Finish();
  check(s, "UploadMesh");
  if (s.ok()) e.ids.push_back(reply.id());
}

void fill_map(FuzzedDataProvider& in, InProcess& e, pb::MapSpec& s) {
  s.set_mesh(pick_id(in, e));
  s.set_domain(static_cast<pb::Domain>(in.ConsumeIntegralInRange(-1, 3)));
  s.set_method(static_cast<pb::MapMethod>(in.ConsumeIntegralInRange(-1, 3)));
  for (int i = in.ConsumeIntegralInRange(0, 3); i > 0; --i) s.add_markers(in.ConsumeIntegralInRange(-2, 200));
  if (in.ConsumeBool())
    for (int i = in.ConsumeIntegralInRange(0, 60); i > 0; --i) s.add_weights(fuzz_double(in));
  s.set_t(fuzz_double(in));
  s.set_cut_hole(in.ConsumeBool());
  s.set_tolerance(fuzz_double(in));
  const char* formats[] = {"", "obj", "ply", "off", "stl", "fs"};
  s.set_output_format(formats[in.ConsumeIntegralInRange(0, 5)]);
  s.set_has_hole_vertex(in.ConsumeBool());
  s.set_hole_vertex(in.ConsumeIntegralInRange(-2, 200));
  s.set_max_iterations(in.ConsumeIntegralInRange(-2, 30));
}

template <typename Spec>
void fill_shape_options(FuzzedDataProvider& in, Spec& s) {
  s.set_domain(static_cast<pb::Domain>(in.ConsumeIntegralInRange(-1, 3)));
  s.set_method(static_cast<pb::DistanceMethod>(in.ConsumeIntegralInRange(-1, 3)));
  s.set_cut_hole(in.ConsumeBool());
  if (in.ConsumeBool()) {
    s.mutable_wasserstein()->set_tolerance(fuzz_double(in));
    s.mutable_wasserstein()->set_cost_tolerance(fuzz_double(in));
    s.mutable_wasserstein()->set_refine_rotation(in.ConsumeBool());
    s.mutable_wasserstein()->set_exact_rotation(in.ConsumeBool());
    s.mutable_wasserstein()->set_raw(in.ConsumeBool());
  }
}

void submit(FuzzedDataProvider& in, InProcess& e) {
  pb::SubmitJobRequest r;
  if (in.ConsumeBool()) r.set_request_id(text(in, 40));
  switch (in.ConsumeIntegralInRange(0, 3)) {
    case 0: fill_map(in, e, *r.mutable_map()); break;
    case 1: {
      pb::DistanceSpec& s = *r.mutable_distance();
      s.set_a(pick_id(in, e));
      s.set_b(pick_id(in, e));
      fill_shape_options(in, s);
      if (in.ConsumeBool()) {
        s.mutable_markers_a()->set_center(in.ConsumeIntegralInRange(-2, 100));
        s.mutable_markers_a()->set_boundary(in.ConsumeIntegralInRange(-2, 100));
      }
      if (in.ConsumeBool()) {
        s.mutable_markers_b()->set_center(in.ConsumeIntegralInRange(-2, 100));
        s.mutable_markers_b()->set_boundary(in.ConsumeIntegralInRange(-2, 100));
      }
      break;
    }
    case 2: {
      pb::MatrixSpec& s = *r.mutable_matrix();
      for (int i = in.ConsumeIntegralInRange(0, 8); i > 0; --i) s.add_meshes(pick_id(in, e));
      fill_shape_options(in, s);
      for (int i = in.ConsumeIntegralInRange(0, 8); i > 0; --i) {
        pb::DiskMarkers* m = s.add_markers();
        m->set_center(in.ConsumeIntegralInRange(-2, 100));
        m->set_boundary(in.ConsumeIntegralInRange(-2, 100));
      }
      break;
    }
    default: break;  // no spec
  }
  grpc::ClientContext ctx;
  pb::Job job;
  const grpc::Status s = e.stub->SubmitJob(&ctx, r, &job);
  check(s, "SubmitJob");
  if (s.ok()) e.ids.push_back(job.id());
}

// A unary call whose request names one id (GetJob, CancelJob, GetMesh, DeleteMesh).
template <class Request, class Response>
Response by_id(InProcess& e, grpc::ClientContext& ctx, const std::string& id, const char* name,
               grpc::Status (pb::Brenier::Stub::*rpc)(grpc::ClientContext*, const Request&, Response*)) {
  Request r;
  r.set_id(id);
  Response out;
  check((e.stub.get()->*rpc)(&ctx, r, &out), name);
  return out;
}

// A server stream read to its end (WatchJob, GetResult).
template <class Item, class Reader>
void drain(Reader reader, const char* name) {
  Item item;
  while (reader->Read(&item)) {
  }
  check(reader->Finish(), name);
}

template <class Request>
Request page_request(FuzzedDataProvider& in) {
  Request r;
  r.set_page_size(in.ConsumeIntegralInRange(-3, 2000));
  r.set_page_token(in.ConsumeBool() ? "" : text(in, 20));
  return r;
}

void inspect(FuzzedDataProvider& in, InProcess& e) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(200));
  const std::string id = pick_id(in, e);
  switch (in.ConsumeIntegralInRange(0, 7)) {
    case 0: {
      const pb::Job j = by_id(e, ctx, id, "GetJob", &pb::Brenier::Stub::GetJob);
      if (j.state() == pb::FAILED && j.error().code() == static_cast<int>(grpc::StatusCode::INTERNAL)) {
        std::fprintf(stderr, "job %s failed with INTERNAL: %s\n", j.id().c_str(), j.error().message().c_str());
        std::abort();
      }
      break;
    }
    case 1: (void)by_id(e, ctx, id, "CancelJob", &pb::Brenier::Stub::CancelJob); break;
    case 2: {
      pb::WatchJobRequest r;
      r.set_id(id);
      drain<pb::JobEvent>(e.stub->WatchJob(&ctx, r), "WatchJob");
      break;
    }
    case 3: {
      pb::GetResultRequest r;
      r.set_id(id);
      r.set_artifact(in.ConsumeBool() ? "" : text(in, 16));
      drain<pb::ResultChunk>(e.stub->GetResult(&ctx, r), "GetResult");
      break;
    }
    case 4: (void)by_id(e, ctx, id, "DeleteMesh", &pb::Brenier::Stub::DeleteMesh); break;
    case 5: {
      pb::ListJobsRequest r = page_request<pb::ListJobsRequest>(in);
      r.set_state(static_cast<pb::JobState>(in.ConsumeIntegralInRange(-1, 7)));
      pb::ListJobsResponse l;
      check(e.stub->ListJobs(&ctx, r, &l), "ListJobs");
      break;
    }
    case 6: {
      pb::ListMeshesResponse l;
      check(e.stub->ListMeshes(&ctx, page_request<pb::ListMeshesRequest>(in), &l), "ListMeshes");
      break;
    }
    default: (void)by_id(e, ctx, id, "GetMesh", &pb::Brenier::Stub::GetMesh); break;
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  InProcess& e = env();
  FuzzedDataProvider in(data, size);
  for (int op = 0; op < 16 && in.remaining_bytes() > 0; ++op) {
    switch (in.ConsumeIntegralInRange(0, 3)) {
      case 0: upload(in, e); break;
      case 1: submit(in, e); break;
      default: inspect(in, e); break;
    }
  }
  if (e.ids.size() > 256) e.ids.erase(e.ids.begin(), e.ids.begin() + 128);
  return 0;
}

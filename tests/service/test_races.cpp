// The three races of issue 20, each with its window held open by a test hook
// (server/test_hooks.hpp) so the bad interleaving happens every run, not by luck. Each test
// fails on the code before its fix; under ThreadSanitizer they also check the fixed code
// for data races. The server runs in this process: a Store, a Manager and, for WatchJob, the
// gRPC Service on a loopback port.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <future>
#include <thread>

#include "brenier/v1/brenier.grpc.pb.h"
#include "common/error.hpp"
#include "common/hash.hpp"
#include "manager.hpp"
#include "mesh/io.hpp"
#include "mesh/shapes.hpp"
#include "service.hpp"
#include "store.hpp"
#include "test_database.hpp"
#include "test_hooks.hpp"

namespace fs = std::filesystem;
using namespace brenier;
using namespace brenier::server;
using namespace std::chrono_literals;

namespace {

ManagerOptions manager_options(int workers, int queue) {
  ManagerOptions o;
  o.workers = workers;
  o.queue = queue;
  return o;
}

struct Fixture : ::testing::Test {
  std::string dir;
  void SetUp() override {
    dir = std::string(BRENIER_TEST_WORK) + "/" + ::testing::UnitTest::GetInstance()->current_test_info()->name() +
          (std::getenv("BRENIER_TEST_PG") ? "-pg" : "");  // the variants may run at once
    fs::remove_all(dir);
    fs::create_directories(dir);
  }
  void TearDown() override { test_hooks::disarm_all(); }
};

std::string disk_bytes(int rings) { return mesh::write_mesh_string(mesh::make_disk(rings), mesh::Format::kOff); }

pb::Mesh upload(Manager& m, const std::string& tenant, const std::string& bytes) {
  pb::UploadMeshRequest::Header h;
  h.set_name("disk.off");
  h.set_sha256(sha256_hex(bytes));
  h.set_size_bytes(static_cast<int64_t>(bytes.size()));
  return m.add_mesh(tenant, h, bytes);
}

pb::SubmitJobRequest map_request(const std::string& mesh_id, const std::string& request_id = "") {
  pb::SubmitJobRequest r;
  r.set_request_id(request_id);
  r.mutable_map()->set_mesh(mesh_id);
  return r;
}

pb::Job wait_terminal(Manager& m, const std::string& tenant, const std::string& id, std::chrono::seconds limit) {
  const auto until = std::chrono::steady_clock::now() + limit;
  for (;;) {
    pb::Job j = m.store().get_job(tenant, id).value();
    if (is_terminal(j.state()) || std::chrono::steady_clock::now() > until) return j;
    std::this_thread::sleep_for(5ms);
  }
}

// Race 1. WatchJob looked the job up in the store, then in the live map: a job that finished
// in between was reported with its stale RUNNING state and the stream ended without the
// terminal event. The hook waits, between the two lookups, until the job has finished.
TEST_F(Fixture, WatchOfAJobFinishingMeanwhileEndsWithItsTerminalEvent) {
  const std::unique_ptr<Store> owned = open_store(dir, brenier::test::test_database(dir));
  Store& store = *owned;
  Manager manager(store, manager_options(1, 4));
  Service service(manager, Auth());
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
  builder.RegisterService(&service);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  ASSERT_GT(port, 0);

  const pb::Mesh mesh = upload(manager, "default", disk_bytes(6));
  // Hold the worker until the watch has looked once, so the job is surely not finished then.
  std::promise<void> looked;
  std::shared_future<void> looked_f = looked.get_future().share();
  test_hooks::arm(test_hooks::Point::kRunStart, [looked_f] { looked_f.wait_for(10s); });
  const pb::Job job = manager.submit("default", map_request(mesh.id()));
  test_hooks::arm(test_hooks::Point::kLiveBetweenLookups, [&] {
    looked.set_value();
    EXPECT_EQ(wait_terminal(manager, "default", job.id(), 60s).state(), pb::SUCCEEDED);
    std::this_thread::sleep_for(50ms);  // and out of the live map (just after the store)
  });

  auto stub = pb::Brenier::NewStub(grpc::CreateChannel("127.0.0.1:" + std::to_string(port),
                                                       grpc::InsecureChannelCredentials()));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + 60s);
  pb::WatchJobRequest req;
  req.set_id(job.id());
  auto reader = stub->WatchJob(&ctx, req);
  pb::JobEvent e, last;
  int n = 0;
  while (reader->Read(&e)) last = e, ++n;
  const grpc::Status status = reader->Finish();
  ASSERT_TRUE(status.ok()) << status.error_code() << " " << status.error_message();
  ASSERT_GT(n, 0);
  EXPECT_EQ(last.state(), pb::SUCCEEDED) << "the stream must end with the terminal event, got "
                                         << pb::JobState_Name(last.state());
  server->Shutdown();
}

// Race 2. An upload found the blob present, then a DeleteMesh of another tenant's last row
// removed it, then the upload inserted its row: a mesh whose bytes were gone. The hook runs
// the delete in the window and gives it time to finish there.
TEST_F(Fixture, UploadRacingADeleteNeverLeavesAMeshWithoutItsBytes) {
  const std::unique_ptr<Store> owned = open_store(dir, brenier::test::test_database(dir));
  Store& store = *owned;
  Manager manager(store, manager_options(1, 4));
  const std::string bytes = disk_bytes(5);
  const pb::Mesh a = upload(manager, "alice", bytes);
  ASSERT_TRUE(store.has_blob(Store::Blob::kMesh, a.id()));

  std::future<bool> deleted;
  test_hooks::arm(test_hooks::Point::kMeshBeforeRow, [&] {
    deleted = std::async(std::launch::async, [&] { return store.delete_mesh("alice", a.id()); });
    // Fixed: the delete waits for the writer's lock this upload holds, so this times out.
    (void)deleted.wait_for(300ms);
  });
  const pb::Mesh b = upload(manager, "bob", bytes);
  ASSERT_TRUE(deleted.valid()) << "the hook did not run";
  EXPECT_TRUE(deleted.get());
  EXPECT_FALSE(store.get_mesh("alice", a.id()).has_value());
  ASSERT_TRUE(store.get_mesh("bob", b.id()).has_value());
  EXPECT_TRUE(store.has_blob(Store::Blob::kMesh, b.id())) << "bob's mesh row outlived its blob";
  // And bob's mesh still maps.
  const pb::Job job = manager.submit("bob", map_request(b.id()));
  EXPECT_EQ(wait_terminal(manager, "bob", job.id(), 60s).state(), pb::SUCCEEDED);
}

// Found by fuzz_service under CI: a job read its mesh's row, the mesh was deleted, and the
// job's read of the bytes then failed with INTERNAL. A deleted mesh is the client's doing: the
// job fails with INVALID_ARGUMENT saying so. The hook deletes between the row and the bytes.
TEST_F(Fixture, AMeshDeletedWhileAJobLoadsItFailsTheJobAsDeleted) {
  const std::unique_ptr<Store> owned = open_store(dir, brenier::test::test_database(dir));
  Store& store = *owned;
  Manager manager(store, manager_options(1, 4));
  const pb::Mesh mesh = upload(manager, "alice", disk_bytes(5));
  bool deleted = false;
  test_hooks::arm(test_hooks::Point::kLoadAfterRow, [&] { deleted = store.delete_mesh("alice", mesh.id()); });
  const pb::Job job = manager.submit("alice", map_request(mesh.id()));
  const pb::Job done = wait_terminal(manager, "alice", job.id(), 60s);
  ASSERT_TRUE(deleted) << "the hook did not run";
  EXPECT_EQ(done.state(), pb::FAILED);
  EXPECT_EQ(done.error().code(), static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT)) << done.error().message();
  EXPECT_NE(done.error().message().find("was deleted"), std::string::npos) << done.error().message();
}

// Race 3. With the queue full, a submission inserted its row, found no place and deleted the
// row: a resubmission with the same request_id in between was handed that job, which then
// vanished. The hook (after the row exists) makes the resubmission there.
TEST_F(Fixture, ASubmissionRefusedByAFullQueueLeavesNoJobBehind) {
  const std::unique_ptr<Store> owned = open_store(dir, brenier::test::test_database(dir));
  Store& store = *owned;
  Manager manager(store, manager_options(1, 1));
  const pb::Mesh mesh = upload(manager, "", disk_bytes(5));
  // The worker holds the first job until released; the second fills the queue.
  std::promise<void> taken, release;
  std::shared_future<void> release_f = release.get_future().share();
  test_hooks::arm(test_hooks::Point::kRunStart, [&taken, release_f] {
    taken.set_value();
    release_f.wait_for(30s);
  });
  const pb::Job first = manager.submit("", map_request(mesh.id()));
  ASSERT_EQ(taken.get_future().wait_for(30s), std::future_status::ready);
  const pb::Job second = manager.submit("", map_request(mesh.id()));

  std::optional<pb::Job> handed;
  test_hooks::arm(test_hooks::Point::kSubmitAfterInsert, [&] {
    try {
      handed = manager.submit("", map_request(mesh.id(), "retry-1"));
    } catch (const Error&) {
    }
  });
  std::optional<ErrorCode> code;
  try {
    (void)manager.submit("", map_request(mesh.id(), "retry-1"));
  } catch (const Error& e) {
    code = e.code();
  }
  test_hooks::disarm_all();
  EXPECT_EQ(code, ErrorCode::kResourceExhausted);
  if (handed) {
    EXPECT_TRUE(store.get_job("", handed->id()).has_value())
        << "a resubmission was handed job " << handed->id() << ", which then vanished";
  }
  // The request_id is free again: once there is room it is accepted and runs.
  release.set_value();
  EXPECT_EQ(wait_terminal(manager, "", first.id(), 60s).state(), pb::SUCCEEDED);
  pb::Job again;
  for (int i = 0; i < 600; ++i) {
    try {
      again = manager.submit("", map_request(mesh.id(), "retry-1"));
      break;
    } catch (const Error& e) {
      ASSERT_EQ(e.code(), ErrorCode::kResourceExhausted) << e.what();
      std::this_thread::sleep_for(50ms);
    }
  }
  ASSERT_FALSE(again.id().empty());
  EXPECT_EQ(wait_terminal(manager, "", again.id(), 60s).state(), pb::SUCCEEDED);
  EXPECT_EQ(wait_terminal(manager, "", second.id(), 60s).state(), pb::SUCCEEDED);
}

// A kill between a blob and its row leaves a blob nothing names; the sweep at start removes
// those and only those.
TEST_F(Fixture, TheStartSweepRemovesOnlyBlobsNothingNames) {
  std::string kept_mesh, kept_result, orphan_mesh, orphan_result;
  {
    const std::unique_ptr<Store> owned = open_store(dir, brenier::test::test_database(dir));
  Store& store = *owned;
    Manager manager(store, manager_options(1, 4));
    kept_mesh = upload(manager, "default", disk_bytes(4)).id();
    const pb::Job job = manager.submit("default", map_request(kept_mesh));
    const pb::Job done = wait_terminal(manager, "default", job.id(), 60s);
    ASSERT_EQ(done.state(), pb::SUCCEEDED);
    kept_result = done.result().artifacts(0).sha256();
    // What a kill -9 leaves: bytes written, their row never.
    orphan_mesh = store.put_blob(Store::Blob::kMesh, disk_bytes(7));
    orphan_result = store.put_blob(Store::Blob::kResult, "a report of a run that was run again");
  }
  const std::unique_ptr<Store> owned = open_store(dir, brenier::test::test_database(dir));
  Store& store = *owned;
  EXPECT_EQ(store.sweep_orphaned_blobs(), 2);
  EXPECT_TRUE(store.has_blob(Store::Blob::kMesh, kept_mesh));
  EXPECT_TRUE(store.has_blob(Store::Blob::kResult, kept_result));
  EXPECT_FALSE(store.has_blob(Store::Blob::kMesh, orphan_mesh));
  EXPECT_FALSE(store.has_blob(Store::Blob::kResult, orphan_result));
  EXPECT_EQ(store.sweep_orphaned_blobs(), 0);
}

}  // namespace

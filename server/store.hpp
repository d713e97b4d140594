// brenierd's persistence on embedded defaults: SQLite (WAL) for mesh and job metadata and a
// content-addressed blob directory (write a temporary file, fsync, rename). A server killed
// at any moment restarts with every blob whole or absent (a rename is atomic) and every
// committed row intact (WAL survives the process; synchronous=NORMAL only risks the last
// commits on a power cut, not on a crash).
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "brenier/v1/brenier.pb.h"

struct sqlite3;
struct sqlite3_stmt;

namespace brenier::server {

namespace pb = ::brenier::v1;

class Store {
 public:
  /// Opens (creating) DIR/brenier.db, DIR/blobs and DIR/tmp; leftover temporary files of an
  /// earlier run are removed. Throws Error(kInvalidArgument) when the directory is unusable.
  explicit Store(const std::string& dir);
  ~Store();
  Store(const Store&) = delete;
  Store& operator=(const Store&) = delete;

  const std::string& dir() const { return dir_; }
  /// The schema version this build writes (its number of migration steps). A database of a
  /// higher version is refused at open (Error(kFailedPrecondition)); a lower one is migrated.
  static int schema_version();

  // ---- blobs ----
  /// Two content-addressed namespaces: uploaded meshes (removed with the last mesh row that
  /// names them) and job results (kept with their jobs). Separate, so that deleting a mesh
  /// whose bytes happen to equal a result (a downloaded map uploaded again) keeps the result.
  enum class Blob { kMesh, kResult };
  /// A fresh path under DIR/tmp for a scratch file.
  std::string temp_path();
  /// Writes `bytes` as a blob (a temporary file, fsync, rename: whole or absent after a
  /// crash; a blob already there is kept) and returns its SHA-256, computed unless the
  /// caller already has it.
  std::string put_blob(Blob kind, const std::string& bytes, const std::string& sha256 = "");
  std::string blob_path(Blob kind, const std::string& sha256) const;
  bool has_blob(Blob kind, const std::string& sha256) const;

  // ---- meshes (per tenant; one blob may back several tenants' rows) ----
  /// Stores the mesh's bytes as its blob (named by mesh.id(), their SHA-256) and inserts the
  /// row, or returns the row the tenant already has for that id. Atomic with delete_mesh:
  /// every row has its blob.
  pb::Mesh put_mesh_with_blob(const std::string& tenant, const pb::Mesh& mesh, const std::string& bytes);
  std::optional<pb::Mesh> get_mesh(const std::string& tenant, const std::string& id);
  /// Up to `limit` meshes after the page token (empty: from the start); `next` gets the
  /// token of the following page, empty at the end.
  std::vector<pb::Mesh> list_meshes(const std::string& tenant, const std::string& token, int limit, std::string& next);
  /// Removes the tenant's row; the blob too when no row refers to it. False when absent.
  bool delete_mesh(const std::string& tenant, const std::string& id);

  // ---- jobs ----
  /// Inserts a new job (its id, request_id and spec set), unless the tenant already has a job
  /// with that non-empty request_id: then that job is returned and `inserted` is false.
  /// With `max_unfinished` > 0, a tenant with that many jobs queued or running gets
  /// Error(kResourceExhausted) naming the quota instead.
  pb::Job insert_job(const std::string& tenant, const pb::Job& job, bool& inserted, int max_unfinished = 0);
  std::optional<pb::Job> get_job(const std::string& tenant, const std::string& id);
  /// Whether the tenant has a job submitted with this request_id.
  bool has_request(const std::string& tenant, const std::string& request_id);
  /// The job whatever its tenant (the server's own use), with its tenant.
  std::optional<pb::Job> get_job_any(const std::string& id, std::string* tenant = nullptr);
  std::vector<pb::Job> list_jobs(const std::string& tenant, pb::JobState state, const std::string& token, int limit,
                                 std::string& next);
  void update_job(const pb::Job& job);
  /// Removes a job row (a submission the full queue refused).
  void delete_job(const std::string& id);
  /// Removes the blobs no mesh row or job artifact names (left by a kill between a blob and
  /// its row); returns how many. Call before serving.
  int sweep_orphaned_blobs();
  /// Removes the jobs that finished before `finished_before` (seconds since the epoch), and
  /// the result blobs no remaining job names unless written (or put again) within `spare`:
  /// a job finishing now may record the same bytes. Returns how many jobs.
  int expire_jobs(int64_t finished_before, std::chrono::seconds spare);
  /// The bytes the tenant holds: its meshes' uploads and its jobs' results.
  int64_t storage_bytes(const std::string& tenant);
  /// Queued and running jobs of every tenant, oldest first.
  std::vector<std::string> unfinished_jobs();

 /// One SQLite connection with its prepared statements (kept: preparing is most of a small
  /// query's cost) and its own lock.
  struct Connection {
    sqlite3* db = nullptr;
    std::mutex mutex;
    std::vector<std::pair<const char*, sqlite3_stmt*>> statements;
    sqlite3_stmt* prepare(const char* sql);
    ~Connection();
  };

 private:
  void exec(const char* sql);
  void migrate();
  std::string write_temp(const std::string& bytes);
  std::string blob_root(Blob kind) const;
  void commit_blob(Blob kind, const std::string& temp, const std::string& sha256);
  /// A reader connection, locked for the caller: WAL lets reads run beside the one writer,
  /// so a GetJob or a submission's mesh lookup never waits behind a job's commit.
  std::unique_lock<std::mutex> reader(Connection*& c);
  std::string dir_;
  Connection writer_;  // every write, and the reads a write depends on
  std::vector<std::unique_ptr<Connection>> readers_;
  std::atomic<unsigned> next_reader_{0};
};

}  // namespace brenier::server

// brenierd's persistence: mesh and job metadata in a database, bytes in a content-addressed
// blob directory under --data (write a temporary file, fsync, rename: a server killed at any
// moment restarts with every blob whole or absent). Two databases implement the rows
// (issue 21): SQLite in DIR/brenier.db, the default that needs no setup (store_sqlite.cpp),
// and PostgreSQL, which several replicas sharing DIR can use at once (store_postgres.cpp).
// open_store picks one. Both version their schema and refuse one a newer brenierd wrote.
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "brenier/v1/brenier.pb.h"

namespace brenier::server {

namespace pb = ::brenier::v1;

class Store {
 public:
  /// Creates DIR/blobs and DIR/tmp; leftover temporary files of an earlier run of this host
  /// are removed. Throws Error(kInvalidArgument) when the directory is unusable.
  explicit Store(const std::string& dir);
  virtual ~Store();
  Store(const Store&) = delete;
  Store& operator=(const Store&) = delete;

  const std::string& dir() const { return dir_; }
  /// "sqlite" or "postgresql", for the logs.
  virtual const char* backend() const = 0;
  /// The schema version of the open database (after migration: this build's).
  virtual int version() = 0;
  /// Whether the database answers now (for the health service).
  virtual bool healthy() { return true; }

  // ---- blobs (files; the same for both databases) ----
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
  /// The blob's bytes, or nothing when it is absent (a mesh deleted meanwhile): opening is the
  /// check, so a delete between a check and the read cannot turn into a failed read.
  std::optional<std::string> read_blob(Blob kind, const std::string& sha256) const;

  // ---- meshes (per tenant; one blob may back several tenants' rows) ----
  /// Stores the mesh's bytes as its blob (named by mesh.id(), their SHA-256) and inserts the
  /// row, or returns the row the tenant already has for that id. Atomic with delete_mesh
  /// (in every process sharing the database): every row has its blob.
  virtual pb::Mesh put_mesh_with_blob(const std::string& tenant, const pb::Mesh& mesh, const std::string& bytes) = 0;
  virtual std::optional<pb::Mesh> get_mesh(const std::string& tenant, const std::string& id) = 0;
  /// Up to `limit` meshes after the page token (empty: from the start); `next` gets the
  /// token of the following page, empty at the end.
  virtual std::vector<pb::Mesh> list_meshes(const std::string& tenant, const std::string& token, int limit,
                                            std::string& next) = 0;
  /// Removes the tenant's row; the blob too when no row refers to it. False when absent.
  virtual bool delete_mesh(const std::string& tenant, const std::string& id) = 0;

  // ---- jobs ----
  /// Inserts a new job (its id, request_id and spec set), unless the tenant already has a job
  /// with that non-empty request_id: then that job is returned and `inserted` is false.
  /// With `max_unfinished` > 0, a tenant with that many jobs queued or running gets
  /// Error(kResourceExhausted) naming the quota instead.
  virtual pb::Job insert_job(const std::string& tenant, const pb::Job& job, bool& inserted, int max_unfinished = 0) = 0;
  virtual std::optional<pb::Job> get_job(const std::string& tenant, const std::string& id) = 0;
  /// Whether the tenant has a job submitted with this request_id.
  virtual bool has_request(const std::string& tenant, const std::string& request_id) = 0;
  /// The job whatever its tenant (the server's own use), with its tenant.
  virtual std::optional<pb::Job> get_job_any(const std::string& id, std::string* tenant = nullptr) = 0;
  virtual std::vector<pb::Job> list_jobs(const std::string& tenant, pb::JobState state, const std::string& token,
                                         int limit, std::string& next) = 0;
  /// Writes the job's record; on a shared store only while this replica holds the job
  /// (Error(kUnavailable) when another replica has claimed it meanwhile).
  virtual void update_job(const pb::Job& job) = 0;
  /// Removes a job row (a submission the full queue refused).
  virtual void delete_job(const std::string& id) = 0;
  /// The bytes the tenant holds: its meshes' uploads and its jobs' results.
  virtual int64_t storage_bytes(const std::string& tenant) = 0;
  /// Queued and running jobs of every tenant, oldest first.
  virtual std::vector<std::string> unfinished_jobs() = 0;

  // ---- replicas (PostgreSQL: every brenierd on the database is one service) ----
  // A job belongs to the replica that holds its lease: the one it was submitted to, or the
  // one that claimed it after its holder stopped renewing (died, lost the database, or let
  // it go at a shutdown). With SQLite one process holds everything and these do nothing.
  /// Whether other processes may share this store (then jobs are leased).
  virtual bool shared() const { return false; }
  /// This process's name in the leases.
  virtual std::string replica() const { return ""; }
  /// Extends this replica's leases on `ids`; returns those still this replica's (a lease
  /// that ran out may have been claimed by another).
  virtual std::vector<std::string> renew_leases(const std::vector<std::string>& ids) { return ids; }
  /// Claims up to `limit` unfinished jobs whose lease ran out, oldest first (SELECT ... FOR
  /// UPDATE SKIP LOCKED: replicas claiming at once take different jobs).
  virtual std::vector<std::string> claim_expired(int /*limit*/) { return {}; }
  /// Lets this replica's job go at once (a shutdown requeued it): the next claim takes it.
  virtual void release(const std::string& /*id*/) {}
  /// Marks an unfinished job for cancellation by whichever replica holds it.
  virtual void request_cancel(const std::string& /*id*/) {}
  /// Writes a running job's progress (its record with stage and fraction) for watchers on
  /// other replicas, unless it has left the running state or this replica meanwhile.
  virtual void update_progress(const pb::Job& /*job*/) {}
  /// This replica's unfinished jobs marked for cancellation.
  virtual std::vector<std::string> cancels_requested() { return {}; }

  // ---- collection ----
  /// Removes the blobs no mesh row or job artifact names (left by a kill between a blob and
  /// its row) and were last written more than `min_age` ago (another process sharing DIR may
  /// be between a blob and its row right now); returns how many. Call before serving.
  int sweep_orphaned_blobs(std::chrono::seconds min_age = std::chrono::seconds(0));
  /// Removes the jobs that finished before `finished_before` (seconds since the epoch), and
  /// the result blobs no remaining job names unless written (or put again) within `spare`:
  /// a job finishing now may record the same bytes. Returns how many jobs.
  int expire_jobs(int64_t finished_before, std::chrono::seconds spare);

 protected:
  /// Deletes the jobs finished before `finished_before`; appends their artifacts' blobs.
  virtual int delete_finished_jobs(int64_t finished_before, std::vector<std::string>& blobs) = 0;
  /// The mesh ids rows name and the result blobs jobs' artifacts name.
  virtual void named_blobs(std::set<std::string>& meshes, std::set<std::string>& results) = 0;
  std::string write_temp(const std::string& bytes);
  void commit_blob(Blob kind, const std::string& temp, const std::string& sha256);
  void remove_blob(Blob kind, const std::string& sha256);

 private:
  std::string blob_root(Blob kind) const;
  std::string dir_;
};

/// The store on DIR: SQLite in DIR/brenier.db when `database` is empty, else PostgreSQL at
/// `database` (postgresql://USER[:PASS]@HOST:PORT/DB). Migrates the schema. Throws
/// Error(kUnavailable) when the database cannot be reached (its URL in the message, the
/// password elided), Error(kFailedPrecondition) when a newer brenierd wrote it.
/// `lease_seconds`: how long a replica's claim on a job lasts without renewal (PostgreSQL).
std::unique_ptr<Store> open_store(const std::string& dir, const std::string& database = "", double lease_seconds = 30);

/// The URL with its password, if any, replaced by "***" (for messages and logs).
std::string elide_password(const std::string& url);

/// The schema version this build writes on each backend (its number of migration steps).
int sqlite_schema_version();
int postgres_schema_version();

}  // namespace brenier::server

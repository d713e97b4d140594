// The PostgreSQL store (issue 21): the rows in a PostgreSQL database that any number of
// brenierd processes sharing one --data directory use at once, through libpq. What the
// SQLite store does under its writer's lock happens here under PostgreSQL's advisory locks,
// which every process sees: a mesh's id while its blob and row are put or deleted, a tenant
// while its job quota is counted with the insert, the schema while it is migrated.
//
// A small pool of connections; a connection found broken is reset before use, and a call that
// cannot reach the database fails with Error(kUnavailable) (UNAVAILABLE to the client) without
// harming the process: the next call tries again.
#include <libpq-fe.h>

#include <algorithm>
#include <atomic>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <set>

#include <unistd.h>

#include "common/error.hpp"
#include "store.hpp"
#include "store_rows.hpp"
#include "test_hooks.hpp"

namespace brenier::server {
using rows::parse;

namespace {

// Advisory-lock classes (the first key of pg_advisory_lock(int, int)).
constexpr int kSchemaLock = 21001, kMeshLock = 21002, kTenantJobsLock = 21003;

struct Param {
  std::string value;
  bool binary = false;  // a bytea (a serialized record), sent as raw bytes
};
Param record(std::string v) { return {std::move(v), true}; }
Param text(std::string v) { return {std::move(v), false}; }
Param num(int64_t v) { return {std::to_string(v), false}; }

class Result {
 public:
  explicit Result(PGresult* r) : r_(r) {}
  Result(Result&& o) noexcept : r_(o.r_) { o.r_ = nullptr; }
  ~Result() { PQclear(r_); }
  int rows() const { return PQntuples(r_); }
  int64_t affected() const { return std::strtoll(PQcmdTuples(r_), nullptr, 10); }
  std::string text(int row, int col) const { return PQgetvalue(r_, row, col); }
  int64_t integer(int row, int col) const { return std::strtoll(PQgetvalue(r_, row, col), nullptr, 10); }
  std::string bytea(int row, int col) const {
    size_t n = 0;
    unsigned char* p = PQunescapeBytea(reinterpret_cast<const unsigned char*>(PQgetvalue(r_, row, col)), &n);
    if (!p) fail(ErrorCode::kInternal, "database: out of memory decoding a record");
    std::string out(reinterpret_cast<const char*>(p), n);
    PQfreemem(p);
    return out;
  }

 private:
  PGresult* r_;
};

class PostgresStore final : public Store {
 public:
  PostgresStore(const std::string& dir, const std::string& url, double lease_seconds);
  const char* backend() const override { return "postgresql"; }
  int version() override;
  bool healthy() override;

  BRENIER_STORE_ROWS_OVERRIDE

  bool shared() const override { return true; }
  std::string replica() const override { return replica_; }
  std::vector<std::string> renew_leases(const std::vector<std::string>& ids) override;
  std::vector<std::string> claim_expired(int limit) override;
  void release(const std::string& id) override;
  void update_progress(const pb::Job& job) override;
  void request_cancel(const std::string& id) override;
  std::vector<std::string> cancels_requested() override;

 private:
  struct Connection {
    PGconn* conn = nullptr;
    std::mutex mutex;
    // Statements prepared on this connection, by the address of their SQL (string literals
    // only): parsed and planned once, not at every call.
    std::map<const char*, std::string> prepared;
    ~Connection() { PQfinish(conn); }
  };
  /// A connection of the pool, locked for the caller, reset first if it broke.
  class Lease {
   public:
    Lease(PostgresStore& s);
    Result run(const char* sql, const std::vector<Param>& params = {});
    /// The statement in a transaction of its own with `body` (BEGIN ... COMMIT; ROLLBACK on a throw).
    template <class F>
    auto transaction(F&& body) {
      run("BEGIN");
      try {
        auto out = body();
        run("COMMIT");
        return out;
      } catch (...) {
        PQclear(PQexec(c_->conn, "ROLLBACK"));
        throw;
      }
    }

   private:
    PostgresStore& s_;
    Connection* c_ = nullptr;
    std::unique_lock<std::mutex> lock_;
  };
  // A session advisory lock on (kind, key), released by the destructor.
  class AdvisoryLock {
   public:
    AdvisoryLock(Lease& l, int kind, const std::string& key) : l_(l), kind_(kind), key_(key) {
      l_.run("SELECT pg_advisory_lock($1, hashtext($2))", {num(kind_), text(key_)});
    }
    ~AdvisoryLock() {
      try {
        l_.run("SELECT pg_advisory_unlock($1, hashtext($2))", {num(kind_), text(key_)});
      } catch (...) {  // the connection broke: the server released the lock with the session
      }
    }

   private:
    Lease& l_;
    int kind_;
    std::string key_;
  };

  [[noreturn]] void unavailable(const std::string& why) const;
  PGconn* connect() const;
  void migrate();
  template <class M>
  std::optional<M> first_record(const char* sql, const std::vector<Param>& params);
  template <class M>
  std::vector<M> page_of(const char* sql, const std::vector<Param>& params, int limit, std::string& next);

  std::string url_;
  int64_t lease_ms_;
  std::string replica_;  // HOST.PID.RANDOM: a restarted process is a new replica
  std::vector<std::unique_ptr<Connection>> pool_;
  std::atomic<unsigned> next_{0};
};

void PostgresStore::unavailable(const std::string& why) const {
  std::string w = why;
  while (!w.empty() && (w.back() == '\n' || w.back() == ' ')) w.pop_back();
  std::replace(w.begin(), w.end(), '\n', ' ');
  fail(ErrorCode::kUnavailable, "the database " + elide_password(url_) + " is unavailable: " + w);
}

PGconn* PostgresStore::connect() const {
  // The URL's own connect_timeout wins; without one, a dead host is given up after 5 s.
  const std::string url = url_ + (url_.find("connect_timeout") == std::string::npos
                                      ? (url_.find('?') == std::string::npos ? "?" : "&") + std::string("connect_timeout=5")
                                      : "");
  PGconn* c = PQconnectdb(url.c_str());
  if (PQstatus(c) != CONNECTION_OK) {
    const std::string why = c ? PQerrorMessage(c) : "out of memory";
    PQfinish(c);
    unavailable(why);
  }
  PQclear(PQexec(c, "SET client_min_messages = warning"));
  return c;
}

PostgresStore::Lease::Lease(PostgresStore& s) : s_(s) {
  const size_t n = s.pool_.size();
  const unsigned start = s.next_.fetch_add(1);
  for (size_t k = 0; k < n && !c_; ++k) {
    Connection& c = *s.pool_[(start + k) % n];
    std::unique_lock<std::mutex> lock(c.mutex, std::try_to_lock);
    if (lock.owns_lock()) {
      c_ = &c;
      lock_ = std::move(lock);
    }
  }
  if (!c_) {
    c_ = s.pool_[start % n].get();
    lock_ = std::unique_lock<std::mutex>(c_->mutex);
  }
  if (!c_->conn || PQstatus(c_->conn) != CONNECTION_OK) {
    PQfinish(c_->conn);
    c_->conn = nullptr;
    c_->prepared.clear();
    c_->conn = s.connect();
  }
}

Result PostgresStore::Lease::run(const char* sql, const std::vector<Param>& params) {
  std::vector<const char*> values;
  std::vector<int> lengths, formats;
  for (const Param& p : params) {
    values.push_back(p.value.c_str());
    lengths.push_back(static_cast<int>(p.value.size()));
    formats.push_back(p.binary ? 1 : 0);
  }
  // Without parameters, the simple protocol: it takes several statements (a migration step).
  // With them, a statement prepared on this connection at its first use.
  PGresult* r = nullptr;
  if (params.empty()) {
    r = PQexec(c_->conn, sql);
  } else {
    auto it = c_->prepared.find(sql);
    if (it == c_->prepared.end()) {
      const std::string name = "s" + std::to_string(c_->prepared.size());
      PGresult* p = PQprepare(c_->conn, name.c_str(), sql, static_cast<int>(params.size()), nullptr);
      const bool ok = PQresultStatus(p) == PGRES_COMMAND_OK;
      PQclear(p);
      if (ok) it = c_->prepared.emplace(sql, name).first;
    }
    r = it != c_->prepared.end()
            ? PQexecPrepared(c_->conn, it->second.c_str(), static_cast<int>(params.size()), values.data(),
                             lengths.data(), formats.data(), 0)
            : PQexecParams(c_->conn, sql, static_cast<int>(params.size()), nullptr, values.data(), lengths.data(),
                           formats.data(), 0);  // the preparation failed: this reports why
  }
  const ExecStatusType status = PQresultStatus(r);
  if (status == PGRES_COMMAND_OK || status == PGRES_TUPLES_OK) return Result(r);
  const std::string why = r ? PQresultErrorMessage(r) : PQerrorMessage(c_->conn);
  const char* state = r ? PQresultErrorField(r, PG_DIAG_SQLSTATE) : nullptr;
  PQclear(r);
  // Class 08 (connection exceptions), 57P (operator intervention: a shutdown, a crash) or a
  // connection now broken: the database is away, not wrong.
  const bool away = PQstatus(c_->conn) != CONNECTION_OK ||
                    (state && (std::strncmp(state, "08", 2) == 0 || std::strncmp(state, "57P", 3) == 0));
  if (away) s_.unavailable(why);
  fail(ErrorCode::kInternal, "database: " + why);
}

// ---- schema ----

// The steps from each version to the next, as in the SQLite store (only ever appended). The
// version is the one row of brenier_schema. The first step is the SQLite store's schema at
// its version 3 (PostgreSQL came later, so it starts there).
const char* const kMigrations[] = {
    "CREATE TABLE meshes (seq BIGSERIAL PRIMARY KEY, tenant TEXT NOT NULL, id TEXT NOT NULL, record BYTEA NOT NULL,"
    " size_bytes BIGINT NOT NULL DEFAULT 0, UNIQUE (tenant, id));"
    "CREATE INDEX meshes_id ON meshes (id);"
    "CREATE TABLE jobs (seq BIGSERIAL PRIMARY KEY, id TEXT NOT NULL UNIQUE, tenant TEXT NOT NULL,"
    " request_id TEXT NOT NULL, state INTEGER NOT NULL, record BYTEA NOT NULL,"
    " result_bytes BIGINT NOT NULL DEFAULT 0, finished_at BIGINT NOT NULL DEFAULT 0);"
    "CREATE UNIQUE INDEX jobs_request ON jobs (tenant, request_id) WHERE request_id <> '';"
    "CREATE INDEX jobs_tenant_state ON jobs (tenant, state);"
    "CREATE INDEX jobs_state ON jobs (state);"
    "CREATE INDEX jobs_finished ON jobs (finished_at) WHERE finished_at > 0;",
    // 1 -> 2: leases (the replica holding a job, until when, in ms of the database's clock)
    // and cancellations asked through another replica. States 1 and 2: queued, running.
    "ALTER TABLE jobs ADD COLUMN owner TEXT NOT NULL DEFAULT '';"
    "ALTER TABLE jobs ADD COLUMN lease_until BIGINT NOT NULL DEFAULT 0;"
    "ALTER TABLE jobs ADD COLUMN cancel BOOLEAN NOT NULL DEFAULT false;"
    "CREATE INDEX jobs_unfinished ON jobs (owner, lease_until) WHERE state IN (1, 2);",
};

// Now in ms on the database's clock: leases never compare two hosts' clocks.
#define BRENIER_PG_NOW_MS "(EXTRACT(EPOCH FROM clock_timestamp()) * 1000)::BIGINT"

}  // namespace

int postgres_schema_version() { return static_cast<int>(std::size(kMigrations)); }

namespace {

std::string replica_name() {
  char host[256] = {};
  if (::gethostname(host, sizeof host - 1) != 0) std::strcpy(host, "host");
  std::random_device rd;
  char tail[16];
  std::snprintf(tail, sizeof tail, "%08x", rd());
  return std::string(host) + "." + std::to_string(::getpid()) + "." + tail;
}

PostgresStore::PostgresStore(const std::string& dir, const std::string& url, double lease_seconds)
    : Store(dir), url_(url), lease_ms_(static_cast<int64_t>(lease_seconds * 1000)), replica_(replica_name()) {
  for (int k = 0; k < 8; ++k) pool_.push_back(std::make_unique<Connection>());
  pool_[0]->conn = connect();  // unreachable: fail now, with the URL
  migrate();
}

int PostgresStore::version() {
  Lease l(*this);
  const Result r = l.run("SELECT version FROM brenier_schema");
  return r.rows() ? static_cast<int>(r.integer(0, 0)) : 0;
}

bool PostgresStore::healthy() {
  try {
    Lease l(*this);
    l.run("SELECT 1");
    return true;
  } catch (const Error&) {
    return false;
  }
}

// Under the schema's advisory lock (replicas starting together migrate once), one step per
// transaction; a database at a newer version is refused.
void PostgresStore::migrate() {
  Lease l(*this);
  AdvisoryLock schema(l, kSchemaLock, "schema");
  l.run("CREATE TABLE IF NOT EXISTS brenier_schema (version INTEGER NOT NULL)");
  l.transaction([&] {
    if (l.run("SELECT 1 FROM brenier_schema").rows() == 0) l.run("INSERT INTO brenier_schema VALUES (0)");
    return 0;
  });
  const Result v = l.run("SELECT version FROM brenier_schema");
  int version = static_cast<int>(v.integer(0, 0));
  if (version > postgres_schema_version()) rows::refuse_newer(elide_password(url_), version, postgres_schema_version());
  for (; version < postgres_schema_version(); ++version) {
    l.transaction([&] {
      l.run(kMigrations[version]);
      l.run("UPDATE brenier_schema SET version = $1", {num(version + 1)});
      return 0;
    });
  }
}

// ---- rows ----

template <class M>
std::optional<M> PostgresStore::first_record(const char* sql, const std::vector<Param>& params) {
  Lease l(*this);
  const Result r = l.run(sql, params);
  if (r.rows() == 0) return std::nullopt;
  return parse<M>(r.bytea(0, 0));
}

template <class M>
std::vector<M> PostgresStore::page_of(const char* sql, const std::vector<Param>& params, int limit, std::string& next) {
  Lease l(*this);
  const Result r = l.run(sql, params);
  int row = 0;
  return rows::page<M>(
      [&](int64_t& seq, std::string& record) {
        if (row == r.rows()) return false;
        seq = r.integer(row, 0);
        record = r.bytea(row, 1);
        ++row;
        return true;
      },
      limit, next);
}

constexpr const char* kMeshById = "SELECT record FROM meshes WHERE tenant = $1 AND id = $2";

pb::Mesh PostgresStore::put_mesh_with_blob(const std::string& tenant, const pb::Mesh& mesh, const std::string& bytes) {
  // As in the SQLite store, with the mesh id's advisory lock for the writer's lock: the long
  // write goes first, outside it; the blob's check and rename and the row go in under it.
  std::string temp;
  if (!has_blob(Blob::kMesh, mesh.id())) temp = write_temp(bytes);
  Lease l(*this);
  AdvisoryLock lock(l, kMeshLock, mesh.id());
  if (temp.empty() && !has_blob(Blob::kMesh, mesh.id())) temp = write_temp(bytes);  // deleted meanwhile
  if (!temp.empty()) commit_blob(Blob::kMesh, temp, mesh.id());
  test_hooks::at(test_hooks::Point::kMeshBeforeRow);
  l.run("INSERT INTO meshes (tenant, id, record, size_bytes) VALUES ($1, $2, $3, $4) ON CONFLICT DO NOTHING",
        {text(tenant), text(mesh.id()), record(mesh.SerializeAsString()), num(mesh.size_bytes())});
  const Result r = l.run(kMeshById, {text(tenant), text(mesh.id())});
  if (r.rows() == 0) fail(ErrorCode::kInternal, "database: a mesh just stored is not there");
  return parse<pb::Mesh>(r.bytea(0, 0));
}

std::optional<pb::Mesh> PostgresStore::get_mesh(const std::string& tenant, const std::string& id) {
  return first_record<pb::Mesh>(kMeshById, {text(tenant), text(id)});
}

std::vector<pb::Mesh> PostgresStore::list_meshes(const std::string& tenant, const std::string& token, int limit,
                                                 std::string& next) {
  return page_of<pb::Mesh>("SELECT seq, record FROM meshes WHERE tenant = $1 AND seq > $2 ORDER BY seq LIMIT $3",
                           {text(tenant), num(rows::token_value(token)), num(limit + 1)}, limit, next);
}

bool PostgresStore::delete_mesh(const std::string& tenant, const std::string& id) {
  Lease l(*this);
  AdvisoryLock lock(l, kMeshLock, id);
  if (l.run("DELETE FROM meshes WHERE tenant = $1 AND id = $2", {text(tenant), text(id)}).affected() == 0) return false;
  if (l.run("SELECT 1 FROM meshes WHERE id = $1 LIMIT 1", {text(id)}).rows() == 0) remove_blob(Blob::kMesh, id);
  return true;
}

pb::Job PostgresStore::insert_job(const std::string& tenant, const pb::Job& job, bool& inserted, int max_unfinished) {
  Lease l(*this);
  auto earlier = [&]() -> std::optional<pb::Job> {
    if (job.request_id().empty()) return std::nullopt;
    const Result r = l.run("SELECT record FROM jobs WHERE tenant = $1 AND request_id = $2",
                           {text(tenant), text(job.request_id())});
    if (r.rows() == 0) return std::nullopt;
    return parse<pb::Job>(r.bytea(0, 0));
  };
  auto insert = [&] {
    // A request_id already taken (by a submission to another replica meanwhile) inserts nothing.
    return l.run("INSERT INTO jobs (id, tenant, request_id, state, record, owner, lease_until) "
                 "VALUES ($1, $2, $3, $4, $5, $6, " BRENIER_PG_NOW_MS " + $7) "
                 "ON CONFLICT (tenant, request_id) WHERE request_id <> '' DO NOTHING",
                 {text(job.id()), text(tenant), text(job.request_id()), num(job.state()),
                  record(job.SerializeAsString()), text(replica_), num(lease_ms_)})
               .affected() == 1;
  };
  if (max_unfinished <= 0) {  // one statement: the unique index makes request_id idempotent
    inserted = insert();
    if (inserted) return job;
    if (std::optional<pb::Job> e = earlier()) return *e;
    fail(ErrorCode::kInternal, "database: job " + job.id() + " was neither inserted nor found");
  }
  // With a quota: the tenant's jobs are counted and the job inserted under the tenant's lock
  // (held to the commit), so submissions to two replicas cannot both take the last place.
  return l.transaction([&] {
    l.run("SELECT pg_advisory_xact_lock($1, hashtext($2))", {num(kTenantJobsLock), text(tenant)});
    if (std::optional<pb::Job> e = earlier()) {
      inserted = false;
      return *e;
    }
    const Result n = l.run("SELECT COUNT(*) FROM jobs WHERE tenant = $1 AND state IN ($2, $3)",
                           {text(tenant), num(pb::QUEUED), num(pb::RUNNING)});
    if (n.integer(0, 0) >= max_unfinished) rows::over_job_quota(n.integer(0, 0));
    inserted = insert();
    if (!inserted) fail(ErrorCode::kInternal, "database: job " + job.id() + " was not inserted");
    return job;
  });
}

std::optional<pb::Job> PostgresStore::get_job(const std::string& tenant, const std::string& id) {
  return first_record<pb::Job>("SELECT record FROM jobs WHERE tenant = $1 AND id = $2", {text(tenant), text(id)});
}

bool PostgresStore::has_request(const std::string& tenant, const std::string& request_id) {
  Lease l(*this);
  return l.run("SELECT 1 FROM jobs WHERE tenant = $1 AND request_id = $2", {text(tenant), text(request_id)}).rows() > 0;
}

std::optional<pb::Job> PostgresStore::get_job_any(const std::string& id, std::string* tenant) {
  Lease l(*this);
  const Result r = l.run("SELECT record, tenant FROM jobs WHERE id = $1", {text(id)});
  if (r.rows() == 0) return std::nullopt;
  if (tenant) *tenant = r.text(0, 1);
  return parse<pb::Job>(r.bytea(0, 0));
}

std::vector<pb::Job> PostgresStore::list_jobs(const std::string& tenant, pb::JobState state, const std::string& token,
                                              int limit, std::string& next) {
  return page_of<pb::Job>(
      "SELECT seq, record FROM jobs WHERE tenant = $1 AND seq > $2 AND ($3 = 0 OR state = $3) ORDER BY seq LIMIT $4",
      {text(tenant), num(rows::token_value(token)), num(state), num(limit + 1)}, limit, next);
}

void PostgresStore::update_job(const pb::Job& job) {
  Lease l(*this);
  const Result r = l.run(
      "UPDATE jobs SET state = $1, record = $2, result_bytes = $3, finished_at = $4 WHERE id = $5 AND owner = $6",
      {num(job.state()), record(job.SerializeAsString()), num(rows::result_bytes(job)), num(job.finished().seconds()),
       text(job.id()), text(replica_)});
  if (r.affected() == 0 && l.run("SELECT 1 FROM jobs WHERE id = $1", {text(job.id())}).rows() > 0)
    fail(ErrorCode::kUnavailable, "job " + job.id() + " is held by another replica now (this one's lease ran out)");
}

// A text[] literal of ids (hex digits: nothing to quote).
std::string id_array(const std::vector<std::string>& ids) {
  std::string a = "{";
  for (const std::string& id : ids) a += (a.size() > 1 ? "," : "") + id;
  return a + "}";
}

std::vector<std::string> column(const Result& r) {
  std::vector<std::string> out;
  for (int i = 0; i < r.rows(); ++i) out.push_back(r.text(i, 0));
  return out;
}

std::vector<std::string> PostgresStore::renew_leases(const std::vector<std::string>& ids) {
  if (ids.empty()) return {};
  Lease l(*this);
  return column(l.run("UPDATE jobs SET lease_until = " BRENIER_PG_NOW_MS " + $1 "
                      "WHERE owner = $2 AND id = ANY($3::TEXT[]) AND state IN (1, 2) RETURNING id",
                      {num(lease_ms_), text(replica_), text(id_array(ids))}));
}

std::vector<std::string> PostgresStore::claim_expired(int limit) {
  if (limit <= 0) return {};
  Lease l(*this);
  return column(l.run("UPDATE jobs SET owner = $1, lease_until = " BRENIER_PG_NOW_MS " + $2 WHERE id IN ("
                      "SELECT id FROM jobs WHERE state IN (1, 2) AND lease_until < " BRENIER_PG_NOW_MS
                      " ORDER BY seq LIMIT $3 FOR UPDATE SKIP LOCKED) RETURNING id",
                      {text(replica_), num(lease_ms_), num(limit)}));
}

void PostgresStore::release(const std::string& id) {
  Lease l(*this);
  l.run("UPDATE jobs SET owner = '', lease_until = 0 WHERE id = $1 AND owner = $2", {text(id), text(replica_)});
}

void PostgresStore::update_progress(const pb::Job& job) {
  Lease l(*this);
  // Only over a running row of this replica's: never over a terminal or requeued state.
  l.run("UPDATE jobs SET record = $1 WHERE id = $2 AND owner = $3 AND state = 2",
        {record(job.SerializeAsString()), text(job.id()), text(replica_)});
}

void PostgresStore::request_cancel(const std::string& id) {
  Lease l(*this);
  l.run("UPDATE jobs SET cancel = true WHERE id = $1 AND state IN (1, 2)", {text(id)});
}

std::vector<std::string> PostgresStore::cancels_requested() {
  Lease l(*this);
  return column(l.run("SELECT id FROM jobs WHERE owner = $1 AND cancel AND state IN (1, 2)", {text(replica_)}));
}

void PostgresStore::delete_job(const std::string& id) {
  Lease l(*this);
  l.run("DELETE FROM jobs WHERE id = $1", {text(id)});
}

int64_t PostgresStore::storage_bytes(const std::string& tenant) {
  Lease l(*this);
  const Result r = l.run(
      "SELECT (SELECT COALESCE(SUM(size_bytes), 0) FROM meshes WHERE tenant = $1) + "
      "(SELECT COALESCE(SUM(result_bytes), 0) FROM jobs WHERE tenant = $1)",
      {text(tenant)});
  return r.integer(0, 0);
}

std::vector<std::string> PostgresStore::unfinished_jobs() {
  Lease l(*this);
  return column(l.run("SELECT id FROM jobs WHERE state IN ($1, $2) ORDER BY seq", {num(pb::QUEUED), num(pb::RUNNING)}));
}

int PostgresStore::delete_finished_jobs(int64_t finished_before, std::vector<std::string>& blobs) {
  Lease l(*this);
  const Result r =
      l.run("DELETE FROM jobs WHERE finished_at > 0 AND finished_at < $1 RETURNING record", {num(finished_before)});
  for (int i = 0; i < r.rows(); ++i) {
    const pb::Job job = parse<pb::Job>(r.bytea(i, 0));
    for (const pb::Artifact& a : job.result().artifacts()) blobs.push_back(a.sha256());
  }
  return r.rows();
}

void PostgresStore::named_blobs(std::set<std::string>& meshes, std::set<std::string>& results) {
  Lease l(*this);
  const Result m = l.run("SELECT DISTINCT id FROM meshes");
  for (int i = 0; i < m.rows(); ++i) meshes.insert(m.text(i, 0));
  const Result j = l.run("SELECT record FROM jobs");
  for (int i = 0; i < j.rows(); ++i) {
    const pb::Job job = parse<pb::Job>(j.bytea(i, 0));
    for (const pb::Artifact& a : job.result().artifacts()) results.insert(a.sha256());
  }
}

}  // namespace

std::unique_ptr<Store> open_postgres_store(const std::string& dir, const std::string& url, double lease_seconds) {
  return std::make_unique<PostgresStore>(dir, url, lease_seconds);
}

}  // namespace brenier::server

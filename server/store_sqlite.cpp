// The SQLite store (issue 21's default backend): DIR/brenier.db in WAL mode, one writer
// connection (every write, and the reads a write depends on, under its lock) and a few reader
// connections, so that a GetJob never waits behind a job's commit. WAL survives the process;
// synchronous=NORMAL only risks the last commits on a power cut, not on a crash. One process
// owns DIR (replicas need PostgreSQL).
#include <sqlite3.h>

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <mutex>
#include <set>

#include "common/error.hpp"
#include "common/hash.hpp"
#include "store.hpp"
#include "store_rows.hpp"
#include "test_hooks.hpp"

namespace brenier::server {
namespace fs = std::filesystem;
using rows::parse;

namespace {

class SqliteStore final : public Store {
 public:
  explicit SqliteStore(const std::string& dir);
  const char* backend() const override { return "sqlite"; }
  int version() override;

  BRENIER_STORE_ROWS_OVERRIDE

  /// One SQLite connection with its prepared statements (kept: preparing is most of a small
  /// query's cost; keyed by the SQL's address, so only string literals are passed) and its
  /// own lock.
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
  /// A reader connection, locked for the caller: WAL lets reads run beside the one writer.
  std::unique_lock<std::mutex> reader(Connection*& c);
  Connection writer_;
  std::vector<std::unique_ptr<Connection>> readers_;
  std::atomic<unsigned> next_reader_{0};
};

// A prepared statement that finalizes itself; errors become Error(kInternal) naming SQLite's
// message (a broken database is ours to fix, not the client's).
class Stmt {
 public:
  Stmt(SqliteStore::Connection& c, const char* sql) : db_(c.db), s_(c.prepare(sql)) {}
  ~Stmt() {
    sqlite3_reset(s_);
    sqlite3_clear_bindings(s_);
  }
  Stmt& text(int i, const std::string& v) {
    sqlite3_bind_text(s_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT);
    return *this;
  }
  Stmt& blob(int i, const std::string& v) {
    sqlite3_bind_blob(s_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT);
    return *this;
  }
  Stmt& integer(int i, int64_t v) {
    sqlite3_bind_int64(s_, i, v);
    return *this;
  }
  /// True while a row is there.
  bool step() {
    const int rc = sqlite3_step(s_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    fail(ErrorCode::kInternal, std::string("database: ") + sqlite3_errmsg(db_));
  }
  std::string column_blob(int i) {
    const void* p = sqlite3_column_blob(s_, i);
    return p ? std::string(static_cast<const char*>(p), static_cast<size_t>(sqlite3_column_bytes(s_, i))) : std::string();
  }
  std::string column_text(int i) {
    const unsigned char* p = sqlite3_column_text(s_, i);
    return p ? std::string(reinterpret_cast<const char*>(p)) : std::string();
  }
  int64_t column_int(int i) { return sqlite3_column_int64(s_, i); }

 private:
  sqlite3* db_;
  sqlite3_stmt* s_;
};

constexpr const char* kMeshById = "SELECT record FROM meshes WHERE tenant = ? AND id = ?";

// The record of the first row a query with two text parameters finds, if any.
template <class M>
std::optional<M> first_record(SqliteStore::Connection& c, const char* sql, const std::string& a, const std::string& b) {
  Stmt s(c, sql);
  s.text(1, a).text(2, b);
  if (!s.step()) return std::nullopt;
  return parse<M>(s.column_blob(0));
}

// A page of rows (seq, record): see rows::page.
template <class M>
std::vector<M> page_of(Stmt& s, int limit, std::string& next) {
  return rows::page<M>(
      [&s](int64_t& seq, std::string& record) {
        if (!s.step()) return false;
        seq = s.column_int(0);
        record = s.column_blob(1);
        return true;
      },
      limit, next);
}

// The result blobs the jobs' artifacts name.
std::set<std::string> result_blobs_named(SqliteStore::Connection& c) {
  std::set<std::string> named;
  Stmt j(c, "SELECT record FROM jobs");
  while (j.step()) {
    const pb::Job job = parse<pb::Job>(j.column_blob(0));  // named: a range-for keeps only its last temporary
    for (const pb::Artifact& a : job.result().artifacts()) named.insert(a.sha256());
  }
  return named;
}

}  // namespace

sqlite3_stmt* SqliteStore::Connection::prepare(const char* sql) {
  for (auto& [text, stmt] : statements)
    if (text == sql) return stmt;
  sqlite3_stmt* stmt = nullptr;
  if (sqlite3_prepare_v3(db, sql, -1, SQLITE_PREPARE_PERSISTENT, &stmt, nullptr) != SQLITE_OK)
    fail(ErrorCode::kInternal, std::string("database: ") + sqlite3_errmsg(db));
  statements.emplace_back(sql, stmt);
  return stmt;
}

SqliteStore::Connection::~Connection() {
  for (auto& [text, stmt] : statements) sqlite3_finalize(stmt);
  sqlite3_close(db);
}

namespace {
sqlite3* open_db(const std::string& dir) {
  sqlite3* db = nullptr;
  if (sqlite3_open_v2((dir + "/brenier.db").c_str(), &db, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX,
                      nullptr) != SQLITE_OK) {
    const std::string msg = db ? sqlite3_errmsg(db) : "out of memory";
    sqlite3_close(db);
    invalid("cannot open the database in " + dir + ": " + msg);
  }
  sqlite3_busy_timeout(db, 10000);
  return db;
}
}  // namespace

std::unique_lock<std::mutex> SqliteStore::reader(Connection*& c) {
  const size_t n = readers_.size();
  const unsigned start = next_reader_.fetch_add(1);
  for (size_t k = 0; k < n; ++k) {
    Connection& r = *readers_[(start + k) % n];
    std::unique_lock<std::mutex> lock(r.mutex, std::try_to_lock);
    if (lock.owns_lock()) {
      c = &r;
      return lock;
    }
  }
  c = readers_[start % n].get();
  return std::unique_lock<std::mutex>(c->mutex);
}

SqliteStore::SqliteStore(const std::string& dir) : Store(dir) {
  writer_.db = open_db(dir);
  exec("PRAGMA journal_mode=WAL");
  exec("PRAGMA synchronous=NORMAL");
  migrate();
  for (int k = 0; k < 4; ++k) {
    readers_.push_back(std::make_unique<Connection>());
    readers_.back()->db = open_db(dir);
  }
}

namespace {

// The schema, as the steps from each version to the next: step k takes a database at
// version k to k + 1 (its SQL, then its C++ part over the rows, if any). A database's
// version is SQLite's user_version; version 0 is a new database or one written before
// versions were kept (its tables, if any, are version 1's, which the first step creates
// only where missing). Steps are only ever appended.
struct Migration {
  const char* sql;
  void (*rows)(SqliteStore::Connection& c);
};

// A column filled in from each row's record: `select` yields (seq, record), `update` sets
// the column of one seq.
template <class M, class Value>
void fill_from_records(SqliteStore::Connection& c, const char* select, const char* update, Value value) {
  std::vector<std::pair<int64_t, int64_t>> rows;
  {
    Stmt s(c, select);
    while (s.step()) rows.emplace_back(s.column_int(0), value(parse<M>(s.column_blob(1))));
  }
  for (const auto& [seq, v] : rows) Stmt(c, update).integer(1, v).integer(2, seq).step();
}

// Step 2's rows: each mesh's size and each job's result size.
void backfill_sizes(SqliteStore::Connection& c) {
  fill_from_records<pb::Mesh>(c, "SELECT seq, record FROM meshes", "UPDATE meshes SET size_bytes = ? WHERE seq = ?",
                              [](const pb::Mesh& m) { return m.size_bytes(); });
  fill_from_records<pb::Job>(c, "SELECT seq, record FROM jobs", "UPDATE jobs SET result_bytes = ? WHERE seq = ?",
                             rows::result_bytes);
}

// Step 3's rows: when each finished job finished (seconds since the epoch).
void backfill_finished(SqliteStore::Connection& c) {
  fill_from_records<pb::Job>(c, "SELECT seq, record FROM jobs", "UPDATE jobs SET finished_at = ? WHERE seq = ?",
                             [](const pb::Job& j) { return j.finished().seconds(); });
}

const Migration kMigrations[] = {
    // 0 -> 1: meshes and jobs, records as serialized protos.
    {"CREATE TABLE IF NOT EXISTS meshes (seq INTEGER PRIMARY KEY AUTOINCREMENT, tenant TEXT NOT NULL, "
     "id TEXT NOT NULL, record BLOB NOT NULL, UNIQUE(tenant, id));"
     "CREATE TABLE IF NOT EXISTS jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT NOT NULL UNIQUE, "
     "tenant TEXT NOT NULL, request_id TEXT NOT NULL, state INTEGER NOT NULL, record BLOB NOT NULL);"
     "CREATE UNIQUE INDEX IF NOT EXISTS jobs_request ON jobs(tenant, request_id) WHERE request_id <> '';"
     "CREATE INDEX IF NOT EXISTS jobs_state ON jobs(state);",
     nullptr},
    // 1 -> 2: sizes for the per-tenant storage quota, and an index for the per-tenant job count.
    {"ALTER TABLE meshes ADD COLUMN size_bytes INTEGER NOT NULL DEFAULT 0;"
     "ALTER TABLE jobs ADD COLUMN result_bytes INTEGER NOT NULL DEFAULT 0;"
     "CREATE INDEX IF NOT EXISTS jobs_tenant_state ON jobs(tenant, state);",
     backfill_sizes},
    // 2 -> 3: when a job finished, for retention.
    {"ALTER TABLE jobs ADD COLUMN finished_at INTEGER NOT NULL DEFAULT 0;"
     "CREATE INDEX IF NOT EXISTS jobs_finished ON jobs(finished_at) WHERE finished_at > 0;",
     backfill_finished},
};

}  // namespace

int sqlite_schema_version() { return static_cast<int>(std::size(kMigrations)); }

int SqliteStore::version() {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  Stmt v(writer_, "PRAGMA user_version");
  return v.step() ? static_cast<int>(v.column_int(0)) : 0;
}

// Brings the database to this build's schema, one step per transaction (a crash between
// steps leaves a database at a version the next start continues from); refuses a database
// a newer brenierd has written, whose rows this one would misread.
void SqliteStore::migrate() {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  int version = 0;
  {
    Stmt v(writer_, "PRAGMA user_version");
    if (v.step()) version = static_cast<int>(v.column_int(0));
  }
  if (version > sqlite_schema_version()) rows::refuse_newer("in " + dir(), version, sqlite_schema_version());
  for (; version < sqlite_schema_version(); ++version) {
    exec("BEGIN IMMEDIATE");
    try {
      exec(kMigrations[version].sql);
      if (kMigrations[version].rows) kMigrations[version].rows(writer_);
      exec(("PRAGMA user_version = " + std::to_string(version + 1)).c_str());
      exec("COMMIT");
    } catch (...) {
      sqlite3_exec(writer_.db, "ROLLBACK", nullptr, nullptr, nullptr);
      throw;
    }
  }
}

void SqliteStore::exec(const char* sql) {
  char* err = nullptr;
  if (sqlite3_exec(writer_.db, sql, nullptr, nullptr, &err) != SQLITE_OK) {
    const std::string msg = err ? err : "unknown";
    sqlite3_free(err);
    fail(ErrorCode::kInternal, std::string("database: ") + msg);
  }
}

pb::Mesh SqliteStore::put_mesh_with_blob(const std::string& tenant, const pb::Mesh& mesh, const std::string& bytes) {
  // The long write goes to a temporary file outside the lock; the check that the blob is
  // there, its rename and the row go in under the writer's lock, the one delete_mesh holds
  // while it removes a last row and its blob. So a row never outlives its bytes: a delete
  // either comes first (and this puts the blob back) or sees this row and keeps the blob.
  std::string temp;
  if (!has_blob(Blob::kMesh, mesh.id())) temp = write_temp(bytes);
  std::lock_guard<std::mutex> lock(writer_.mutex);
  if (temp.empty() && !has_blob(Blob::kMesh, mesh.id())) temp = write_temp(bytes);  // deleted meanwhile
  if (!temp.empty()) commit_blob(Blob::kMesh, temp, mesh.id());
  test_hooks::at(test_hooks::Point::kMeshBeforeRow);
  Stmt(writer_, "INSERT OR IGNORE INTO meshes (tenant, id, record, size_bytes) VALUES (?, ?, ?, ?)")
      .text(1, tenant)
      .text(2, mesh.id())
      .blob(3, mesh.SerializeAsString())
      .integer(4, mesh.size_bytes())
      .step();
  std::optional<pb::Mesh> stored = first_record<pb::Mesh>(writer_, kMeshById, tenant, mesh.id());
  if (!stored) fail(ErrorCode::kInternal, "database: a mesh just stored is not there");
  return *stored;
}

std::optional<pb::Mesh> SqliteStore::get_mesh(const std::string& tenant, const std::string& id) {
  Connection* c = nullptr;
  auto lock = reader(c);
  return first_record<pb::Mesh>(*c, kMeshById, tenant, id);
}

std::vector<pb::Mesh> SqliteStore::list_meshes(const std::string& tenant, const std::string& token, int limit,
                                         std::string& next) {
  const int64_t after = rows::token_value(token);
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT seq, record FROM meshes WHERE tenant = ? AND seq > ? ORDER BY seq LIMIT ?");
  s.text(1, tenant).integer(2, after).integer(3, limit + 1);
  return page_of<pb::Mesh>(s, limit, next);
}

bool SqliteStore::delete_mesh(const std::string& tenant, const std::string& id) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  Stmt d(writer_, "DELETE FROM meshes WHERE tenant = ? AND id = ?");
  d.text(1, tenant).text(2, id).step();
  if (sqlite3_changes(writer_.db) == 0) return false;
  Stmt s(writer_, "SELECT 1 FROM meshes WHERE id = ? LIMIT 1");
  s.text(1, id);
  if (!s.step()) remove_blob(Blob::kMesh, id);
  return true;
}

pb::Job SqliteStore::insert_job(const std::string& tenant, const pb::Job& job, bool& inserted, int max_unfinished) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  if (!job.request_id().empty()) {
    if (std::optional<pb::Job> earlier = first_record<pb::Job>(
            writer_, "SELECT record FROM jobs WHERE tenant = ? AND request_id = ?", tenant, job.request_id())) {
      inserted = false;
      return *earlier;
    }
  }
  // Counted under the writer's lock, with the insert: concurrent submissions cannot both
  // take the last place.
  if (max_unfinished > 0) {
    Stmt n(writer_, "SELECT COUNT(*) FROM jobs WHERE tenant = ? AND state IN (?, ?)");
    n.text(1, tenant).integer(2, pb::QUEUED).integer(3, pb::RUNNING);
    const int64_t unfinished = n.step() ? n.column_int(0) : 0;
    if (unfinished >= max_unfinished) rows::over_job_quota(unfinished);
  }
  Stmt(writer_, "INSERT INTO jobs (id, tenant, request_id, state, record) VALUES (?, ?, ?, ?, ?)")
      .text(1, job.id())
      .text(2, tenant)
      .text(3, job.request_id())
      .integer(4, job.state())
      .blob(5, job.SerializeAsString())
      .step();
  inserted = true;
  return job;
}

std::optional<pb::Job> SqliteStore::get_job(const std::string& tenant, const std::string& id) {
  Connection* c = nullptr;
  auto lock = reader(c);
  return first_record<pb::Job>(*c, "SELECT record FROM jobs WHERE tenant = ? AND id = ?", tenant, id);
}

bool SqliteStore::has_request(const std::string& tenant, const std::string& request_id) {
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT 1 FROM jobs WHERE tenant = ? AND request_id = ?");
  s.text(1, tenant).text(2, request_id);
  return s.step();
}

std::optional<pb::Job> SqliteStore::get_job_any(const std::string& id, std::string* tenant) {
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT record, tenant FROM jobs WHERE id = ?");
  s.text(1, id);
  if (!s.step()) return std::nullopt;
  if (tenant) *tenant = s.column_text(1);
  return parse<pb::Job>(s.column_blob(0));
}

std::vector<pb::Job> SqliteStore::list_jobs(const std::string& tenant, pb::JobState state, const std::string& token, int limit,
                                      std::string& next) {
  const int64_t after = rows::token_value(token);
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT seq, record FROM jobs WHERE tenant = ? AND seq > ? AND (? = 0 OR state = ?) ORDER BY seq LIMIT ?");
  s.text(1, tenant).integer(2, after).integer(3, state).integer(4, state).integer(5, limit + 1);
  return page_of<pb::Job>(s, limit, next);
}

void SqliteStore::update_job(const pb::Job& job) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  Stmt(writer_, "UPDATE jobs SET state = ?, record = ?, result_bytes = ?, finished_at = ? WHERE id = ?")
      .integer(1, job.state())
      .blob(2, job.SerializeAsString())
      .integer(3, rows::result_bytes(job))
      .integer(4, job.finished().seconds())
      .text(5, job.id())
      .step();
}

void SqliteStore::delete_job(const std::string& id) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  Stmt(writer_, "DELETE FROM jobs WHERE id = ?").text(1, id).step();
}

int SqliteStore::delete_finished_jobs(int64_t finished_before, std::vector<std::string>& blobs) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  std::vector<std::string> ids;
  {
    Stmt s(writer_, "SELECT id, record FROM jobs WHERE finished_at > 0 AND finished_at < ?");
    s.integer(1, finished_before);
    while (s.step()) {
      ids.push_back(s.column_text(0));
      const pb::Job job = parse<pb::Job>(s.column_blob(1));
      for (const pb::Artifact& a : job.result().artifacts()) blobs.push_back(a.sha256());
    }
  }
  if (ids.empty()) return 0;
  exec("BEGIN IMMEDIATE");
  try {
    for (const std::string& id : ids) Stmt(writer_, "DELETE FROM jobs WHERE id = ?").text(1, id).step();
    exec("COMMIT");
  } catch (...) {
    sqlite3_exec(writer_.db, "ROLLBACK", nullptr, nullptr, nullptr);
    throw;
  }
  return static_cast<int>(ids.size());
}

void SqliteStore::named_blobs(std::set<std::string>& meshes, std::set<std::string>& results) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  Stmt m(writer_, "SELECT DISTINCT id FROM meshes");
  while (m.step()) meshes.insert(m.column_text(0));
  results = result_blobs_named(writer_);
}

int64_t SqliteStore::storage_bytes(const std::string& tenant) {
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT (SELECT COALESCE(SUM(size_bytes), 0) FROM meshes WHERE tenant = ?) + "
             "(SELECT COALESCE(SUM(result_bytes), 0) FROM jobs WHERE tenant = ?)");
  s.text(1, tenant).text(2, tenant);
  return s.step() ? s.column_int(0) : 0;
}

std::vector<std::string> SqliteStore::unfinished_jobs() {
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT id FROM jobs WHERE state IN (?, ?) ORDER BY seq");
  s.integer(1, pb::QUEUED).integer(2, pb::RUNNING);
  std::vector<std::string> out;
  while (s.step()) out.push_back(s.column_text(0));
  return out;
}

std::unique_ptr<Store> open_sqlite_store(const std::string& dir) { return std::make_unique<SqliteStore>(dir); }

}  // namespace brenier::server

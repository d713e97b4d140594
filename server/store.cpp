#include "store.hpp"
#include "test_hooks.hpp"

#include <fcntl.h>
#include <sqlite3.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <atomic>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>

#include "common/error.hpp"
#include "common/hash.hpp"

namespace brenier::server {
namespace fs = std::filesystem;

namespace {

// A prepared statement that finalizes itself; errors become Error(kInternal) naming SQLite's
// message (a broken database is ours to fix, not the client's).
class Stmt {
 public:
  Stmt(Store::Connection& c, const char* sql) : db_(c.db), s_(c.prepare(sql)) {}
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

template <class M>
M parse(const std::string& bytes) {
  M m;
  if (!m.ParseFromString(bytes)) fail(ErrorCode::kInternal, "database: a stored record does not parse");
  return m;
}

// The record of the first row a query with two text parameters finds, if any.
template <class M>
std::optional<M> first_record(Store::Connection& c, const char* sql, const std::string& a, const std::string& b) {
  Stmt s(c, sql);
  s.text(1, a).text(2, b);
  if (!s.step()) return std::nullopt;
  return parse<M>(s.column_blob(0));
}

// The bytes of a job's results (what it holds of its tenant's storage quota).
int64_t result_bytes(const pb::Job& job) {
  int64_t n = 0;
  for (const pb::Artifact& a : job.result().artifacts()) n += a.size_bytes();
  return n;
}

// The result blobs the jobs' artifacts name.
std::set<std::string> result_blobs_named(Store::Connection& c) {
  std::set<std::string> named;
  Stmt j(c, "SELECT record FROM jobs");
  while (j.step()) {
    const pb::Job job = parse<pb::Job>(j.column_blob(0));  // named: a range-for keeps only its last temporary
    for (const pb::Artifact& a : job.result().artifacts()) named.insert(a.sha256());
  }
  return named;
}

int64_t token_value(const std::string& token) {
  if (token.empty()) return 0;
  char* end = nullptr;
  const long long v = std::strtoll(token.c_str(), &end, 10);
  if (end == token.c_str() || *end != '\0' || v < 0) invalid("page_token '" + token + "' is not one this server gave");
  return v;
}

// Rows (seq, record) of a query that asked for limit + 1 rows after the page token: the
// records of the page, and the token of the next page when there is one more row.
template <class M>
std::vector<M> page_of(Stmt& s, int limit, std::string& next) {
  std::vector<M> out;
  next.clear();
  while (s.step()) {
    if (static_cast<int>(out.size()) == limit) return out;  // one more row: `next` stays
    next = std::to_string(s.column_int(0));
    out.push_back(parse<M>(s.column_blob(1)));
  }
  next.clear();
  return out;
}

void fsync_path(const std::string& path, bool directory) {
  const int fd = ::open(path.c_str(), directory ? O_RDONLY | O_DIRECTORY : O_RDONLY);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

}  // namespace

sqlite3_stmt* Store::Connection::prepare(const char* sql) {
  for (auto& [text, stmt] : statements)
    if (text == sql) return stmt;
  sqlite3_stmt* stmt = nullptr;
  if (sqlite3_prepare_v3(db, sql, -1, SQLITE_PREPARE_PERSISTENT, &stmt, nullptr) != SQLITE_OK)
    fail(ErrorCode::kInternal, std::string("database: ") + sqlite3_errmsg(db));
  statements.emplace_back(sql, stmt);
  return stmt;
}

Store::Connection::~Connection() {
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

std::unique_lock<std::mutex> Store::reader(Connection*& c) {
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

Store::Store(const std::string& dir) : dir_(dir) {
  std::error_code ec;
  fs::create_directories(dir + "/blobs", ec);
  if (!ec) fs::create_directories(dir + "/tmp", ec);
  if (ec) invalid("cannot create the data directory " + dir + ": " + ec.message());
  for (const auto& e : fs::directory_iterator(dir + "/tmp", ec)) fs::remove_all(e.path(), ec);
  writer_.db = open_db(dir);
  exec("PRAGMA journal_mode=WAL");
  exec("PRAGMA synchronous=NORMAL");
  migrate();
  for (int k = 0; k < 4; ++k) {
    readers_.push_back(std::make_unique<Connection>());
    readers_.back()->db = open_db(dir);
  }
}

Store::~Store() = default;

namespace {

// The schema, as the steps from each version to the next: step k takes a database at
// version k to k + 1 (its SQL, then its C++ part over the rows, if any). A database's
// version is SQLite's user_version; version 0 is a new database or one written before
// versions were kept (its tables, if any, are version 1's, which the first step creates
// only where missing). Steps are only ever appended.
struct Migration {
  const char* sql;
  void (*rows)(Store::Connection& c);
};

// A column filled in from each row's record: `select` yields (seq, record), `update` sets
// the column of one seq.
template <class M, class Value>
void fill_from_records(Store::Connection& c, const char* select, const char* update, Value value) {
  std::vector<std::pair<int64_t, int64_t>> rows;
  {
    Stmt s(c, select);
    while (s.step()) rows.emplace_back(s.column_int(0), value(parse<M>(s.column_blob(1))));
  }
  for (const auto& [seq, v] : rows) Stmt(c, update).integer(1, v).integer(2, seq).step();
}

// Step 2's rows: each mesh's size and each job's result size.
void backfill_sizes(Store::Connection& c) {
  fill_from_records<pb::Mesh>(c, "SELECT seq, record FROM meshes", "UPDATE meshes SET size_bytes = ? WHERE seq = ?",
                              [](const pb::Mesh& m) { return m.size_bytes(); });
  fill_from_records<pb::Job>(c, "SELECT seq, record FROM jobs", "UPDATE jobs SET result_bytes = ? WHERE seq = ?",
                             result_bytes);
}

// Step 3's rows: when each finished job finished (seconds since the epoch).
void backfill_finished(Store::Connection& c) {
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

int Store::schema_version() { return static_cast<int>(std::size(kMigrations)); }

// Brings the database to this build's schema, one step per transaction (a crash between
// steps leaves a database at a version the next start continues from); refuses a database
// a newer brenierd has written, whose rows this one would misread.
void Store::migrate() {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  int version = 0;
  {
    Stmt v(writer_, "PRAGMA user_version");
    if (v.step()) version = static_cast<int>(v.column_int(0));
  }
  if (version > schema_version())
    fail(ErrorCode::kFailedPrecondition, "the database in " + dir_ + " has schema version " + std::to_string(version) +
                                             ", written by a newer brenierd; this one reads up to version " +
                                             std::to_string(schema_version()));
  for (; version < schema_version(); ++version) {
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

// A blob is written before the row that names it (so a row never names missing bytes); a
// kill -9 between the two leaves a blob nothing names: a mesh upload that was never
// acknowledged, or the artifacts of a job run that is then run again (a report holding its
// timings hashes differently each run). Swept at start, before any request is served.
int Store::sweep_orphaned_blobs() {
  std::set<std::string> named_meshes, named_results;
  {
    std::lock_guard<std::mutex> lock(writer_.mutex);
    Stmt m(writer_, "SELECT DISTINCT id FROM meshes");
    while (m.step()) named_meshes.insert(m.column_text(0));
    named_results = result_blobs_named(writer_);
  }
  int removed = 0;
  for (const auto& [kind, named] : {std::pair{Blob::kMesh, &named_meshes}, std::pair{Blob::kResult, &named_results}}) {
    const std::string root = blob_root(kind);
    std::error_code ec;
    for (auto it = fs::recursive_directory_iterator(root, ec); !ec && it != fs::recursive_directory_iterator();
         it.increment(ec)) {
      if (!it->is_regular_file(ec) || named->count(it->path().filename().string())) continue;
      std::error_code rm;
      if (fs::remove(it->path(), rm)) ++removed;
    }
  }
  return removed;
}

void Store::exec(const char* sql) {
  char* err = nullptr;
  if (sqlite3_exec(writer_.db, sql, nullptr, nullptr, &err) != SQLITE_OK) {
    const std::string msg = err ? err : "unknown";
    sqlite3_free(err);
    fail(ErrorCode::kInternal, std::string("database: ") + msg);
  }
}

std::string Store::temp_path() {
  static std::atomic<uint64_t> counter{0};
  static const uint64_t salt = std::random_device{}();
  return dir_ + "/tmp/" + std::to_string(::getpid()) + "-" + std::to_string(salt % 100000) + "-" +
         std::to_string(counter.fetch_add(1));
}

std::string Store::blob_root(Blob kind) const {
  return dir_ + (kind == Blob::kMesh ? "/blobs/meshes" : "/blobs/results");
}

// Blob paths are made only of SHA-256 digests: nothing a client sends can name a file
// outside DIR/blobs.
std::string Store::blob_path(Blob kind, const std::string& sha) const {
  if (!is_sha256_hex(sha)) fail(ErrorCode::kInvalidArgument, "'" + sha.substr(0, 80) + "' is not a SHA-256 digest");
  return blob_root(kind) + "/" + sha.substr(0, 2) + "/" + sha;
}

bool Store::has_blob(Blob kind, const std::string& sha) const {
  std::error_code ec;
  return is_sha256_hex(sha) && fs::exists(blob_path(kind, sha), ec);
}

void Store::commit_blob(Blob kind, const std::string& temp, const std::string& sha) {
  const std::string path = blob_path(kind, sha);
  std::error_code ec;
  if (fs::exists(path, ec)) {
    fs::remove(temp, ec);
    return;
  }
  fs::create_directories(fs::path(path).parent_path(), ec);
  fsync_path(temp, false);
  fs::rename(temp, path, ec);
  if (ec) fail(ErrorCode::kInternal, "cannot store a blob: " + ec.message());
  fsync_path(fs::path(path).parent_path().string(), true);
}

std::string Store::write_temp(const std::string& bytes) {
  const std::string temp = temp_path();
  std::ofstream os(temp, std::ios::binary | std::ios::trunc);
  if (!os || !os.write(bytes.data(), static_cast<std::streamsize>(bytes.size())) || !os.flush())
    fail(ErrorCode::kInternal, "cannot write a blob in " + dir_ + "/tmp");
  return temp;
}

std::string Store::put_blob(Blob kind, const std::string& bytes, const std::string& known_sha) {
  const std::string sha = known_sha.empty() ? sha256_hex(bytes) : known_sha;
  if (has_blob(kind, sha)) {
    // Touched: expire_jobs spares recent blobs, which a job about to record them may share
    // with a job it expires.
    std::error_code ec;
    fs::last_write_time(blob_path(kind, sha), fs::file_time_type::clock::now(), ec);
    return sha;
  }
  commit_blob(kind, write_temp(bytes), sha);
  return sha;
}

pb::Mesh Store::put_mesh_with_blob(const std::string& tenant, const pb::Mesh& mesh, const std::string& bytes) {
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

std::optional<pb::Mesh> Store::get_mesh(const std::string& tenant, const std::string& id) {
  Connection* c = nullptr;
  auto lock = reader(c);
  return first_record<pb::Mesh>(*c, kMeshById, tenant, id);
}

std::vector<pb::Mesh> Store::list_meshes(const std::string& tenant, const std::string& token, int limit,
                                         std::string& next) {
  const int64_t after = token_value(token);
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT seq, record FROM meshes WHERE tenant = ? AND seq > ? ORDER BY seq LIMIT ?");
  s.text(1, tenant).integer(2, after).integer(3, limit + 1);
  return page_of<pb::Mesh>(s, limit, next);
}

bool Store::delete_mesh(const std::string& tenant, const std::string& id) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  Stmt d(writer_, "DELETE FROM meshes WHERE tenant = ? AND id = ?");
  d.text(1, tenant).text(2, id).step();
  if (sqlite3_changes(writer_.db) == 0) return false;
  Stmt s(writer_, "SELECT 1 FROM meshes WHERE id = ? LIMIT 1");
  s.text(1, id);
  if (!s.step()) {
    std::error_code ec;
    fs::remove(blob_path(Blob::kMesh, id), ec);
  }
  return true;
}

pb::Job Store::insert_job(const std::string& tenant, const pb::Job& job, bool& inserted, int max_unfinished) {
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
    if (unfinished >= max_unfinished)
      fail(ErrorCode::kResourceExhausted, "you have " + std::to_string(unfinished) +
                                              " jobs queued or running, the quota max_jobs_per_tenant of this server");
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

std::optional<pb::Job> Store::get_job(const std::string& tenant, const std::string& id) {
  Connection* c = nullptr;
  auto lock = reader(c);
  return first_record<pb::Job>(*c, "SELECT record FROM jobs WHERE tenant = ? AND id = ?", tenant, id);
}

bool Store::has_request(const std::string& tenant, const std::string& request_id) {
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT 1 FROM jobs WHERE tenant = ? AND request_id = ?");
  s.text(1, tenant).text(2, request_id);
  return s.step();
}

std::optional<pb::Job> Store::get_job_any(const std::string& id, std::string* tenant) {
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT record, tenant FROM jobs WHERE id = ?");
  s.text(1, id);
  if (!s.step()) return std::nullopt;
  if (tenant) *tenant = s.column_text(1);
  return parse<pb::Job>(s.column_blob(0));
}

std::vector<pb::Job> Store::list_jobs(const std::string& tenant, pb::JobState state, const std::string& token, int limit,
                                      std::string& next) {
  const int64_t after = token_value(token);
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT seq, record FROM jobs WHERE tenant = ? AND seq > ? AND (? = 0 OR state = ?) ORDER BY seq LIMIT ?");
  s.text(1, tenant).integer(2, after).integer(3, state).integer(4, state).integer(5, limit + 1);
  return page_of<pb::Job>(s, limit, next);
}

void Store::update_job(const pb::Job& job) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  Stmt(writer_, "UPDATE jobs SET state = ?, record = ?, result_bytes = ?, finished_at = ? WHERE id = ?")
      .integer(1, job.state())
      .blob(2, job.SerializeAsString())
      .integer(3, result_bytes(job))
      .integer(4, job.finished().seconds())
      .text(5, job.id())
      .step();
}

void Store::delete_job(const std::string& id) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  Stmt(writer_, "DELETE FROM jobs WHERE id = ?").text(1, id).step();
}

int Store::expire_jobs(int64_t finished_before, std::chrono::seconds spare) {
  std::lock_guard<std::mutex> lock(writer_.mutex);
  std::vector<std::string> ids, blobs;
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
  // A result's bytes go with the last job that names them (content-addressed: two jobs may
  // share them), under the lock that every job update takes.
  const std::set<std::string> named = result_blobs_named(writer_);
  const auto recent = fs::file_time_type::clock::now() - spare;
  for (const std::string& sha : blobs) {
    if (named.count(sha) || !is_sha256_hex(sha)) continue;
    std::error_code ec;
    const std::string path = blob_path(Blob::kResult, sha);
    const auto written = fs::last_write_time(path, ec);
    if (!ec && written < recent) fs::remove(path, ec);
  }
  return static_cast<int>(ids.size());
}

int64_t Store::storage_bytes(const std::string& tenant) {
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT (SELECT COALESCE(SUM(size_bytes), 0) FROM meshes WHERE tenant = ?) + "
             "(SELECT COALESCE(SUM(result_bytes), 0) FROM jobs WHERE tenant = ?)");
  s.text(1, tenant).text(2, tenant);
  return s.step() ? s.column_int(0) : 0;
}

std::vector<std::string> Store::unfinished_jobs() {
  Connection* c = nullptr;
  auto lock = reader(c);
  Stmt s(*c, "SELECT id FROM jobs WHERE state IN (?, ?) ORDER BY seq");
  s.integer(1, pb::QUEUED).integer(2, pb::RUNNING);
  std::vector<std::string> out;
  while (s.step()) out.push_back(s.column_text(0));
  return out;
}

}  // namespace brenier::server

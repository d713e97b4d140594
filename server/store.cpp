#include "store.hpp"

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <filesystem>
#include <fstream>

#include "common/error.hpp"
#include "common/hash.hpp"

namespace brenier::server {
namespace fs = std::filesystem;

namespace {

void fsync_path(const std::string& path, bool directory) {
  const int fd = ::open(path.c_str(), directory ? O_RDONLY | O_DIRECTORY : O_RDONLY);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

std::string host_name() {
  char buf[256] = {};
  if (::gethostname(buf, sizeof buf - 1) != 0 || !buf[0]) return "host";
  std::string h(buf);
  for (char& c : h)
    if (c == '/' || c == '.') c = '_';
  return h;
}

// Temporary files are named HOST.PID.N: replicas on several hosts (or containers) may share
// DIR/tmp, so a process removes only what a dead process of its own host left, and anything
// a day old (a host that never comes back).
bool leftover(const fs::directory_entry& e, const std::string& host) {
  const std::string name = e.path().filename().string();
  const size_t dot = name.find('.');
  std::error_code ec;
  const auto written = fs::last_write_time(e.path(), ec);
  if (!ec && written < fs::file_time_type::clock::now() - std::chrono::hours(24)) return true;
  if (dot == std::string::npos || name.substr(0, dot) != host) return false;
  const long pid = std::strtol(name.c_str() + dot + 1, nullptr, 10);
  return pid > 0 && pid != ::getpid() && ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH;
}

}  // namespace

Store::Store(const std::string& dir) : dir_(dir) {
  std::error_code ec;
  fs::create_directories(dir + "/blobs", ec);
  if (!ec) fs::create_directories(dir + "/tmp", ec);
  if (ec) invalid("cannot create the data directory " + dir + ": " + ec.message());
  const std::string host = host_name();
  for (const auto& e : fs::directory_iterator(dir + "/tmp", ec))
    if (leftover(e, host)) fs::remove_all(e.path(), ec);
}

Store::~Store() = default;

std::string Store::temp_path() {
  static std::atomic<uint64_t> counter{0};
  static const std::string host = host_name();
  return dir_ + "/tmp/" + host + "." + std::to_string(::getpid()) + "." + std::to_string(counter.fetch_add(1));
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

std::optional<std::string> Store::read_blob(Blob kind, const std::string& sha) const {
  if (!is_sha256_hex(sha)) return std::nullopt;
  std::ifstream in(blob_path(kind, sha), std::ios::binary);
  if (!in) return std::nullopt;  // an open file stays readable if it is unlinked meanwhile
  std::string bytes(std::istreambuf_iterator<char>(in), {});
  if (in.bad()) fail(ErrorCode::kInternal, "cannot read the blob " + sha);
  return bytes;
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

void Store::remove_blob(Blob kind, const std::string& sha) {
  std::error_code ec;
  fs::remove(blob_path(kind, sha), ec);
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

// A blob is written before the row that names it (so a row never names missing bytes); a
// kill -9 between the two leaves a blob nothing names: a mesh upload that was never
// acknowledged, or the artifacts of a job run that is then run again (a report holding its
// timings hashes differently each run). Swept at start, before any request is served.
int Store::sweep_orphaned_blobs(std::chrono::seconds min_age) {
  std::set<std::string> named_meshes, named_results;
  named_blobs(named_meshes, named_results);
  const auto before = fs::file_time_type::clock::now() - min_age;
  int removed = 0;
  for (const auto& [kind, named] : {std::pair{Blob::kMesh, &named_meshes}, std::pair{Blob::kResult, &named_results}}) {
    std::error_code ec;
    for (auto it = fs::recursive_directory_iterator(blob_root(kind), ec); !ec && it != fs::recursive_directory_iterator();
         it.increment(ec)) {
      if (!it->is_regular_file(ec) || named->count(it->path().filename().string())) continue;
      std::error_code rm;
      if (min_age.count() > 0 && fs::last_write_time(it->path(), rm) >= before) continue;
      if (!rm && fs::remove(it->path(), rm)) ++removed;
    }
  }
  return removed;
}

int Store::expire_jobs(int64_t finished_before, std::chrono::seconds spare) {
  std::vector<std::string> blobs;
  const int n = delete_finished_jobs(finished_before, blobs);
  if (n == 0) return 0;
  // A result's bytes go with the last job that names them (content-addressed: two jobs may
  // share them); a job recording the same bytes now has touched them (put_blob), so recent
  // blobs are spared.
  std::set<std::string> meshes, named;
  named_blobs(meshes, named);
  const auto recent = fs::file_time_type::clock::now() - spare;
  for (const std::string& sha : blobs) {
    if (named.count(sha) || !is_sha256_hex(sha)) continue;
    std::error_code ec;
    const std::string path = blob_path(Blob::kResult, sha);
    const auto written = fs::last_write_time(path, ec);
    if (!ec && written < recent) fs::remove(path, ec);
  }
  return n;
}

std::string elide_password(const std::string& url) {
  const size_t scheme = url.find("://");
  const size_t start = scheme == std::string::npos ? 0 : scheme + 3;
  const size_t at = url.find('@', start);
  if (at == std::string::npos) return url;
  const size_t colon = url.find(':', start);
  if (colon == std::string::npos || colon > at) return url;
  return url.substr(0, colon + 1) + "***" + url.substr(at);
}

std::unique_ptr<Store> open_sqlite_store(const std::string& dir);
std::unique_ptr<Store> open_postgres_store(const std::string& dir, const std::string& url, double lease_seconds);

std::unique_ptr<Store> open_store(const std::string& dir, const std::string& database, double lease_seconds) {
  if (database.empty()) return open_sqlite_store(dir);
  if (database.rfind("postgresql://", 0) != 0 && database.rfind("postgres://", 0) != 0)
    invalid("--database '" + elide_password(database) + "' is not a postgresql://USER[:PASS]@HOST:PORT/DB URL");
  return open_postgres_store(dir, database, lease_seconds);
}

}  // namespace brenier::server

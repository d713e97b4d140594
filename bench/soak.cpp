// Soak of brenierd under faults (issues 20 and 21), a timed harness:
//   bench_soak BRENIERD [--minutes M=30] [--clients N=64] [--kill-every S=180] [--work DIR]
//              [--postgres POSTGRES_SH]
// starts brenierd on loopback, runs N clients that mix uploads, maps (disk and sphere,
// conformal and area-preserving), distances, matrices, cancels, deletes, watches and result
// downloads, and kills the server with SIGKILL every S seconds (±50 %) and restarts it on the
// same port. With --postgres: a PostgreSQL 15 of its own (tests/service/postgres.sh) and two
// replicas on it and one data directory, each client call going to either; each fault kills
// with -9 one replica, PostgreSQL (then started again), or both a replica and PostgreSQL.
// Then, without faults, it waits for every job the server accepted and checks:
//  - no accepted job is lost (each is found, and ends SUCCEEDED, FAILED or CANCELLED);
//  - every downloaded result matches the SHA-256 the server gives for it;
//  - no status a client could not have caused (INTERNAL, UNKNOWN, DATA_LOSS) was answered;
//  - after a clean stop, no blob is orphaned and no row names a missing blob (read from the
//    database and the blob folders directly, not through the server's code; on PostgreSQL
//    orphans are only counted: replicas sweep those an hour old, as another replica may be
//    between a blob and its row);
//  - RSS after warm-up: sampled every 5 s; per server life, the growth from the first sample
//    after 60 s to the last, and the slope; the life without kills at the end is the cleanest.
// Prints figures and exits non-zero when a check fails.
#include <fcntl.h>
#include <signal.h>
#include <libpq-fe.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <set>
#include <thread>

#include "child_process.hpp"
#include "client.hpp"
#include "mesh/io.hpp"
#include "mesh/shapes.hpp"

namespace fs = std::filesystem;
namespace pb = brenier::v1;
using brenier::client::Client;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// brenierd as a child process on a fixed port once the first start has picked one.
class Server {
 public:
  Server(std::string brenierd, std::string data, std::string tag = "", std::vector<std::string> flags = {})
      : brenierd_(std::move(brenierd)), data_(std::move(data)), tag_(std::move(tag)), flags_(std::move(flags)) {}
  void start() {
    const std::string port_file = data_ + tag_ + ".port";
    fs::remove(port_file);
    const std::string listen = "127.0.0.1:" + std::to_string(port_);
    std::vector<std::string> args = {brenierd_, "--listen", listen, "--data", data_, "--port-file", port_file,
                                     "--log-level", "warn", "--queue", "256", "--grace", "5"};
    args.insert(args.end(), flags_.begin(), flags_.end());
    pid_ = brenier::bench::spawn(args, data_ + tag_ + ".log");
    port_ = brenier::bench::wait_for_port(port_file, pid_);  // its log: data_ + ".log"
    started_ = Clock::now();
  }
  void kill9() {
    ::kill(pid_, SIGKILL);
    int st = 0;
    waitpid(pid_, &st, 0);
  }
  bool stop() {  // SIGTERM; true when it exited 0
    ::kill(pid_, SIGTERM);
    int st = 0;
    waitpid(pid_, &st, 0);
    return WIFEXITED(st) && WEXITSTATUS(st) == 0;
  }
  double rss_mb() const {
    std::ifstream in("/proc/" + std::to_string(pid_) + "/status");
    std::string key;
    while (in >> key) {
      if (key == "VmRSS:") {
        double kb = 0;
        in >> kb;
        return kb / 1024;
      }
      in.ignore(1 << 12, '\n');
    }
    return 0;
  }
  double uptime() const { return since(started_); }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

 private:
  std::string brenierd_, data_, tag_;
  std::vector<std::string> flags_;
  int port_ = 0;
  pid_t pid_ = -1;
  Clock::time_point started_;
};

struct Tally {
  std::mutex mutex;
  std::map<std::string, int64_t> calls;      // "op code" -> count
  std::map<std::string, int64_t> why;        // code and the start of the message -> count
  std::set<std::string> accepted;            // job ids the server accepted
  std::vector<std::string> problems;         // failed checks, with what happened
  int64_t downloads = 0, verified = 0;
  void note(int code, const std::string& message) {
    // Ids (runs of 12 or more hex digits) and numbers folded, so that like messages count together.
    std::string key = std::to_string(code) + " ";
    for (size_t i = 0; i < message.size() && key.size() < 72;) {
      size_t j = i;
      while (j < message.size() && std::isxdigit(static_cast<unsigned char>(message[j]))) ++j;
      if (j - i >= 12) {
        key += "<id>";
        i = j;
      } else {
        key += std::isdigit(static_cast<unsigned char>(message[i])) ? '#' : message[i];
        ++i;
      }
    }
    std::lock_guard<std::mutex> lock(mutex);
    ++why[key];
  }
  void count(const std::string& op, grpc::StatusCode code) {
    std::lock_guard<std::mutex> lock(mutex);
    ++calls[op + " " + std::to_string(static_cast<int>(code))];
    if (code == grpc::StatusCode::INTERNAL || code == grpc::StatusCode::UNKNOWN || code == grpc::StatusCode::DATA_LOSS)
      problems.push_back(op + " answered " + std::to_string(static_cast<int>(code)));
  }
};

// Meshes the clients upload: small disks and spheres, each client's own jittered copies too
// (new blobs to store and delete), so that uploads, dedup and deletes all happen.
std::string jittered(const brenier::mesh::TriMesh& base, std::mt19937_64& rng, brenier::mesh::Format f) {
  brenier::mesh::TriMesh m = base;
  std::uniform_real_distribution<double> u(-1e-3, 1e-3);
  for (int i = 0; i < m.V.rows(); ++i) m.V(i, 2) += u(rng);
  return brenier::mesh::write_mesh_string(m, f);
}

class Soaker {
 public:
  Soaker(std::vector<Server*> servers, Tally& tally, std::atomic<bool>& stop)
      : servers_(std::move(servers)), tally_(tally), stop_(stop) {}

  void run_client(int index) {
    std::mt19937_64 rng(1000 + index);
    std::vector<Client> clients;  // one per replica; each call goes to either, as behind a balancer
    for (Server* s : servers_) {
      brenier::client::Options o;
      o.server = s->address();
      o.call_timeout = 20;
      clients.emplace_back(o);
    }
    std::vector<std::string> disks, spheres, jobs;
    const auto disk = brenier::mesh::make_disk(4 + index % 5);
    const auto sphere = brenier::mesh::make_icosphere(1 + index % 2);
    while (!stop_) {
      const int op = std::uniform_int_distribution<int>(0, 99)(rng);
      Client& c = clients[std::uniform_int_distribution<size_t>(0, clients.size() - 1)(rng)];
      try {
        if (op < 12 || disks.size() < 3) {
          const bool sph = op % 4 == 0;
          const bool ply = op % 2 == 1;
          const std::string bytes = jittered(sph ? sphere : disk, rng, ply ? brenier::mesh::Format::kPly : brenier::mesh::Format::kOff);
          const pb::Mesh m = c.upload_bytes(bytes, std::string(sph ? "sphere" : "disk") + (ply ? ".ply" : ".off"));
          (sph ? spheres : disks).push_back(m.id());
          tally_.count("upload", grpc::StatusCode::OK);
        } else if (op < 40) {
          pb::SubmitJobRequest r;
          const bool sph = !spheres.empty() && op % 5 == 0;
          r.mutable_map()->set_mesh(pick(sph ? spheres : disks, rng));
          r.mutable_map()->set_domain(sph ? pb::SPHERE : pb::DISK);
          r.mutable_map()->set_method(op % 2 ? pb::AREA_PRESERVING : pb::CONFORMAL);
          submit(c, r, jobs, "map");
        } else if (op < 50) {
          pb::SubmitJobRequest r;
          r.mutable_distance()->set_a(pick(disks, rng));
          r.mutable_distance()->set_b(pick(disks, rng));
          r.mutable_distance()->set_method(op % 2 ? pb::OMT_LINEAR : pb::WASSERSTEIN);
          submit(c, r, jobs, "distance");
        } else if (op < 54) {
          pb::SubmitJobRequest r;
          std::set<std::string> chosen;
          while (chosen.size() < std::min<size_t>(4, disks.size())) chosen.insert(pick(disks, rng));
          for (const auto& id : chosen) r.mutable_matrix()->add_meshes(id);
          r.mutable_matrix()->set_method(pb::OMT_LINEAR);
          submit(c, r, jobs, "matrix");
        } else if (op < 58 && !jobs.empty()) {
          c.cancel(pick(jobs, rng));
          tally_.count("cancel", grpc::StatusCode::OK);
        } else if (op < 62 && disks.size() > 12) {
          const size_t k = std::uniform_int_distribution<size_t>(0, disks.size() - 1)(rng);
          c.delete_mesh(disks[k]);
          disks.erase(disks.begin() + static_cast<std::ptrdiff_t>(k));
          tally_.count("delete", grpc::StatusCode::OK);
        } else if (op < 75 && !jobs.empty()) {
          grpc::ClientContext ctx;  // a watch for a while, then let go
          ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(3));
          pb::WatchJobRequest w;
          w.set_id(pick(jobs, rng));
          auto reader = c.stub().WatchJob(&ctx, w);
          pb::JobEvent e;
          while (reader->Read(&e)) {
          }
          const grpc::Status s = reader->Finish();
          tally_.count("watch", s.error_code());
        } else if (!jobs.empty()) {
          download(c, pick(jobs, rng));
        }
      } catch (const brenier::client::Error& e) {
        tally_.count("call", e.code());
        tally_.note(e.code(), e.what());
        // Back off as a client should: the server is restarting, or its queue or our share of
        // its upload streams is full.
        if (e.code() == grpc::StatusCode::UNAVAILABLE || e.code() == grpc::StatusCode::DEADLINE_EXCEEDED ||
            e.code() == grpc::StatusCode::RESOURCE_EXHAUSTED)
          std::this_thread::sleep_for(std::chrono::milliseconds(std::uniform_int_distribution<int>(100, 500)(rng)));
        if (e.code() == grpc::StatusCode::NOT_FOUND && std::string(e.what()).find("no mesh") != std::string::npos) {
          // Another try of an upload's GetMesh raced a delete: forget the ids and go on.
          disks.clear();
          spheres.clear();
        }
      }
    }
  }

  void download(Client& c, const std::string& job) {
    pb::Artifact meta;
    std::string bytes;
    try {
      bytes = c.fetch(job, "", &meta);
    } catch (const brenier::client::Error& e) {
      tally_.count("result", e.code());
      return;
    }
    std::lock_guard<std::mutex> lock(tally_.mutex);
    ++tally_.downloads;
    if (brenier::client::sha256_hex(bytes) == meta.sha256() && static_cast<int64_t>(bytes.size()) == meta.size_bytes())
      ++tally_.verified;
    else
      tally_.problems.push_back("job " + job + ": downloaded bytes do not match the artifact's SHA-256");
  }

 private:
  static const std::string& pick(const std::vector<std::string>& v, std::mt19937_64& rng) {
    return v[std::uniform_int_distribution<size_t>(0, v.size() - 1)(rng)];
  }
  void submit(Client& c, pb::SubmitJobRequest r, std::vector<std::string>& jobs, const char* kind) {
    const pb::Job j = c.submit(std::move(r));
    jobs.push_back(j.id());
    if (jobs.size() > 200) jobs.erase(jobs.begin());
    std::lock_guard<std::mutex> lock(tally_.mutex);
    tally_.accepted.insert(j.id());
    ++tally_.calls[std::string(kind) + " 0"];
  }

  std::vector<Server*> servers_;
  Tally& tally_;
  std::atomic<bool>& stop_;
};

// The mesh ids rows name and the result blobs jobs name, read from the database directly.
void named_blobs(const std::string& data, const std::string& database, std::set<std::string>& meshes,
                 std::set<std::string>& results) {
  auto add_results = [&](const void* p, int n) {
    pb::Job j;
    j.ParseFromArray(p, n);
    for (const auto& a : j.result().artifacts()) results.insert(a.sha256());
  };
  if (!database.empty()) {
    PGconn* c = PQconnectdb(database.c_str());
    if (PQstatus(c) != CONNECTION_OK) throw std::runtime_error("cannot reach the database");
    PGresult* r = PQexec(c, "SELECT id FROM meshes");
    for (int i = 0; i < PQntuples(r); ++i) meshes.insert(PQgetvalue(r, i, 0));
    PQclear(r);
    r = PQexecParams(c, "SELECT record FROM jobs", 0, nullptr, nullptr, nullptr, nullptr, 1);  // binary
    for (int i = 0; i < PQntuples(r); ++i) add_results(PQgetvalue(r, i, 0), PQgetlength(r, i, 0));
    PQclear(r);
    PQfinish(c);
    return;
  }
  sqlite3* db = nullptr;
  if (sqlite3_open_v2((data + "/brenier.db").c_str(), &db, SQLITE_OPEN_READONLY, nullptr) != SQLITE_OK)
    throw std::runtime_error("cannot open the database");
  sqlite3_stmt* s = nullptr;
  sqlite3_prepare_v2(db, "SELECT id FROM meshes", -1, &s, nullptr);
  while (sqlite3_step(s) == SQLITE_ROW) meshes.insert(reinterpret_cast<const char*>(sqlite3_column_text(s, 0)));
  sqlite3_finalize(s);
  sqlite3_prepare_v2(db, "SELECT record FROM jobs", -1, &s, nullptr);
  while (sqlite3_step(s) == SQLITE_ROW) add_results(sqlite3_column_blob(s, 0), sqlite3_column_bytes(s, 0));
  sqlite3_finalize(s);
  sqlite3_close(db);
}

// Reads the database and the blob folders directly: blobs no row names, rows whose blob is gone.
std::pair<int, int> orphans_and_missing(const std::string& data, const std::string& database) {
  std::set<std::string> meshes, results;
  named_blobs(data, database, meshes, results);
  int orphans = 0, missing = 0;
  for (const auto& [folder, named] : {std::pair{"/blobs/meshes", &meshes}, std::pair{"/blobs/results", &results}}) {
    std::set<std::string> present;
    if (fs::exists(data + folder))
      for (const auto& e : fs::recursive_directory_iterator(data + folder))
        if (e.is_regular_file()) present.insert(e.path().filename().string());
    for (const auto& p : present) orphans += named->count(p) ? 0 : 1;
    for (const auto& n : *named) missing += present.count(n) ? 0 : 1;
  }
  return {orphans, missing};
}

struct Life {
  double seconds = 0, rss_warm = 0, rss_end = 0, rss_max = 0, slope_mb_per_min = 0;
};

// Least-squares slope of (t, rss) samples, MB per minute.
double slope(const std::vector<std::pair<double, double>>& s) {
  if (s.size() < 3) return 0;
  double mt = 0, mr = 0;
  for (auto [t, r] : s) mt += t, mr += r;
  mt /= s.size();
  mr /= s.size();
  double num = 0, den = 0;
  for (auto [t, r] : s) num += (t - mt) * (r - mr), den += (t - mt) * (t - mt);
  return den > 0 ? 60 * num / den : 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s BRENIERD [--minutes M] [--clients N] [--kill-every S] [--work DIR] [--postgres SH]\n",
                 argv[0]);
    return 2;
  }
  double minutes = 30, kill_every = 180;
  int clients = 64;
  std::string work = fs::temp_directory_path().string() + "/brenier-soak", postgres_sh;
  for (int i = 2; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--minutes") minutes = std::stod(v);
    else if (k == "--clients") clients = std::stoi(v);
    else if (k == "--kill-every") kill_every = std::stod(v);
    else if (k == "--work") work = v;
    else if (k == "--postgres") postgres_sh = v;
    else {
      std::fprintf(stderr, "bench_soak: unknown option %s\n", k.c_str());
      return 2;
    }
  }
  fs::remove_all(work);
  fs::create_directories(work);
  const std::string data = work + "/data";
  // With PostgreSQL: its own cluster, and two replicas on it and on one data directory.
  const std::string pg_state = work + "/pg/url";
  auto pg = [&](const std::string& cmd) { return std::system((postgres_sh + " " + cmd + " " + pg_state + " > /dev/null").c_str()); };
  std::string database;
  if (!postgres_sh.empty()) {
    if (pg("start") != 0) {
      std::fprintf(stderr, "bench_soak: cannot start PostgreSQL with %s\n", postgres_sh.c_str());
      return 1;
    }
    std::ifstream(pg_state) >> database;
  }
  std::vector<std::unique_ptr<Server>> replicas;
  if (database.empty()) {
    replicas.push_back(std::make_unique<Server>(argv[1], data));
  } else {
    for (const char* tag : {"a", "b"})
      replicas.push_back(std::make_unique<Server>(argv[1], data, tag,
                                                  std::vector<std::string>{"--database", database, "--lease-seconds", "10"}));
  }
  std::vector<Server*> servers;
  for (auto& r : replicas) {
    r->start();
    servers.push_back(r.get());
  }
  Server& server = *servers.front();  // its RSS is sampled; the drain goes through it
  Tally tally;
  std::atomic<bool> stop{false};
  Soaker soaker(servers, tally, stop);
  std::vector<std::thread> threads;
  for (int i = 0; i < clients; ++i) threads.emplace_back([&, i] { soaker.run_client(i); });

  std::vector<Life> lives;
  std::vector<std::pair<double, double>> samples;
  auto close_life = [&] {
    Life l;
    l.seconds = server.uptime();
    std::vector<std::pair<double, double>> warm;
    for (auto s : samples)
      if (s.first >= 60) warm.push_back(s);
    if (!warm.empty()) {
      l.rss_warm = warm.front().second;
      l.rss_end = warm.back().second;
      l.slope_mb_per_min = slope(warm);
    }
    for (auto s : samples) l.rss_max = std::max(l.rss_max, s.second);
    lives.push_back(l);
    samples.clear();
  };
  std::mt19937_64 rng(7);
  const auto t0 = Clock::now();
  int kills = 0;
  double next_kill = kill_every * std::uniform_real_distribution<double>(0.5, 1.5)(rng), last_fault = 0;
  std::map<std::string, int> faults;
  // The last fifth of the time runs without kills: one long life to read the RSS from.
  const double faults_until = 60 * minutes * 0.8;
  while (since(t0) < 60 * minutes) {
    std::this_thread::sleep_for(std::chrono::seconds(5));
    samples.emplace_back(server.uptime(), server.rss_mb());
    if (since(t0) < faults_until && since(t0) - last_fault >= next_kill) {
      // Which: the server (SQLite); with replicas, one of them, PostgreSQL, or a replica and PostgreSQL.
      const int what = database.empty() ? 0 : std::uniform_int_distribution<int>(0, 3)(rng);
      const char* names[] = {"replica a", "replica b", "PostgreSQL", "replica a and PostgreSQL"};
      Server* victim = what == 1 ? servers[1] : what == 2 ? nullptr : servers[0];
      if (victim == &server) close_life();
      if (victim) victim->kill9();
      if (what >= 2) pg("kill");
      ++kills;
      ++faults[database.empty() ? "brenierd" : names[what]];
      std::this_thread::sleep_for(std::chrono::milliseconds(what >= 2 ? 2000 : 500));
      if (what >= 2 && pg("resume") != 0) tally.problems.push_back("PostgreSQL did not start again");
      if (victim) victim->start();
      last_fault = since(t0);
      next_kill = kill_every * std::uniform_real_distribution<double>(0.5, 1.5)(rng);
      std::printf("%.0f s: kill -9 #%d (%s), restarted\n", since(t0), kills, database.empty() ? "brenierd" : names[what]);
      std::fflush(stdout);
    }
  }
  stop = true;
  for (auto& t : threads) t.join();
  close_life();

  // Every accepted job must be found and end.
  brenier::client::Options o;
  o.server = server.address();
  Client c(o);
  std::map<std::string, int> states;
  int lost = 0, unfinished = 0;
  const auto drain = Clock::now();
  for (const std::string& id : tally.accepted) {
    for (;;) {
      try {
        const pb::Job j = c.get(id);
        if (j.state() == pb::SUCCEEDED || j.state() == pb::FAILED || j.state() == pb::CANCELLED) {
          ++states[pb::JobState_Name(j.state())];
          if (j.state() == pb::FAILED && j.error().code() == static_cast<int>(grpc::StatusCode::INTERNAL))
            tally.problems.push_back("job " + id + " failed with INTERNAL: " + j.error().message());
          if (j.state() == pb::SUCCEEDED) soaker.download(c, id);
          if (j.state() == pb::FAILED) tally.note(1000 + j.error().code(), j.error().message());
          break;
        }
        if (since(drain) > 900) {
          ++unfinished;
          break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      } catch (const brenier::client::Error& e) {
        if (e.code() == grpc::StatusCode::NOT_FOUND) {
          ++lost;
          break;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(200));
      }
    }
  }
  bool clean_stop = true;
  for (Server* r : servers) clean_stop = r->stop() && clean_stop;
  const auto [orphans, missing] = orphans_and_missing(data, database);
  if (!database.empty()) pg("stop");

  std::printf("\nsoak: %.1f min, %d clients, %zu replica(s) on %s, %d kills -9, %zu jobs accepted\n", since(t0) / 60,
              clients, servers.size(), database.empty() ? "SQLite" : "PostgreSQL", kills, tally.accepted.size());
  for (const auto& [k, n] : faults) std::printf("  killed %-26s %d times\n", k.c_str(), n);
  for (const auto& [k, n] : tally.calls) std::printf("  calls %-16s %lld\n", k.c_str(), static_cast<long long>(n));
  for (const auto& [k, n] : states) std::printf("  jobs %-10s %d\n", k.c_str(), n);
  std::printf("  refusals and job failures (1000 + code: a job's error):\n");
  for (const auto& [k, n] : tally.why) std::printf("    %6lld  %s\n", static_cast<long long>(n), k.c_str());
  std::printf("  lost jobs %d, unfinished after 15 min of draining %d\n", lost, unfinished);
  std::printf("  results downloaded %lld, SHA-256 verified %lld\n", static_cast<long long>(tally.downloads),
              static_cast<long long>(tally.verified));
  std::printf("  after a clean stop (%s): orphaned blobs %d, rows with a missing blob %d\n", clean_stop ? "exit 0" : "NOT exit 0",
              orphans, missing);
  std::printf("  %s lives (s, RSS MB at 60 s -> end, max, slope MB/min after 60 s):\n",
              database.empty() ? "server" : "replica a's");
  for (const Life& l : lives)
    std::printf("    %7.0f s  %7.1f -> %7.1f  max %7.1f  slope %+6.2f\n", l.seconds, l.rss_warm, l.rss_end, l.rss_max,
                l.slope_mb_per_min);
  // Orphans on PostgreSQL: replicas spare an hour's (another may be between a blob and its row).
  bool ok = lost == 0 && unfinished == 0 && (orphans == 0 || !database.empty()) && missing == 0 && clean_stop &&
            tally.downloads == tally.verified && tally.problems.empty();
  for (const auto& p : tally.problems) std::printf("  PROBLEM %s\n", p.c_str());
  std::printf("soak %s\n", ok ? "PASSED" : "FAILED");
  return ok ? 0 : 1;
}

// A brenierd process for the service tests: started on 127.0.0.1 with an ephemeral port
// and its own data directory (and its own PostgreSQL database in the suites' "pg." variants), stopped with SIGTERM (or killed with SIGKILL) on request.
#pragma once

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "client.hpp"
#include "grpc/health/v1/health.grpc.pb.h"
#include "test_database.hpp"

namespace brenier::test {

inline std::string temp_dir(const std::string& name) {
  const std::string d = std::string(BRENIER_TEST_WORK) + "/" + name + "-" + std::to_string(::getpid());
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

class ServerProcess {
 public:
  /// Starts brenierd on `data` with extra flags; waits until it listens. `replica` names one
  /// of several processes on the same data directory (and database).
  ServerProcess(const std::string& data, std::vector<std::string> flags = {}, const std::string& replica = "")
      : data_(data), replica_(replica) {
    start(flags);
  }
  ~ServerProcess() { stop(); }

  void start(const std::vector<std::string>& flags) {
    flags_ = flags;
    const std::string port_file = data_ + replica_ + ".port";
    std::filesystem::remove(port_file);
    std::vector<std::string> args = {BRENIERD, "--listen", "127.0.0.1:0", "--data", data_, "--port-file", port_file,
                                     "--log-level", "warn"};
    // A short lease on PostgreSQL: a killed server's jobs are taken over in seconds.
    const bool own_database = std::find(flags.begin(), flags.end(), "--database") != flags.end();
    if (const std::string db = test_database(data_); !db.empty() && !own_database)
      args.insert(args.end(), {"--database", db, "--lease-seconds", "4"});
    args.insert(args.end(), flags.begin(), flags.end());
    pid_ = ::fork();
    if (pid_ == 0) {
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(argv[0], argv.data());
      ::_exit(127);
    }
    for (int k = 0; k < 300; ++k) {
      std::ifstream in(port_file);
      if (in >> port_) return;
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        throw std::runtime_error("brenierd exited at start");
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    throw std::runtime_error("brenierd did not start");
  }
  /// SIGTERM and wait (the graceful path); returns the exit status.
  int stop() {
    if (pid_ <= 0) return -1;
    ::kill(pid_, SIGTERM);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  }
  /// SIGTERM without waiting (then stop() waits).
  void term() const {
    if (pid_ > 0) ::kill(pid_, SIGTERM);
  }
  void kill9() {
    if (pid_ <= 0) return;
    ::kill(pid_, SIGKILL);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
  }
  void restart() {
    stop();
    start(flags_);
  }
  bool alive() const { return pid_ > 0 && ::kill(pid_, 0) == 0; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  client::Client client(const std::string& token = "") const {
    client::Options o;
    o.server = address();
    o.token = token;
    return client::Client(o);
  }
  /// grpc.health.v1 status of the whole server: 1 SERVING, 2 NOT_SERVING, -1 no answer.
  int health() const {
    auto channel = grpc::CreateChannel(address(), grpc::InsecureChannelCredentials());
    auto stub = grpc::health::v1::Health::NewStub(channel);
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
    grpc::health::v1::HealthCheckRequest req;
    grpc::health::v1::HealthCheckResponse resp;
    return stub->Check(&ctx, req, &resp).ok() ? resp.status() : -1;
  }
  pid_t pid() const { return pid_; }

 private:
  std::string data_, replica_;
  std::vector<std::string> flags_;
  pid_t pid_ = -1;
  int port_ = 0;
};

}  // namespace brenier::test

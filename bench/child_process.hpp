// brenierd as a child process of a harness (bench_service, bench_replicas, bench_soak):
// started with its arguments, its port read from the --port-file it writes.
#pragma once

#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <signal.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "client.hpp"

namespace brenier::bench {

/// Forks and executes args[0] with args; stderr goes to `stderr_file` (appended) when given.
inline pid_t spawn(std::vector<std::string> args, const std::string& stderr_file = "") {
  const pid_t pid = fork();
  if (pid == 0) {
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    if (!stderr_file.empty()) {
      const int fd = ::open(stderr_file.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (fd >= 0) dup2(fd, 2);
    }
    execv(argv[0], argv.data());
    _exit(127);
  }
  return pid;
}

/// The port a server started as `pid` writes into `port_file`, waited for up to 30 s;
/// throws when the server exits or does not write it.
inline int wait_for_port(const std::string& port_file, pid_t pid) {
  for (int k = 0; k < 1500; ++k) {
    std::ifstream in(port_file);
    int port = 0;
    if (in >> port) return port;
    int st = 0;
    if (waitpid(pid, &st, WNOHANG) == pid)
      throw std::runtime_error("brenierd exited at start (wait status " + std::to_string(st) + ")");
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  throw std::runtime_error("brenierd did not start within 30 s");
}

/// A brenierd on loopback for the length of a scope (SIGTERM at its end). `tag` tells apart
/// replicas on one data directory; the first clears the directory unless `keep`.
struct Server {
  pid_t pid = -1;
  std::string address;
  Server(const std::string& brenierd, const std::string& data, const std::vector<std::string>& flags,
         const std::string& tag = "", bool keep = false) {
    if (!keep) std::filesystem::remove_all(data);
    const std::string port_file = data + tag + ".port";
    std::filesystem::remove(port_file);
    std::vector<std::string> args = {brenierd, "--listen", "127.0.0.1:0", "--data", data, "--port-file", port_file,
                                     "--log-level", "warn"};
    args.insert(args.end(), flags.begin(), flags.end());
    pid = spawn(args);
    address = "127.0.0.1:" + std::to_string(wait_for_port(port_file, pid));
  }
  ~Server() {
    if (pid <= 0) return;
    kill(pid, SIGTERM);
    int st = 0;
    waitpid(pid, &st, 0);
  }
  void kill9() {
    kill(pid, SIGKILL);
    int st = 0;
    waitpid(pid, &st, 0);
    pid = -1;
  }
  client::Client client() const {
    client::Options o;
    o.server = address;
    return client::Client(o);
  }
};

}  // namespace brenier::bench

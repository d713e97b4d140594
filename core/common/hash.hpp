// Content hashes (SHA-256, by OpenSSL) for caching per-shape results by what they were
// computed from.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <string_view>

namespace brenier {

/// Incremental SHA-256.
class Sha256 {
 public:
  Sha256();
  ~Sha256();
  Sha256(const Sha256&) = delete;
  Sha256& operator=(const Sha256&) = delete;
  void update(const void* data, std::size_t bytes);
  void update(std::string_view s) { update(s.data(), s.size()); }
  /// The digest as 64 lower-case hex digits; the hash cannot be updated after.
  std::string hex();

 private:
  struct State;
  std::unique_ptr<State> state_;
};

std::string sha256_hex(std::string_view bytes);

/// True for 64 lower-case hex digits (what sha256_hex returns).
bool is_sha256_hex(std::string_view s);

}  // namespace brenier

// Bearer tokens mapped to tenants (--tokens FILE: one "TOKEN TENANT" per line, # comments).
// Without a tokens file every caller is the tenant "default".
//
// Tokens are kept only as their SHA-256, and a presented token is compared with every known
// digest in constant time (CRYPTO_memcmp, no early exit, no map lookup): how long a call
// takes to be refused tells nothing about how much of a token was right. The tokens file must
// not be readable or writable by group or others (like ssh's keys).
#pragma once

#include <grpcpp/grpcpp.h>

#include <vector>
#include <string>

namespace brenier::server {

/// Refuses (kInvalidArgument, saying how to fix it) a secret file that group or others may
/// read or write.
void require_private_file(const std::string& path, const char* what);

class Auth {
 public:
  Auth() = default;
  /// Reads the tokens file; Error(kInvalidArgument) naming the line when it is malformed.
  static Auth from_file(const std::string& path);
  bool enabled() const { return !tenants_.empty(); }
  /// The caller's tenant, from `authorization: Bearer TOKEN`; Error(kUnauthenticated) for a
  /// missing or unknown token when tokens are configured.
  std::string tenant(const grpc::ServerContext* context) const;

 private:
  struct Entry {
    std::string digest;  // SHA-256 of the token, raw 32 bytes
    std::string tenant;
  };
  std::vector<Entry> tenants_;
};

}  // namespace brenier::server

// Bearer tokens mapped to tenants (--tokens FILE: one "TOKEN TENANT" per line, # comments).
// Without a tokens file every caller is the tenant "default".
#pragma once

#include <grpcpp/grpcpp.h>

#include <map>
#include <string>

namespace brenier::server {

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
  std::map<std::string, std::string> tenants_;  // token -> tenant
};

}  // namespace brenier::server

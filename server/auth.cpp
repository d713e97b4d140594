#include "auth.hpp"

#include <fstream>
#include <sstream>

#include "common/error.hpp"

namespace brenier::server {

Auth Auth::from_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) invalid("cannot read the tokens file " + path);
  Auth a;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    std::istringstream ss(line);
    std::string token, tenant, extra;
    if (!(ss >> token) || token[0] == '#') continue;
    if (!(ss >> tenant) || (ss >> extra && extra[0] != '#'))
      invalid(path + ":" + std::to_string(n) + ": expected 'TOKEN TENANT'");
    if (token.size() < 16) invalid(path + ":" + std::to_string(n) + ": tokens must have at least 16 characters");
    if (!a.tenants_.emplace(token, tenant).second) invalid(path + ":" + std::to_string(n) + ": the token is given twice");
  }
  if (a.tenants_.empty()) invalid(path + " holds no token");
  return a;
}

std::string Auth::tenant(const grpc::ServerContext* context) const {
  if (!enabled()) return "default";
  const auto& md = context->client_metadata();
  auto it = md.find("authorization");
  if (it == md.end()) fail(ErrorCode::kUnauthenticated, "this server needs 'authorization: Bearer TOKEN'");
  const std::string value(it->second.data(), it->second.size());
  constexpr std::string_view kBearer = "Bearer ";
  if (value.compare(0, kBearer.size(), kBearer) != 0)
    fail(ErrorCode::kUnauthenticated, "the authorization header must be 'Bearer TOKEN'");
  auto t = tenants_.find(value.substr(kBearer.size()));
  if (t == tenants_.end()) fail(ErrorCode::kUnauthenticated, "unknown token");
  return t->second;
}

}  // namespace brenier::server

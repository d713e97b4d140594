#include "auth.hpp"

#include <openssl/crypto.h>
#include <openssl/sha.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cctype>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "common/error.hpp"

namespace brenier::server {

namespace {

std::string digest(const std::string& token) {
  unsigned char d[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(token.data()), token.size(), d);
  return std::string(reinterpret_cast<const char*>(d), sizeof d);
}

}  // namespace

void require_private_file(const std::string& path, const char* what) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) invalid("cannot read the " + std::string(what) + " file " + path);
  // Private: no access for group or others. Or, for a file root owns (a Kubernetes Secret
  // mounted with fsGroup, which makes it mode 0440 root:GROUP), readable by its group and no
  // one else, as PostgreSQL allows for its keys.
  const bool root_group_read = st.st_uid == 0 && ::geteuid() != 0 && (st.st_mode & 037) == 0;
  if ((st.st_mode & 077) != 0 && !root_group_read) {
    char mode[8];
    std::snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(st.st_mode & 07777));
    invalid("the " + std::string(what) + " file " + path + " is open to group or others (mode " + mode +
            "); make it private: chmod 600 " + path);
  }
}

Auth Auth::from_file(const std::string& path) {
  require_private_file(path, "tokens");
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
    // No credential ships with brenier: the examples' placeholders are refused, not served.
    std::string lower = token;
    for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    if (lower.find("replace-me") != std::string::npos || lower.find("change-me") != std::string::npos)
      invalid(path + ":" + std::to_string(n) +
              ": the token is the documented placeholder; put a secret of your own (openssl rand -hex 32)");
    const std::string d = digest(token);
    for (const Entry& e : a.tenants_)
      if (e.digest == d) invalid(path + ":" + std::to_string(n) + ": the token is given twice");
    a.tenants_.push_back({d, tenant});
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
  // Every entry is compared, whatever matched, in constant time.
  const std::string d = digest(value.substr(kBearer.size()));
  const Entry* match = nullptr;
  for (const Entry& e : tenants_)
    if (CRYPTO_memcmp(e.digest.data(), d.data(), d.size()) == 0) match = &e;
  if (!match) fail(ErrorCode::kUnauthenticated, "unknown token");
  return match->tenant;
}

}  // namespace brenier::server

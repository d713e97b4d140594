// What both databases' stores share about rows: records are serialized protos; a page token
// is the sequence number of the last row given; a job's result size counts towards its
// tenant's storage quota. Internal to the store implementations.
#pragma once

#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "brenier/v1/brenier.pb.h"
#include "common/error.hpp"

// The row operations of Store each backend implements, declared once for both classes.
#define BRENIER_STORE_ROWS_OVERRIDE                                                                                    \
  pb::Mesh put_mesh_with_blob(const std::string& tenant, const pb::Mesh& mesh, const std::string& bytes) override;    \
  std::optional<pb::Mesh> get_mesh(const std::string& tenant, const std::string& id) override;                        \
  std::vector<pb::Mesh> list_meshes(const std::string& tenant, const std::string& token, int limit,                    \
                                    std::string& next) override;                                                       \
  bool delete_mesh(const std::string& tenant, const std::string& id) override;                                        \
  pb::Job insert_job(const std::string& tenant, const pb::Job& job, bool& inserted, int max_unfinished) override;     \
  std::optional<pb::Job> get_job(const std::string& tenant, const std::string& id) override;                          \
  bool has_request(const std::string& tenant, const std::string& request_id) override;                                \
  std::optional<pb::Job> get_job_any(const std::string& id, std::string* tenant) override;                            \
  std::vector<pb::Job> list_jobs(const std::string& tenant, pb::JobState state, const std::string& token, int limit,   \
                                 std::string& next) override;                                                          \
  void update_job(const pb::Job& job) override;                                                                       \
  void delete_job(const std::string& id) override;                                                                    \
  int64_t storage_bytes(const std::string& tenant) override;                                                          \
  std::vector<std::string> unfinished_jobs() override;                                                                \
                                                                                                                       \
 protected:                                                                                                            \
  int delete_finished_jobs(int64_t finished_before, std::vector<std::string>& blobs) override;                        \
  void named_blobs(std::set<std::string>& meshes, std::set<std::string>& results) override;                           \
                                                                                                                       \
 public:

namespace brenier::server::rows {

template <class M>
M parse(const std::string& bytes) {
  M m;
  if (!m.ParseFromString(bytes)) fail(ErrorCode::kInternal, "database: a stored record does not parse");
  return m;
}

// The bytes of a job's results (what it holds of its tenant's storage quota).
inline int64_t result_bytes(const ::brenier::v1::Job& job) {
  int64_t n = 0;
  for (const auto& a : job.result().artifacts()) n += a.size_bytes();
  return n;
}

inline int64_t token_value(const std::string& token) {
  if (token.empty()) return 0;
  char* end = nullptr;
  const long long v = std::strtoll(token.c_str(), &end, 10);
  if (end == token.c_str() || *end != '\0' || v < 0) invalid("page_token '" + token + "' is not one this server gave");
  return v;
}

// A page from rows (seq, record) read in order, of which the query asked for limit + 1: the
// records of the page, and in `next` the token of the following page when there is one more
// row. `row(seq, record)` is called for each row until it returns false.
template <class M, class Rows>
std::vector<M> page(Rows&& next_row, int limit, std::string& next) {
  std::vector<M> out;
  next.clear();
  int64_t seq = 0;
  std::string record;
  while (next_row(seq, record)) {
    if (static_cast<int>(out.size()) == limit) return out;  // one more row: `next` stays
    next = std::to_string(seq);
    out.push_back(parse<M>(record));
  }
  next.clear();
  return out;
}

}  // namespace brenier::server::rows

namespace brenier::server::rows {

[[noreturn]] inline void over_job_quota(int64_t unfinished) {
  fail(ErrorCode::kResourceExhausted, "you have " + std::to_string(unfinished) +
                                          " jobs queued or running, the quota max_jobs_per_tenant of this server");
}

// A database a newer brenierd has written, whose rows this one would misread.
[[noreturn]] inline void refuse_newer(const std::string& where, int version, int mine) {
  fail(ErrorCode::kFailedPrecondition, "the database " + where + " has schema version " + std::to_string(version) +
                                           ", written by a newer brenierd; this one reads up to version " +
                                           std::to_string(mine));
}

}  // namespace brenier::server::rows

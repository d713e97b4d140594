#include "mesh/mesh.hpp"

#include <algorithm>

namespace brenier::mesh {

void Report::warn(std::string code, std::string message, int64_t count) {
  problems.push_back({Problem::Severity::kWarning, std::move(code), std::move(message), count});
}

void Report::error(std::string code, std::string message, int64_t count) {
  problems.push_back({Problem::Severity::kError, std::move(code), std::move(message), count});
}

bool Report::has_errors() const { return first_error() != nullptr; }

const Problem* Report::first_error() const {
  auto it = std::find_if(problems.begin(), problems.end(), [](const Problem& p) {
    return p.severity == Problem::Severity::kError;
  });
  return it == problems.end() ? nullptr : &*it;
}

}  // namespace brenier::mesh

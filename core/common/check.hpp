// Invariant checks that stay on in Release builds. A failed check is a bug of ours, reported
// as brenier::Error(kInternal) with the condition, the place and a message naming the
// element involved, so that a server survives it and a user can report it.
#pragma once

#include <sstream>
#include <string>

#include "common/error.hpp"

namespace brenier::detail {
[[noreturn]] inline void check_failed(const char* cond, const char* file, int line,
                                      const std::string& msg) {
  std::ostringstream os;
  os << "internal check failed: " << cond << " at " << file << ":" << line;
  if (!msg.empty()) os << ": " << msg;
  throw Error(ErrorCode::kInternal, os.str());
}
}  // namespace brenier::detail

#define BRENIER_CHECK(cond, msg)                                                  \
  do {                                                                            \
    if (!(cond)) {                                                                \
      std::ostringstream brenier_check_os_;                                       \
      brenier_check_os_ << msg;                                                   \
      ::brenier::detail::check_failed(#cond, __FILE__, __LINE__,                  \
                                      brenier_check_os_.str());                   \
    }                                                                             \
  } while (false)

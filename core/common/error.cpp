#include "common/error.hpp"

namespace brenier {

const char* error_code_name(ErrorCode code) {
  switch (code) {
    case ErrorCode::kInvalidArgument: return "invalid_argument";
    case ErrorCode::kNotFound: return "not_found";
    case ErrorCode::kFailedPrecondition: return "failed_precondition";
    case ErrorCode::kNotConverged: return "not_converged";
    case ErrorCode::kCancelled: return "cancelled";
    case ErrorCode::kResourceExhausted: return "resource_exhausted";
    case ErrorCode::kInternal: return "internal";
    case ErrorCode::kUnauthenticated: return "unauthenticated";
    case ErrorCode::kUnavailable: return "unavailable";
  }
  return "unknown";
}

std::string name_options(std::string_view m, OptionStyle style) {
  std::string out;
  out.reserve(m.size() + 16);
  for (size_t i = 0; i < m.size(); ++i) {
    if (m[i] == '{') {
      // A field's name: a lower-case letter, then letters, digits and '_' ("refine_p95_tolerance").
      size_t j = i + 1;
      auto name_char = [&](size_t k) {
        const char c = m[k];
        return (c >= 'a' && c <= 'z') || (k > i + 1 && ((c >= '0' && c <= '9') || c == '_'));
      };
      while (j < m.size() && name_char(j)) ++j;
      if (j < m.size() && m[j] == '}' && j > i + 1) {
        std::string name(m.substr(i + 1, j - i - 1));
        if (style == OptionStyle::kFlag) {
          for (char& c : name)
            if (c == '_') c = '-';
          out += "--";
        }
        out += name;
        i = j;
        continue;
      }
    }
    out += m[i];
  }
  return out;
}

}  // namespace brenier

// Errors of the numerical core. Every failure the core reports is a brenier::Error with a
// code from the small set below; the tools turn the code into an exit status and the server
// (one function, server/status.cpp) into a gRPC status. The core never knows about either.
#pragma once

#include <stdexcept>
#include <string>
#include <string_view>

namespace brenier {

enum class ErrorCode {
  kInvalidArgument,     // bad mesh, bad option, wrong topology for the asked domain
  kNotFound,            // a file or object that does not exist
  kFailedPrecondition,  // asked for something whose prerequisite is not met
  kNotConverged,        // a solver stopped without meeting its tolerance
  kCancelled,           // the caller asked to stop
  kResourceExhausted,   // a size limit was hit
  kInternal,            // a broken invariant of ours (a bug)
  kUnauthenticated,     // a caller without valid credentials (the service)
  kUnavailable,         // a service that is shutting down
};

const char* error_code_name(ErrorCode code);

/// Core messages name an option of a request by its field in braces, "{allow_flips}" (the
/// field of jobs::MapRequest or ShapeRequest, and of the proto's specs), never by a command-
/// line flag: each front end names options its own way, in the one place it prints errors.
enum class OptionStyle {
  kFlag,   // "--allow-flips" (brenier-compute)
  kField,  // "allow_flips" (gRPC status messages and job errors)
};
std::string name_options(std::string_view message, OptionStyle style);

class Error : public std::runtime_error {
 public:
  Error(ErrorCode code, const std::string& message)
      : std::runtime_error(message), code_(code) {}
  ErrorCode code() const { return code_; }

 private:
  ErrorCode code_;
};

[[noreturn]] inline void fail(ErrorCode code, const std::string& message) {
  throw Error(code, message);
}
[[noreturn]] inline void invalid(const std::string& message) {
  throw Error(ErrorCode::kInvalidArgument, message);
}

}  // namespace brenier

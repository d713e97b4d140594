// The one place where errors become gRPC statuses (DESIGN.md: thin handlers, one
// conversion). Every handler runs its body through guarded().
#pragma once

#include <grpcpp/grpcpp.h>

#include <exception>
#include <functional>

#include "brenier/v1/brenier.pb.h"
#include "common/error.hpp"

namespace brenier::server {

/// The status of the exception in flight: brenier::Error by its code (kNotConverged, a
/// solver's limit on this input, is ABORTED), std::bad_alloc RESOURCE_EXHAUSTED, anything
/// else INTERNAL. Messages are kept to one line.
grpc::Status to_status(std::exception_ptr e);
/// The code a failed job reports (google.rpc.Code numbers, as grpc::StatusCode).
grpc::StatusCode status_code(ErrorCode code);
/// An error's message as a client sees it: one line, options named as request fields.
std::string client_message(const Error& e);

/// Runs body; any exception becomes its status.
inline grpc::Status guarded(const std::function<grpc::Status()>& body) {
  try {
    return body();
  } catch (...) {
    return to_status(std::current_exception());
  }
}

}  // namespace brenier::server

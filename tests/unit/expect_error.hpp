// Errors are checked by their code and their message, not only by being thrown.
#pragma once

#include <gtest/gtest.h>

#include <functional>
#include <string_view>

#include "common/error.hpp"

namespace brenier::test {

inline ::testing::AssertionResult fails_with(const std::function<void()>& f, ErrorCode code, std::string_view fragment) {
  try {
    f();
  } catch (const Error& e) {
    if (e.code() != code)
      return ::testing::AssertionFailure() << "threw " << error_code_name(e.code()) << " (expected "
                                           << error_code_name(code) << "): " << e.what();
    if (std::string_view(e.what()).find(fragment) == std::string_view::npos)
      return ::testing::AssertionFailure() << "the message \"" << e.what() << "\" does not say \"" << fragment << "\"";
    return ::testing::AssertionSuccess();
  } catch (const std::exception& e) {
    return ::testing::AssertionFailure() << "threw a std::exception that is no brenier::Error: " << e.what();
  }
  return ::testing::AssertionFailure() << "did not throw";
}

}  // namespace brenier::test

/// EXPECT_ERROR(statement, ErrorCode::kX, "a fragment of the message").
#define EXPECT_ERROR(statement, code, fragment) \
  EXPECT_TRUE(::brenier::test::fails_with([&] { (void)(statement); }, code, fragment))

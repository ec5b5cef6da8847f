// Test support: the message of the fluxcal::Error a call throws, so a test can check that it names
// the input or option at fault.
#pragma once

#include <fluxcal/types.hpp>

#include <gtest/gtest.h>

#include <string>

namespace fluxcal_test {

/// What the fluxcal::Error thrown by `call` says; a test failure (and "") when it throws none.
template <typename F>
std::string error_message(F&& call) {
  try {
    call();
  } catch (const fluxcal::Error& e) {
    return e.what();
  }
  ADD_FAILURE() << "no fluxcal::Error thrown";
  return "";
}

}  // namespace fluxcal_test

/// EXPECT that `call` throws fluxcal::Error and its message contains `text`.
#define EXPECT_ERROR_SAYS(call, text)                                                         \
  do {                                                                                        \
    const std::string fluxcal_message_ = fluxcal_test::error_message([&] { (void)(call); }); \
    EXPECT_NE(fluxcal_message_.find(text), std::string::npos) << "message: " << fluxcal_message_; \
  } while (0)

#pragma once
// What the OpenIGTLink client's tests share (igtl_surrogate_test.cpp in process,
// served_tracker_test.cpp against `lftrack serve tracker`): the clocks, a client of a loopback
// port with wide stale limits, and reading as a loop would.

#include <time.h>

#include <chrono>
#include <cstdint>
#include <thread>
#include <vector>

#include "lftrack/drivers/igtl_surrogate.hpp"

namespace lftrack::test {

using namespace std::chrono_literals;

inline std::int64_t igtl_clock_ns(clockid_t clock) {
  timespec ts{};
  clock_gettime(clock, &ts);
  return std::int64_t{ts.tv_sec} * 1'000'000'000 + ts.tv_nsec;
}
inline std::int64_t mono_ns() {
  return igtl_clock_ns(CLOCK_MONOTONIC);
}

// The client's readings until `enough` have come (or `limit` passed), asking as a loop would.
inline std::vector<drivers::SurrogateReading> read_until(drivers::IgtlSurrogateSource& source,
                                                         std::size_t enough,
                                                         std::chrono::seconds limit = 20s) {
  std::vector<drivers::SurrogateReading> got;
  drivers::SurrogateReading batch[64];
  const auto deadline = std::chrono::steady_clock::now() + limit;
  while (got.size() < enough && std::chrono::steady_clock::now() < deadline) {
    const int n = source.read(mono_ns(), batch, 64);
    got.insert(got.end(), batch, batch + n);
    std::this_thread::sleep_for(5ms);
  }
  return got;
}

// A client of the tracker on loopback `port`: quick retries, stale and future limits wide enough
// for a loaded host.
inline drivers::IgtlSurrogateOptions client_of(int port) {
  drivers::IgtlSurrogateOptions o;
  o.port = port;
  o.retry_ms = 20;
  o.stale_ms = 5000;
  o.future_ms = 500;
  return o;
}

}  // namespace lftrack::test

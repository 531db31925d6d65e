// The optical tracker's OpenIGTLink client (drivers/igtl_surrogate.hpp) against the tracker's
// twin as a process of its own (`lftrack serve tracker`). In the real-clock tier with the other
// served devices, so that the sanitized protocol suite does not need the whole program built.

#include <gtest/gtest.h>

#include <algorithm>
#include <csignal>
#include <cstdlib>
#include <optional>
#include <string>
#include <vector>

#include "child_process.hpp"
#include "igtl_test_support.hpp"
#include "lftrack/drivers/igtl_surrogate.hpp"

namespace lftrack {
namespace {

using namespace std::chrono_literals;
using drivers::IgtlSurrogateSource;
using drivers::SurrogateReading;
using test::client_of;
using test::read_until;

// `lftrack serve tracker` as a process of its own: its breathing marker read by the client.
TEST(IgtlSurrogate, ReadsTheTrackersTwinAsAProcessOfItsOwn) {
  test::ChildProcess tracker({LFTRACK_BIN_PATH, "-q", "serve", "tracker", "--listen", "127.0.0.1:0", "--rate",
                              "50", "--message", "position", "--duration", "60"});
  const std::optional<std::string> line = tracker.read_line(60s);
  ASSERT_TRUE(line.has_value()) << "the tracker's twin started";
  const auto colon = line->find("127.0.0.1:");
  ASSERT_NE(colon, std::string::npos) << *line;
  const int port = std::atoi(line->c_str() + colon + 10);
  ASSERT_GT(port, 0) << *line;
  IgtlSurrogateSource s(client_of(port));
  ASSERT_TRUE(s.open().ok());
  const std::vector<SurrogateReading> got = read_until(s, 100, 60s);
  ASSERT_GE(got.size(), 100u) << "two seconds at 50 Hz";
  double low = got[0].amplitude, high = low;
  for (const SurrogateReading& r : got) {
    low = std::min(low, r.amplitude);
    high = std::max(high, r.amplitude);
  }
  // The built-in scene's marker: 10 mm of travel over a 4 s breath, 0.1 mm noise.
  EXPECT_GE(low, -1.0);
  EXPECT_LE(high, 11.0);
  EXPECT_GT(high - low, 1.0) << "half a breath moves the marker";
  EXPECT_EQ(s.counters().refused_stale + s.counters().refused_future + s.counters().protocol_errors, 0);
  tracker.signal(SIGTERM);
  EXPECT_EQ(tracker.wait(20s), 0);
}

}  // namespace
}  // namespace lftrack

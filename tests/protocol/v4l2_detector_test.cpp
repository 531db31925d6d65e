// The V4L2 detector driver against a scripted device through its system-call seam: the ioctl
// sequence, format negotiation, newest-frame capture, and every detector fault of the catalogue
// (docs/faults.md); and the real kernel path where the host has a vivid or v4l2loopback device.

#include "lftrack/drivers/v4l2_detector.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>

#include "protocol_test_support.hpp"
#include "scripted_v4l2_device.hpp"

namespace lftrack {
namespace {

using drivers::DeviceStatus;
using drivers::Frame;
using drivers::V4l2Detector;
using drivers::V4l2DetectorOptions;
using test::ScriptedV4l2Device;

using test::in_ms;

V4l2DetectorOptions options(int rows = 48, int cols = 64) {
  V4l2DetectorOptions o;
  o.device = "/dev/video-scripted";
  o.rows = rows;
  o.cols = cols;
  return o;
}

Frame frame(int rows = 48, int cols = 64) {
  Frame f;
  f.pixels = tracking::Image<std::uint16_t>(rows, cols);
  return f;
}

TEST(V4l2Detector, OpensWithTheIoctlSequenceOfMmapStreaming) {
  ScriptedV4l2Device dev;
  V4l2Detector d(options(), dev);
  ASSERT_TRUE(d.open().ok());
  EXPECT_EQ(d.pixel_format(), V4L2_PIX_FMT_Y16);
  const std::vector<std::string> expected = {"QUERYCAP", "ENUM_FMT", "ENUM_FMT", "ENUM_FMT", "S_FMT",
                                             "REQBUFS",  "QUERYBUF", "QBUF",     "QUERYBUF", "QBUF",
                                             "QUERYBUF", "QBUF",     "QUERYBUF", "QBUF",     "STREAMON"};
  EXPECT_EQ(dev.log, expected);
  EXPECT_TRUE(dev.streaming);
  EXPECT_EQ(dev.queued(), 4u);
  d.close();
  EXPECT_FALSE(dev.streaming);
  EXPECT_EQ(dev.munmap_count, 4);
  EXPECT_EQ(dev.close_count, 1);
}

TEST(V4l2Detector, NegotiatesSixteenBitsFirstAndGreyAsTheStatedFallback) {
  ScriptedV4l2Device twelve;
  twelve.formats = {V4L2_PIX_FMT_GREY, V4L2_PIX_FMT_Y12, V4L2_PIX_FMT_Y10};
  V4l2Detector a(options(), twelve);
  ASSERT_TRUE(a.open().ok());
  EXPECT_EQ(a.pixel_format(), V4L2_PIX_FMT_Y12);

  ScriptedV4l2Device grey;
  grey.formats = {V4L2_PIX_FMT_GREY};
  V4l2Detector b(options(), grey);
  ASSERT_TRUE(b.open().ok());
  EXPECT_EQ(b.pixel_format(), V4L2_PIX_FMT_GREY);
  grey.expose(0, 1000, 200);
  Frame f = frame();
  ASSERT_EQ(b.capture(&f, in_ms(10)), DeviceStatus::kOk);
  EXPECT_EQ(f.pixels.at(5, 10), 210) << "8-bit counts widened to 16 bits, not scaled";
}

TEST(V4l2Detector, RefusesWhatItCannotUseWithTheReason) {
  ScriptedV4l2Device colour;
  colour.formats = {V4L2_PIX_FMT_YUYV};
  const Status s1 = V4l2Detector(options(), colour).open();
  EXPECT_NE(s1.message().find("offers no grey format"), std::string::npos) << s1.message();
  EXPECT_NE(s1.message().find("YUYV"), std::string::npos) << s1.message();

  ScriptedV4l2Device no_streaming;
  no_streaming.capabilities = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_READWRITE;
  const Status s2 = V4l2Detector(options(), no_streaming).open();
  EXPECT_NE(s2.message().find("cannot stream"), std::string::npos) << s2.message();

  ScriptedV4l2Device smaller;
  smaller.width = 32;
  const Status s3 = V4l2Detector(options(), smaller).open();
  EXPECT_NE(s3.message().find("gives 32 x 48"), std::string::npos) << s3.message();

  ScriptedV4l2Device no_trigger;
  V4l2DetectorOptions triggered = options();
  triggered.trigger_control_id = V4L2_CID_USER_BASE + 0x1000;
  const Status s4 = V4l2Detector(triggered, no_trigger).open();
  EXPECT_NE(s4.message().find("no external-trigger control"), std::string::npos) << s4.message();
  EXPECT_EQ(no_trigger.close_count, 1) << "a refused device is closed";

  ScriptedV4l2Device with_trigger;
  with_trigger.trigger_control = triggered.trigger_control_id;
  V4l2Detector t(triggered, with_trigger);
  ASSERT_TRUE(t.open().ok());
  EXPECT_EQ(with_trigger.trigger_value, 1);
}

TEST(V4l2Detector, DeliversTheNewestFrameAndRequeuesTheOlderOnes) {
  ScriptedV4l2Device dev;
  V4l2Detector d(options(), dev);
  ASSERT_TRUE(d.open().ok());
  Frame f = frame();
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kTimeout) << "nothing exposed by the deadline";
  dev.expose(0, 1'000'000, 100);
  dev.expose(1, 2'000'000, 300);
  dev.expose(2, 3'000'000, 500);
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk);
  EXPECT_EQ(f.sequence, 2u);
  EXPECT_EQ(f.timestamp_ns, 3'000'000);
  EXPECT_EQ(f.pixels.at(0, 0), 500);
  EXPECT_EQ(f.pixels.at(47, 63), 563);
  EXPECT_EQ(d.counters().stale_dropped, 2);
  EXPECT_EQ(dev.queued(), 4u) << "every buffer back in the queue";
}

TEST(V4l2Detector, ErrorBuffersAndEioAreFaultsNeverHalfFrames) {
  ScriptedV4l2Device dev;
  V4l2Detector d(options(), dev);
  ASSERT_TRUE(d.open().ok());
  Frame f = frame();
  dev.expose(0, 1000, 100);
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk);
  dev.expose(1, 2000, 999, V4L2_BUF_FLAG_ERROR);
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kFault);
  EXPECT_EQ(f.pixels.at(0, 0), 100) << "the caller's frame is untouched";
  EXPECT_EQ(d.counters().error_buffers, 1);
  dev.expose(2, 3000, 200);
  dev.fail_next_dqbuf(EIO);
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kFault);
  EXPECT_EQ(d.counters().io_errors, 1);
  dev.expose(3, 4000, 300);
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk);
  EXPECT_EQ(f.pixels.at(0, 0), 300);
}

// Found while writing the V4L2 fuzz target (fuzz/fuzz_v4l2.cpp): the driver trusted what a
// device said about a filled buffer. A torn buffer (bytes used short of a frame) was delivered
// with an older frame's pixels in its tail, a time stamp of 10^12 s overflowed the nanosecond
// count, a device that never said "no more buffers" held the cycle forever, and a device that
// granted 4 x 10^9 buffers made the driver allocate for all of them.
TEST(V4l2Detector, TornBuffersBadTimeStampsAndEndlessDevicesAreFaultsNotFrames) {
  ScriptedV4l2Device dev;
  V4l2Detector d(options(), dev);
  ASSERT_TRUE(d.open().ok());
  Frame f = frame();
  dev.expose(0, 1000, 100);
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk);
  const std::uint32_t whole = 48 * 64 * 2;
  dev.expose(1, 2000, 999, 0, whole - 1);
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kFault) << "a buffer one byte short is torn";
  EXPECT_EQ(f.pixels.at(0, 0), 100) << "the caller's frame is untouched";
  dev.expose_raw_time(2, 1'000'000'000'000, 0);
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kFault) << "10^12 s is no monotonic time";
  dev.expose_raw_time(3, 5, -1);
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kFault) << "negative microseconds";
  dev.expose_raw_time(4, 5, 1'000'000);
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kFault) << "a million microseconds";
  EXPECT_EQ(d.counters().bad_buffers, 4);
  dev.expose(5, 6000, 300, 0, whole);
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk) << "exactly a frame's bytes is whole";
  EXPECT_EQ(f.pixels.at(0, 0), 300);
  EXPECT_EQ(dev.queued(), 4u) << "every refused buffer went back to the queue";

  dev.endless = true;
  dev.expose(6, 7000, 400);
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kFault) << "a device that never runs dry";
  EXPECT_EQ(d.counters().bad_buffers, 5);

  ScriptedV4l2Device greedy;
  greedy.granted_buffers = 4'000'000'000u;
  const Status s = V4l2Detector(options(), greedy).open();
  EXPECT_NE(s.message().find("gives 4000000000 buffers"), std::string::npos) << s.message();
  EXPECT_EQ(greedy.close_count, 1);
}

TEST(V4l2Detector, SequenceGapsAreCountedWrapsAreNotAndGoingBackwardsIsAFault) {
  ScriptedV4l2Device dev;
  V4l2Detector d(options(), dev);
  ASSERT_TRUE(d.open().ok());
  Frame f = frame();
  dev.expose(0xFFFFFFFEu, 1000, 1);
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk);
  dev.expose(0xFFFFFFFFu, 2000, 1);
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk);
  dev.expose(0, 3000, 1);  // wrap
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk);
  EXPECT_EQ(d.counters().sequence_gaps, 0);
  dev.expose(4, 4000, 1);  // frames 1..3 lost
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk);
  EXPECT_EQ(d.counters().sequence_gaps, 1);
  EXPECT_EQ(d.counters().frames_lost, 3);
  dev.expose(2, 5000, 1);  // backwards: the device restarted its count
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kFault);
  EXPECT_EQ(d.counters().backwards, 1);
}

TEST(V4l2Detector, UnplugClosesAtOnceAndReopenOutsideTheCycleWorks) {
  ScriptedV4l2Device dev;
  V4l2Detector d(options(), dev);
  ASSERT_TRUE(d.open().ok());
  Frame f = frame();
  dev.unplug();
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kDisconnected);
  EXPECT_FALSE(d.is_open());
  EXPECT_EQ(dev.close_count, 1);
  EXPECT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kDisconnected) << "no calls on a closed device";
  EXPECT_FALSE(d.reopen().ok()) << "still unplugged";
  dev.plug();
  ASSERT_TRUE(d.reopen().ok());
  EXPECT_EQ(d.counters().reopens, 1);
  dev.expose(7, 1000, 42);
  ASSERT_EQ(d.capture(&f, in_ms(5)), DeviceStatus::kOk);
  EXPECT_EQ(f.pixels.at(0, 1), 43);
}

TEST(V4l2FrameSource, APairIsBothFramesWithinTheSkewWindowOrAStatus) {
  ScriptedV4l2Device a, b;
  std::vector<std::unique_ptr<V4l2Detector>> detectors;
  detectors.push_back(std::make_unique<V4l2Detector>(options(), a));
  detectors.push_back(std::make_unique<V4l2Detector>(options(), b));
  drivers::V4l2FrameSource source(std::move(detectors), 2.0);
  drivers::FramePair pair;
  ASSERT_TRUE(source.open(&pair).ok());
  ASSERT_EQ(pair.frames.size(), 2u);
  for (auto& f : pair.frames) f.pixels = tracking::Image<std::uint16_t>(48, 64);
  a.expose(0, 10'000'000, 1);
  b.expose(0, 11'000'000, 2);
  ASSERT_EQ(source.acquire(&pair, in_ms(5)), DeviceStatus::kOk);
  EXPECT_EQ(pair.frames[0].pixels.at(0, 0), 1);
  EXPECT_EQ(pair.frames[1].pixels.at(0, 0), 2);
  a.expose(1, 20'000'000, 1);
  EXPECT_EQ(source.acquire(&pair, in_ms(5)), DeviceStatus::kTimeout) << "the second detector has none";
  b.expose(1, 25'000'000, 2);  // 5 ms after the first detector's newest
  a.expose(2, 30'000'000, 1);
  b.expose(2, 36'000'000, 2);
  EXPECT_EQ(source.acquire(&pair, in_ms(5)), DeviceStatus::kFault);
  EXPECT_EQ(source.skewed_pairs(), 1);
}

TEST(V4l2Detector, RealKernelDevice) {
  namespace fs = std::filesystem;
  std::string found;
  for (int i = 0; i < 16 && found.empty(); ++i) {
    const fs::path name = fs::path("/sys/class/video4linux") / ("video" + std::to_string(i)) / "name";
    std::error_code ec;
    if (!fs::exists(name, ec)) continue;
    std::ifstream in(name);
    std::string driver;
    std::getline(in, driver);
    if (driver.find("vivid") != std::string::npos || driver.find("Dummy") != std::string::npos ||
        driver.find("loopback") != std::string::npos)
      found = "/dev/video" + std::to_string(i);
  }
  if (found.empty()) GTEST_SKIP() << "no vivid or v4l2loopback device on this host (modprobe vivid)";
  V4l2DetectorOptions o;
  o.device = found;
  o.rows = 480;
  o.cols = 640;
  V4l2Detector d(o);
  const Status s = d.open();
  if (!s.ok()) GTEST_SKIP() << "the device offers no grey format at 640 x 480: " << s.message();
  Frame f = frame(480, 640);
  EXPECT_EQ(d.capture(&f, in_ms(2000)), DeviceStatus::kOk);
}

}  // namespace
}  // namespace lftrack

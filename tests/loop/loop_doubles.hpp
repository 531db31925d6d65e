#pragma once
// What the loop's own tests run it on: two small detectors' geometry, frames of a fixed pattern
// for them (anatomy enough for the image-quality gate), and a frame source of such frames.

#include <cstdint>

#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/loop/loop_parts.hpp"

namespace lftrack::test {

inline constexpr int kPatternRows = 48, kPatternCols = 40;

// Sizes `pair` for two detectors and fills both with the pattern (timestamps left to the caller).
inline void open_pattern_pair(drivers::FramePair* pair) {
  pair->frames.resize(2);
  for (auto& f : pair->frames) {
    f.pixels = tracking::Image<std::uint16_t>(kPatternRows, kPatternCols, 2000);
    for (int r = 0; r < kPatternRows; ++r)
      for (int c = 0; c < kPatternCols; ++c)
        f.pixels.at(r, c) = static_cast<std::uint16_t>(1000 + (7 * r + 13 * c) % 800);
  }
}

// Two isocentric views, A and B at +-45 degrees, of the pattern's size, their full windows and
// no detector corrections; nothing else of the parts is set.
inline loop::LoopParts pattern_loop_parts() {
  loop::LoopParts parts;
  for (const char* name : {"A", "B"}) {
    const double s = name[0] == 'A' ? 1.0 : -1.0;
    auto view = tracking::XrayView::isocentric(name, Eigen::Vector3d::Zero(), Eigen::Vector3d(0.7071, s * 0.7071, 0),
                                               Eigen::Vector3d(0, 0, 1), 1000, 1400, kPatternRows, kPatternCols, 0.8);
    if (!view.ok()) continue;  // the caller's size checks fail
    parts.geometry.views.push_back(*view);
    parts.geometry.roi_windows.push_back(tracking::PixelWindow::full(view->rows, view->cols));
    parts.corrections.emplace_back();
  }
  return parts;
}

// Pattern frames, exposed when the loop asks (on its simulated clock too): never stale.
class PatternFrames final : public drivers::FrameSource {
 public:
  Status open(drivers::FramePair* pair) override {
    open_pattern_pair(pair);
    return {};
  }
  void request_exposure(std::int64_t exposure_time_ns) override { exposure_ns_ = exposure_time_ns; }
  drivers::DeviceStatus acquire(drivers::FramePair* pair, drivers::Deadline) override {
    ++sequence_;
    for (auto& f : pair->frames) {
      f.timestamp_ns = exposure_ns_;
      f.sequence = sequence_;
    }
    return drivers::DeviceStatus::kOk;
  }
  void close() override {}

 private:
  std::int64_t exposure_ns_ = 0;
  std::uint32_t sequence_ = 0;
};

}  // namespace lftrack::test

#pragma once
// Prediction of the patient's own motion over the loop's latency (frame -> couch in motion).
// A polynomial of `order` 1 (a line) or 2 (a parabola), fitted by least squares per component to
// the last `window` estimates of the patient's offset, evaluated `lookahead_s` after the newest.
// Breathing-like motion is smooth over a few hundred milliseconds, so the fit removes most of the
// lag a couch with latency would otherwise leave; a parabola also follows the turning points,
// where a line overshoots. A jump (a shift, a resumed HOLD) resets the history, so it never
// extrapolates across one. Fixed capacity, allocates nothing.
//
// Translations only, unless `predict_rotations` (a scene's loop.predict_rotations): a rotation is
// predicted as its newest estimate. Breathing moves the target
// along the room's axes (the built-in scene's 0.2 degree of breathing rotation lags by about 0.05
// degree unpredicted), while a registration's rotation is its noisiest part, and a registration
// that over-reads a rotation (the small closed-loop scene reads about 1.3 to 2 times the true
// rotation about y) closes a loop through the couch: extrapolated, the over-read grew into an
// oscillation of about 5 cycles, the true rotation swinging by up to +-0.5 degree and the commands
// by +-0.7 degree; one step past the gate's 2 degree limit holds the loop (most likely what a
// served-couch breathing run in CI met at cycle 14). Unextrapolated, the same run swings by +-0.16
// degree and commands +-0.25 degree: each correction leaves (1 - over-read) of the last.
//
// Extrapolation amplifies the estimates' noise, most where there are few of them: a parabola
// through 4 estimates 0.1 s apart, evaluated 0.2 s ahead, weighs them so that independent noise
// comes out 5.7 times larger (a line through 2 of them at 30 Hz, 0.13 s ahead: 6.4 times). After
// every alignment and resume the history starts empty, and so a registration's 0.15 degree of
// rotational noise once became a 2.2 degree step that the gate held (the room's sudden-shift test,
// 7 runs in 20 on a loaded host). So the fit's order drops, to a line and then to the newest
// estimate alone, until its noise gain is at most kMaxNoiseGain: a full window as the scenes set it
// (a parabola over 8 estimates at 10 Hz, 2.1; over 24 at 30 Hz, 1.05) predicts as configured.
//
// Times are integer nanoseconds on any clock (CLOCK_MONOTONIC, the loop's simulated clock) and
// only their differences count: the fit is the same bit for bit whatever the clock's origin. (It
// took seconds as doubles once: 1e-9 * ns rounds differently at every origin, so two runs of the
// same seed on the simulated clock, which starts at the host's uptime, drifted apart by 1e-12 mm
// from the third cycle on and by 0.05 mm in the residual's p95 after 120 cycles.)

#include <array>
#include <cstdint>

#include "lftrack/tracking/pose.hpp"

namespace lftrack::loop {

class MotionPredictor {
 public:
  static constexpr int kCapacity = 32;
  // The most the prediction may multiply the deviation of independent noise in the estimates by.
  static constexpr double kMaxNoiseGain = 2.5;
  // window < 2: no prediction (the newest estimate is returned as it is). With fewer estimates
  // than order + 2 the order drops (a line from 2, the newest alone from 1), and it drops further
  // while the fit's noise gain is above kMaxNoiseGain.
  MotionPredictor(int window, int order, double lookahead_s, bool predict_rotations = false);

  void reset() { count_ = 0; }
  // The patient's offset (delta 6-vector, mm and rad) estimated at time t_ns.
  void add(std::int64_t t_ns, const tracking::Vector6d& offset);
  int size() const { return count_; }
  // The offset expected lookahead_s after the newest estimate; zero with no estimate.
  tracking::Vector6d predict() const;

  // What a full window of estimates `period_s` apart predicts with, as predict() chooses: the
  // order (`order`, 1, or 0 for the newest estimate alone) and that fit's noise gain; and the
  // configured order's gain (infinite where the window is shorter than order + 2). A scene whose window is too short for its order is told so
  // (loop_session.cpp) rather than silently predicting with a line.
  struct FullWindow {
    int order_used = 0;
    double gain_used = 1.0;
    double gain_configured = 1.0;
  };
  static FullWindow full_window(int window, int order, double period_s, double lookahead_s);

 private:
  int window_;
  int order_;
  double lookahead_s_;
  bool predict_rotations_;
  std::array<std::int64_t, kCapacity> t_ns_{};
  std::array<tracking::Vector6d, kCapacity> x_{};
  int count_ = 0;  // newest last
};

}  // namespace lftrack::loop

#pragma once
// The correlation model between an external breathing surrogate and the target (issue 58), as
// CyberKnife Synchrony, Vero and KIM fit one between sparse X-ray pairs: the target's position
// (room frame, mm, each axis on its own) as a function of the surrogate's amplitude s (a chest
// marker's displacement, any unit) and its rate r = ds/dt (per second), fitted by least squares to
// pairs of (surrogate at the X-ray exposure, registered target position):
//   kLinear      p = a + b s
//   kQuadratic   p = a + b s + c s^2
// and, with `hysteresis`, + d r: the target leads or lags the chest, so inhale and exhale follow
// different paths through (s, p) (Synchrony's two curves; Low's "5D" model's airflow term).
//
// When it may be used (ready()): at least `min_pairs` pairs, spread over at least `min_span_s` (a
// breathing cycle: the scene's period), among them an inhale (r > 0) and an exhale (r < 0), whose
// surrogate amplitudes span at least kMinCoverage of the range the surrogate itself covered over
// the last breaths (observe()), at least one more distinct level of the surrogate than the model
// has amplitude terms (3 for a line, 4 for a parabola; levels kLevelSpacing of that range apart),
// and a fit whose normal equations are well conditioned. These rules matter: X-rays every half
// period (2 s in a 4 s breath), or at 1 Hz in a 4 s breath at some phases, see two phases of every
// breath, inhale and exhale at the same heights; a model fitted there agrees with every later
// X-ray and errs by millimetres, up to centimetres, in between. A surrogate that never moved fits
// nothing.
//
// within_fit() says whether a reading lies within the amplitudes and rates the model was fitted on
// (with a margin): outside, the model extrapolates (a cough, a gasp, a deep breath) and the loop
// should take an X-ray pair early rather than trust it.
//
// check() compares the model's prediction at a new pair's surrogate with the registered position:
// within `tolerance_mm` (3D) it agrees; beyond it is a miss, and the model is refitted with the new
// pair; a second miss in a row says the relation has changed under it (the surrogate drifted from
// the target, the patient moved) and the loop must HOLD. Either way the pair joins the model, which
// keeps the newest `window` pairs, so it follows a slow drift of the relation.
//
// Fixed capacity; add(), check() and predict() allocate nothing. Times are integer nanoseconds on
// the loop's clock; only differences count.

#include <Eigen/Core>
#include <array>
#include <cstdint>

#include "lftrack/tracking/status.hpp"

namespace lftrack::loop {

struct CorrelationModelSpec {
  enum class Order { kLinear, kQuadratic };
  // A line with the rate term by default: as good as the parabola on the thoracic breath (BENCHMARKS.md)
  // and needing one level of the surrogate fewer, which X-rays at a steady rate in a steady breath
  // do not always give (1 Hz in a 4 s breath visits four phases).
  Order order = Order::kLinear;
  bool hysteresis = true;
  int window = 20;            // the newest pairs fitted, 4..kCapacity
  int min_pairs = 8;          // before ready(), at least the model's coefficients + 2
  double min_span_s = 4.0;    // the pairs' first to last exposure, at least one breathing cycle
  double tolerance_mm = 1.5;  // check(): a prediction this far (3D) from the registration misses
};

Status check_correlation_model_spec(const CorrelationModelSpec& spec);

// One surrogate sample: amplitude s and rate r = ds/dt (per second), at t_ns on the loop's clock.
struct SurrogateSample {
  std::int64_t t_ns = 0;
  double amplitude = 0;
  double rate_per_s = 0;
};

// The surrogate's stream as the loop reads it: the newest readings, and the sample the model takes,
// whose rate is the least-squares slope of the readings within `rate_window_s` of the newest (a
// derivative of a noisy stream by differences would multiply its noise by the sample rate).
// Fixed capacity, allocates nothing.
class SurrogateStream {
 public:
  static constexpr int kCapacity = 32;
  explicit SurrogateStream(double rate_window_s = 0.1) : rate_window_s_(rate_window_s) {}
  void reset() { count_ = 0; }
  // A reading at t_ns; one that is not finite, or not newer than the last, is refused (false).
  bool push(std::int64_t t_ns, double amplitude);
  int readings() const { return count_; }
  // The newest reading with its rate; rate 0 and false with fewer than 3 readings in the window.
  bool newest(SurrogateSample* sample) const;

 private:
  double rate_window_s_;
  std::array<std::int64_t, kCapacity> t_ns_{};
  std::array<double, kCapacity> amplitude_{};
  int count_ = 0;  // oldest first
};

// The pairs a model keeps at `xray_hz`: at least the spec's window, enough to span its min_span_s
// (a breathing cycle) with a quarter to spare, at most CorrelationModel::kCapacity. A rate whose
// kCapacity pairs cannot span min_span_s is refused (the study's options, the scene).
int model_window_at(const CorrelationModelSpec& spec, double xray_hz);
// The surrogate stream's rate window (s): 0.1 s, widened to hold 2.5 reading intervals below 25 Hz
// and narrowed to 30 readings (SurrogateStream's capacity) above 300 Hz.
double rate_window_at(double sample_rate_hz);

class CorrelationModel {
 public:
  static constexpr int kCapacity = 64;
  static constexpr int kTerms = 4;  // 1, s, s^2, r; the terms the spec leaves out fit to zero

  explicit CorrelationModel(const CorrelationModelSpec& spec);

  static constexpr double kMinCoverage = 0.6;
  static constexpr double kLevelSpacing = 0.125;  // of the surrogate's range, between two levels
  // The pairs' amplitudes may be exceeded by this fraction of their span before within_fit fails.
  static constexpr double kFitMargin = 0.1;

  // Forgets every pair (a new set-up, a resumed HOLD) and the surrogate's range.
  void reset();
  // Every surrogate reading the loop takes: the range the pairs must cover is the surrogate's over
  // the last one to two min_span_s windows. A non-finite reading is ignored.
  void observe(const SurrogateSample& surrogate);
  bool within_fit(const SurrogateSample& surrogate) const { return within(surrogate, kFitMargin); }
  // The same with a margin of `margin` times the fitted span (amplitude and rate).
  bool within(const SurrogateSample& surrogate, double margin) const;
  // Adds a pair and refits. A pair with a non-finite value is refused (false) and changes nothing.
  bool add(const SurrogateSample& surrogate, const Eigen::Vector3d& target_room_mm);

  enum class Check { kNotReady, kAgrees, kMissRefitted, kMissAgain };
  // The new pair against the prediction, then add(). kNotReady: there was no model to check
  // against (the pair is still added). A non-finite pair is kMissAgain: nothing trusts it.
  Check check(const SurrogateSample& surrogate, const Eigen::Vector3d& target_room_mm);

  bool ready() const { return ready_; }
  // The target position the model gives for a surrogate sample; the last fit's, valid only when
  // ready() (otherwise NaN, which the gate refuses).
  Eigen::Vector3d predict(const SurrogateSample& surrogate) const;

  int pairs() const { return count_; }
  // The fit's RMS residual per axis over its pairs (mm), and the last check's 3D error (mm; NaN
  // before the first check of a ready model).
  const Eigen::Vector3d& fit_rms_mm() const { return fit_rms_mm_; }
  double last_check_error_mm() const { return last_check_error_mm_; }
  // Per axis, the coefficients of 1, s', s'^2 and r' on the standardised surrogate (fitted about
  // the pairs' mean amplitude and scaled by their deviations), for the journal.
  const Eigen::Matrix<double, 3, kTerms>& coefficients() const { return coefficients_; }
  // Why ready() is false, for a log line or a HOLD's text ("" when ready).
  const char* not_ready_reason() const { return not_ready_; }

 private:
  void refit();
  Eigen::Matrix<double, kTerms, 1> basis(const SurrogateSample& s) const;

  CorrelationModelSpec spec_;
  std::array<SurrogateSample, kCapacity> surrogate_{};
  std::array<Eigen::Vector3d, kCapacity> target_{};
  int count_ = 0;  // oldest first
  int misses_in_a_row_ = 0;
  bool ready_ = false;
  const char* not_ready_ = "no pairs yet";
  double mean_s_ = 0, scale_s_ = 1, scale_r_ = 1;
  double fit_min_s_ = 0, fit_max_s_ = 0;  // the fitted pairs' amplitudes
  double fit_min_r_ = 0, fit_max_r_ = 0;  // and rates
  // The surrogate's range in the current window of min_span_s (from window_start_ns_) and the one
  // before it.
  std::int64_t window_start_ns_ = 0;
  bool observed_ = false, previous_observed_ = false;
  double window_min_ = 0, window_max_ = 0, previous_min_ = 0, previous_max_ = 0;
  Eigen::Matrix<double, 3, kTerms> coefficients_ = Eigen::Matrix<double, 3, kTerms>::Zero();
  Eigen::Vector3d fit_rms_mm_ = Eigen::Vector3d::Zero();
  double last_check_error_mm_;
};

}  // namespace lftrack::loop

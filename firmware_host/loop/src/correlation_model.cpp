#include "lftrack/loop/correlation_model.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>

namespace lftrack::loop {
namespace {

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
// The smallest eigenvalue of the standardised normal equations, per pair, that makes a fit: the
// coefficients' error along the weakest direction is the registration's error / sqrt(eigenvalue),
// so below this two terms explain nearly the same thing (pairs from two phases of the breath:
// 1.6e-3 with the quadratic and rate terms; pairs spread over the breath: 0.16-0.9).
constexpr double kMinEigenvaluePerPair = 2e-2;

bool finite(const SurrogateSample& s) {
  return std::isfinite(s.amplitude) && std::isfinite(s.rate_per_s);
}

// The amplitude terms (1, s and s^2 when quadratic): the distinct surrogate levels the pairs must
// hold are one more.
int amplitude_terms_of(const CorrelationModelSpec& spec) {
  return spec.order == CorrelationModelSpec::Order::kQuadratic ? 3 : 2;
}

int terms_of(const CorrelationModelSpec& spec) {
  return amplitude_terms_of(spec) + (spec.hysteresis ? 1 : 0);
}

}  // namespace

Status check_correlation_model_spec(const CorrelationModelSpec& spec) {
  if (spec.window < 4 || spec.window > CorrelationModel::kCapacity)
    return invalid_argument("correlation model: window must be 4.." +
                            std::to_string(CorrelationModel::kCapacity) + " pairs");
  if (spec.min_pairs < terms_of(spec) + 2 || spec.min_pairs > spec.window)
    return invalid_argument("correlation model: min_pairs must be at least the model's terms + 2 (" +
                            std::to_string(terms_of(spec) + 2) + ") and at most the window (" +
                            std::to_string(spec.window) + ")");
  if (!(spec.min_span_s >= 1 && spec.min_span_s <= 600))
    return invalid_argument("correlation model: min_span_s must be 1..600 s (a breathing cycle)");
  if (!(spec.tolerance_mm > 0 && spec.tolerance_mm <= 20))
    return invalid_argument("correlation model: tolerance_mm must be in (0, 20] mm");
  return {};
}

bool SurrogateStream::push(std::int64_t t_ns, double amplitude) {
  if (!std::isfinite(amplitude) || (count_ > 0 && t_ns <= t_ns_[std::size_t(count_ - 1)])) return false;
  if (count_ == kCapacity) {
    std::move(t_ns_.begin() + 1, t_ns_.end(), t_ns_.begin());
    std::move(amplitude_.begin() + 1, amplitude_.end(), amplitude_.begin());
    --count_;
  }
  t_ns_[std::size_t(count_)] = t_ns;
  amplitude_[std::size_t(count_)] = amplitude;
  ++count_;
  return true;
}

bool SurrogateStream::newest(SurrogateSample* sample) const {
  if (count_ == 0) return false;
  const std::int64_t t_last = t_ns_[std::size_t(count_ - 1)];
  *sample = {t_last, amplitude_[std::size_t(count_ - 1)], 0.0};
  // The slope about the window's mean time (times relative to the newest: exact in double).
  double n = 0, sum_t = 0, sum_a = 0;
  int first = count_ - 1;
  while (first > 0 && 1e-9 * double(t_last - t_ns_[std::size_t(first - 1)]) <= rate_window_s_) --first;
  for (int i = first; i < count_; ++i) {
    n += 1;
    sum_t += 1e-9 * double(t_ns_[std::size_t(i)] - t_last);
    sum_a += amplitude_[std::size_t(i)];
  }
  if (n < 3) return false;
  const double mean_t = sum_t / n, mean_a = sum_a / n;
  double stt = 0, sta = 0;
  for (int i = first; i < count_; ++i) {
    const double dt = 1e-9 * double(t_ns_[std::size_t(i)] - t_last) - mean_t;
    stt += dt * dt;
    sta += dt * (amplitude_[std::size_t(i)] - mean_a);
  }
  if (!(stt > 0)) return false;
  sample->rate_per_s = sta / stt;
  return true;
}

CorrelationModel::CorrelationModel(const CorrelationModelSpec& spec)
    : spec_(spec), last_check_error_mm_(kNan) {
  spec_.window = std::clamp(spec_.window, 4, kCapacity);
}

void CorrelationModel::reset() {
  count_ = 0;
  coefficients_.setZero();
  fit_rms_mm_.setZero();
  observed_ = previous_observed_ = false;
  misses_in_a_row_ = 0;
  ready_ = false;
  not_ready_ = "no pairs yet";
  last_check_error_mm_ = kNan;
}

bool CorrelationModel::add(const SurrogateSample& surrogate, const Eigen::Vector3d& target_room_mm) {
  if (!finite(surrogate) || !target_room_mm.allFinite()) return false;
  if (count_ == spec_.window) {
    std::move(surrogate_.begin() + 1, surrogate_.begin() + count_, surrogate_.begin());
    std::move(target_.begin() + 1, target_.begin() + count_, target_.begin());
    --count_;
  }
  surrogate_[std::size_t(count_)] = surrogate;
  target_[std::size_t(count_)] = target_room_mm;
  ++count_;
  refit();
  return true;
}

CorrelationModel::Check CorrelationModel::check(const SurrogateSample& surrogate,
                                                const Eigen::Vector3d& target_room_mm) {
  if (!finite(surrogate) || !target_room_mm.allFinite()) {
    misses_in_a_row_ = 2;
    return Check::kMissAgain;
  }
  if (!ready_) {  // a model being built anew: no earlier miss counts against it
    misses_in_a_row_ = 0;
    add(surrogate, target_room_mm);
    return Check::kNotReady;
  }
  last_check_error_mm_ = (predict(surrogate) - target_room_mm).norm();
  const bool miss = !(last_check_error_mm_ <= spec_.tolerance_mm);
  add(surrogate, target_room_mm);
  if (!miss) {
    misses_in_a_row_ = 0;
    return Check::kAgrees;
  }
  return ++misses_in_a_row_ >= 2 ? Check::kMissAgain : Check::kMissRefitted;
}

void CorrelationModel::observe(const SurrogateSample& s) {
  if (!finite(s)) return;
  const std::int64_t window_ns = std::max<std::int64_t>(1, std::int64_t(spec_.min_span_s * 1e9));
  if (!observed_ || s.t_ns - window_start_ns_ >= window_ns || s.t_ns < window_start_ns_) {
    previous_observed_ = observed_ && s.t_ns - window_start_ns_ < 2 * window_ns && s.t_ns >= window_start_ns_;
    previous_min_ = window_min_;
    previous_max_ = window_max_;
    window_start_ns_ = s.t_ns;
    window_min_ = window_max_ = s.amplitude;
    observed_ = true;
    return;
  }
  window_min_ = std::min(window_min_, s.amplitude);
  window_max_ = std::max(window_max_, s.amplitude);
}

bool CorrelationModel::within(const SurrogateSample& s, double fraction) const {
  if (!ready_ || !finite(s)) return false;
  const double margin = fraction * (fit_max_s_ - fit_min_s_);
  const double rate_margin = fraction * (fit_max_r_ - fit_min_r_);
  return s.amplitude >= fit_min_s_ - margin && s.amplitude <= fit_max_s_ + margin &&
         s.rate_per_s >= fit_min_r_ - rate_margin && s.rate_per_s <= fit_max_r_ + rate_margin;
}

Eigen::Matrix<double, CorrelationModel::kTerms, 1> CorrelationModel::basis(const SurrogateSample& s) const {
  const double u = (s.amplitude - mean_s_) / scale_s_;
  return {1.0, u, spec_.order == CorrelationModelSpec::Order::kQuadratic ? u * u : 0.0,
          spec_.hysteresis ? s.rate_per_s / scale_r_ : 0.0};
}

Eigen::Vector3d CorrelationModel::predict(const SurrogateSample& surrogate) const {
  if (!ready_ || !finite(surrogate)) return Eigen::Vector3d::Constant(kNan);
  return coefficients_ * basis(surrogate);
}

void CorrelationModel::refit() {
  ready_ = false;
  // Nothing of an earlier fit is left for a reader (the journal) while the model is not ready.
  coefficients_.setZero();
  fit_rms_mm_.setZero();
  if (count_ < spec_.min_pairs) {
    not_ready_ = "fewer pairs than the model needs (min_pairs)";
    return;
  }
  const double span_s = 1e-9 * double(surrogate_[std::size_t(count_ - 1)].t_ns - surrogate_[0].t_ns);
  if (!(span_s >= spec_.min_span_s)) {
    not_ready_ = "the pairs span less than a breathing cycle (min_span_s)";
    return;
  }
  bool inhale = false, exhale = false;
  double sum_s = 0, sum_r2 = 0;
  fit_min_s_ = fit_max_s_ = surrogate_[0].amplitude;
  fit_min_r_ = fit_max_r_ = surrogate_[0].rate_per_s;
  for (int i = 0; i < count_; ++i) {
    const SurrogateSample& s = surrogate_[std::size_t(i)];
    inhale = inhale || s.rate_per_s > 0;
    exhale = exhale || s.rate_per_s < 0;
    sum_s += s.amplitude;
    sum_r2 += s.rate_per_s * s.rate_per_s;
    fit_min_s_ = std::min(fit_min_s_, s.amplitude);
    fit_min_r_ = std::min(fit_min_r_, s.rate_per_s);
    fit_max_r_ = std::max(fit_max_r_, s.rate_per_s);
    fit_max_s_ = std::max(fit_max_s_, s.amplitude);
  }
  if (!inhale || !exhale) {
    not_ready_ = "the pairs hold no inhale or no exhale";
    return;
  }
  mean_s_ = sum_s / count_;
  double sum_d2 = 0;
  for (int i = 0; i < count_; ++i) {
    const double d = surrogate_[std::size_t(i)].amplitude - mean_s_;
    sum_d2 += d * d;
  }
  scale_s_ = std::sqrt(sum_d2 / count_);
  scale_r_ = std::sqrt(sum_r2 / count_);
  if (!(scale_s_ > 1e-12 * (1 + std::abs(mean_s_))) || !(scale_r_ > 0) ||
      !std::isfinite(scale_s_ * scale_r_)) {
    not_ready_ = "the surrogate did not move";
    return;
  }
  if (!observed_) {
    not_ready_ = "no surrogate reading observed (observe())";
    return;
  }
  {
    const double low = previous_observed_ ? std::min(window_min_, previous_min_) : window_min_;
    const double high = previous_observed_ ? std::max(window_max_, previous_max_) : window_max_;
    if (!(fit_max_s_ - fit_min_s_ >= kMinCoverage * (high - low))) {
      not_ready_ =
          "the pairs cover too little of the surrogate's range (X-rays at the same phases of each breath)";
      return;
    }
    // Distinct levels: X-rays at two phases of every breath read two levels (inhale and exhale at
    // the same height), which a line through them fits exactly and wrongly where the relation
    // loops or bends. Counted greedily over the sorted amplitudes, a level kLevelSpacing of the
    // range above the last; insertion sort of at most kCapacity values, in place of a copy.
    std::array<double, kCapacity> sorted{};
    for (int i = 0; i < count_; ++i) {
      double v = surrogate_[std::size_t(i)].amplitude;
      int j = i;
      for (; j > 0 && sorted[std::size_t(j - 1)] > v; --j)
        sorted[std::size_t(j)] = sorted[std::size_t(j - 1)];
      sorted[std::size_t(j)] = v;
    }
    int levels = 1;
    double last = sorted[0];
    for (int i = 1; i < count_; ++i)
      if (sorted[std::size_t(i)] - last >= kLevelSpacing * (high - low)) {
        ++levels;
        last = sorted[std::size_t(i)];
      }
    if (levels < amplitude_terms_of(spec_) + 1) {
      not_ready_ =
          "the pairs hold too few levels of the surrogate (X-rays at the same phases of each breath)";
      return;
    }
  }
  Eigen::Matrix<double, kTerms, kTerms> normal = Eigen::Matrix<double, kTerms, kTerms>::Zero();
  Eigen::Matrix<double, kTerms, 3> rhs = Eigen::Matrix<double, kTerms, 3>::Zero();
  for (int i = 0; i < count_; ++i) {
    const auto b = basis(surrogate_[std::size_t(i)]);
    normal += b * b.transpose();
    rhs += b * target_[std::size_t(i)].transpose();
  }
  // The terms the spec leaves out (their basis is 0) solve to zero.
  for (int k = 0; k < kTerms; ++k)
    if (normal(k, k) == 0) normal(k, k) = count_;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, kTerms, kTerms>> eigen(normal,
                                                                                   Eigen::EigenvaluesOnly);
  if (eigen.info() != Eigen::Success || !(eigen.eigenvalues()(0) >= kMinEigenvaluePerPair * count_)) {
    not_ready_ = "the pairs do not tell the model's terms apart (one phase of the breath)";
    return;
  }
  coefficients_ = normal.ldlt().solve(rhs).transpose();
  Eigen::Vector3d sum_e2 = Eigen::Vector3d::Zero();
  for (int i = 0; i < count_; ++i) {
    const Eigen::Vector3d e = coefficients_ * basis(surrogate_[std::size_t(i)]) - target_[std::size_t(i)];
    sum_e2 += e.cwiseProduct(e);
  }
  fit_rms_mm_ = (sum_e2 / count_).cwiseSqrt();
  if (!coefficients_.allFinite() || !fit_rms_mm_.allFinite()) {
    not_ready_ = "the fit is not finite";
    return;
  }
  ready_ = true;
  not_ready_ = "";
}

int model_window_at(const CorrelationModelSpec& spec, double xray_hz) {
  const double span_pairs = std::ceil(1.25 * spec.min_span_s * xray_hz) + 1;
  return int(std::clamp(std::max(double(spec.window), span_pairs), 4.0, double(CorrelationModel::kCapacity)));
}

double rate_window_at(double sample_rate_hz) {
  return std::max(2.5 / sample_rate_hz, std::min(0.1, 30.0 / sample_rate_hz));
}

}  // namespace lftrack::loop

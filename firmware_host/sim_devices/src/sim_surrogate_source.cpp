#include "lftrack/sim_devices/sim_surrogate_source.hpp"

#include <cmath>
#include <numbers>

namespace lftrack::sim_devices {

using session::SimSurrogateFaults;

SimSurrogateSource::SimSurrogateSource(const sim_spec::BreathingSurrogateSpec& spec,
                                       const sim::SimulatedRoom* room, const SimSurrogateFaults& faults)
    : chest_(spec), room_(room), faults_(faults) {}

double SimSurrogateSource::reading_at(double t_s) {
  double s = chest_.sample(t_s);
  const SimSurrogateFaults& f = faults_;
  if (f.cough_at_s >= 0 && t_s >= f.cough_at_s && t_s < f.cough_at_s + f.cough_s) {
    const double bump = std::sin(std::numbers::pi * (t_s - f.cough_at_s) / f.cough_s);
    s += f.cough_mm * bump * bump;
  }
  if (f.slide_from_s >= 0 && t_s > f.slide_from_s) s += f.slide_mm_per_s * (t_s - f.slide_from_s);
  if (f.freeze_from_s >= 0 && t_s >= f.freeze_from_s) {
    if (!have_frozen_) {
      frozen_ = s;
      have_frozen_ = true;
    }
    return frozen_;
  }
  return s;
}

int SimSurrogateSource::read(std::int64_t now_ns, drivers::SurrogateReading* out, int capacity) {
  const std::int64_t epoch = room_->epoch_ns();
  if (epoch < 0 || now_ns < epoch || capacity <= 0) return 0;
  const double rate = chest_.spec().sample_rate_hz;
  const auto at_ns = [&](std::int64_t k) { return epoch + std::int64_t(std::floor(double(k) * 1e9 / rate)); };
  // Readings older than the capacity's newest are skipped (their noise drawn all the same, so the
  // stream does not depend on how often the loop asks).
  int n = 0;
  for (; at_ns(next_) <= now_ns; ++next_) {
    const double t_s = double(next_) / rate;
    const double value = reading_at(t_s);
    if (stopped_at(t_s)) continue;
    if (n == capacity) {
      for (int i = 1; i < capacity; ++i) out[i - 1] = out[i];
      --n;
    }
    out[n++] = drivers::SurrogateReading{at_ns(next_), value};
  }
  return n;
}

}  // namespace lftrack::sim_devices

// The run's target residual per axis and its command latency, from journal records.

#include "lftrack/loop/tracking_accuracy.hpp"

#include "lftrack/loop/latency_chain.hpp"

#include <cmath>

#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/tracking/pose.hpp"

namespace lftrack::loop {

void TrackingAccuracy::add(const JournalRecord& r) {
  if (r.command_sent != 0 && r.command_acked_ns > 0) {
    const std::int64_t exposed = exposure_ns(r);
    if (exposed > 0 && r.command_acked_ns >= exposed) latency_ms_.add(1e-6 * double(r.command_acked_ns - exposed));
  }
  if (!per_axis_ || !(r.true_residual_mm >= 0) || static_cast<TrackingState>(r.state) != TrackingState::kTrack)
    return;
  for (double v : r.true_target_residual)
    if (!std::isfinite(v)) return;
  ++n_;
  for (std::size_t i = 0; i < 6; ++i) {
    const double x = r.true_target_residual[i];
    const double d = x - mean_[i];
    mean_[i] += d / double(n_);
    m2_[i] += d * (x - mean_[i]);
  }
  const double e = std::sqrt(r.true_target_residual[0] * r.true_target_residual[0] +
                             r.true_target_residual[1] * r.true_target_residual[1] +
                             r.true_target_residual[2] * r.true_target_residual[2]);
  error_3d_mm_.add(e);
  if (e > 1.0) ++over_1mm_;
  if (e > 2.0) ++over_2mm_;
  if (r.beam_permit != 0) {
    ++beam_on_;
    if (e > 1.0) ++beam_on_over_1mm_;
    if (e > 2.0) ++beam_on_over_2mm_;
  }
}

std::optional<TargetResidualReport> TrackingAccuracy::target_residual() const {
  if (n_ == 0) return std::nullopt;
  TargetResidualReport out;
  out.cycles = n_;
  auto sd = [&](std::size_t i) { return n_ > 1 ? std::sqrt(m2_[i] / double(n_ - 1)) : 0.0; };
  for (std::size_t a = 0; a < 3; ++a) {
    out.translation_mean_mm[a] = mean_[a];
    out.translation_sd_mm[a] = sd(a);
    out.rotation_mean_deg[a] = tracking::rad_to_deg(mean_[3 + a]);
    out.rotation_sd_deg[a] = tracking::rad_to_deg(sd(3 + a));
  }
  out.error_3d_mean_mm = error_3d_mm_.mean();
  out.error_3d_p95_mm = error_3d_mm_.quantile(0.95);
  out.error_3d_max_mm = error_3d_mm_.max();
  out.share_over_1mm = double(over_1mm_) / double(n_);
  out.share_over_2mm = double(over_2mm_) / double(n_);
  out.beam_on_cycles = beam_on_;
  if (beam_on_ > 0) {
    out.beam_on_share_over_1mm = double(beam_on_over_1mm_) / double(beam_on_);
    out.beam_on_share_over_2mm = double(beam_on_over_2mm_) / double(beam_on_);
  }
  return out;
}

std::optional<CommandLatencyReport> TrackingAccuracy::latency() const {
  if (latency_ms_.count() == 0) return std::nullopt;
  return CommandLatencyReport{std::int64_t(latency_ms_.count()), latency_ms_.quantile(0.5), latency_ms_.quantile(0.95),
                              latency_ms_.quantile(0.99), latency_ms_.max()};
}

}  // namespace lftrack::loop

// The summary of a run: statistics gathered over the cycles.

#include "lftrack/tracking/pose.hpp"
#include "loop_impl.hpp"

namespace lftrack::loop {

void TrackingLoop::Impl::finish_summary(std::int64_t aligned_at, std::uint64_t allocations_at_warmup,
                                        std::uint64_t allocations_at_end) {
  LoopSummary& s = summary;
  if (residual_mm.count() > 0) {
    s.residual_mean_mm = residual_mm.mean();
    s.residual_p95_mm = residual_mm.quantile(0.95);
    s.residual_max_mm = residual_mm.max();
  }
  s.target_residual = accuracy.target_residual();
  s.command_latency = accuracy.latency();
  s.latency_chain = latency_chain.report();
  s.simulated_clock = settings.simulated_clock;
  s.view_check_every =
      parts.view_agreement == nullptr ? -1 : (settings.judge_tracking ? settings.view_check_every : 0);
  s.cycle_p50_ms = cycle_ms.quantile(0.5);
  s.cycle_p95_ms = cycle_ms.quantile(0.95);
  s.cycle_p99_ms = cycle_ms.quantile(0.99);
  s.cycle_max_ms = cycle_ms.max();
  s.registration_p50_ms = registration_ms.quantile(0.5);
  s.registration_p95_ms = registration_ms.quantile(0.95);
  s.registration_max_ms = registration_ms.max();
  s.acquire_p95_ms = acquire_ms.quantile(0.95);
  s.acquire_max_ms = acquire_ms.max();
  s.readback_p50_ms = readback_ms.quantile(0.5);
  s.readback_p99_ms = readback_ms.quantile(0.99);
  s.preprocess_p95_ms = preprocess_ms.quantile(0.95);
  s.preprocess_max_ms = preprocess_ms.max();
  s.verdict_checks = verdict_check_ms.count();
  s.verdict_check_p50_ms = verdict_check_ms.quantile(0.5);
  s.verdict_check_p95_ms = verdict_check_ms.quantile(0.95);
  s.verdict_check_max_ms = verdict_check_ms.max();
  s.view_checks = view_check_ms.count();
  s.view_checks_refused = view_checks_refused;
  s.view_checks_out_of_time = view_checks_out_of_time;
  s.view_check_p50_ms = view_check_ms.quantile(0.5);
  s.view_check_max_ms = view_check_ms.max();
  s.imaging = settings.loop.imaging.model_mode() ? "model" : "every_cycle";
  if (settings.loop.imaging.model_mode()) s.model_not_ready = model.not_ready_reason();
  s.model_check_p50_mm = model_check_mm.quantile(0.5);
  s.model_check_p95_mm = model_check_mm.quantile(0.95);
  const double minutes = double(s.cycles + s.skipped_periods) * double(period_ns) / 60e9;
  s.pairs_per_minute = minutes > 0 ? double(s.xray_pairs) / minutes : 0;
  s.dose_per_pair_mGy = settings.loop.imaging.dose_per_pair_mGy;
  s.dose_mGy_per_minute = s.pairs_per_minute * s.dose_per_pair_mGy;
  s.evaluations_mean =
      registration_ms.count() > 0 ? evaluations_sum / double(registration_ms.count()) : 0;
  if (parts.allocation_count != nullptr && aligned_at >= 0) {
    const std::int64_t counted = s.cycles - (aligned_at + settings.warmup_cycles);
    if (counted > 0) {
      s.allocation_cycles = counted;
      s.allocations_per_cycle = double(allocations_at_end - allocations_at_warmup) / double(counted);
    }
  }
}

}  // namespace lftrack::loop

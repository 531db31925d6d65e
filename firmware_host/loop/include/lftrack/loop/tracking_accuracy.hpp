#pragma once
// How well a run kept the target in place, as a clinic reports it, and how long its corrections
// took to reach the actuator: gathered from journal records, so the loop's summary and `lftrack
// journal export` of the same journal report the same figures.
//
// Target residual (simulation only: records with true_residual_mm >= 0 and, from journal format
// 4 on, true_target_residual): the true offset of the target (the registration origin) after
// correction, per room axis, over the cycles that end in TRACK: mean and standard deviation of
// each translation (mm) and rotation (degrees at the edges), and the share of those cycles whose
// 3D target error exceeds 1 mm and 2 mm; the shares again over the TRACK cycles with the beam on
// (the cycles that treat: the set-up move's cycles, whose error is the set-up error, are not).
//
// Latency: from the older frame's exposure to the actuator's acknowledgement of the command the
// cycle sent (records with command_sent and command_acked_ns), p50/p95/p99/max in ms. On the
// real clock the acknowledgement is when the actuator's command() returned (a Modbus reply, the
// robot's CAN answer); on the simulated clock it is the command's deadline, the time the
// simulated room takes it to be sent.
//
// add() allocates nothing (fixed histograms), so the loop may call it every cycle.

#include <array>
#include <cstdint>
#include <optional>

#include "lftrack/loop/histogram.hpp"
#include "lftrack/loop/journal.hpp"

namespace lftrack::loop {

struct TargetResidualReport {
  std::int64_t cycles = 0;                   // TRACK cycles with a truth
  std::array<double, 3> translation_mean_mm{}, translation_sd_mm{};  // room x, y, z
  std::array<double, 3> rotation_mean_deg{}, rotation_sd_deg{};      // about room x, y, z
  double error_3d_mean_mm = 0, error_3d_p95_mm = 0, error_3d_max_mm = 0;
  double share_over_1mm = 0, share_over_2mm = 0;  // of those cycles, 0..1
  std::int64_t beam_on_cycles = 0;                 // of those, the beam on
  double beam_on_share_over_1mm = 0, beam_on_share_over_2mm = 0;
};

struct CommandLatencyReport {
  std::int64_t commands = 0;  // acknowledged commands
  double p50_ms = 0, p95_ms = 0, p99_ms = 0, max_ms = 0;
};

class TrackingAccuracy {
 public:
  // `records_have_target_residual`: false for journals before format 4, whose records carry
  // only the scalar true_residual_mm (their target residual is not reported).
  explicit TrackingAccuracy(bool records_have_target_residual = true)
      : per_axis_(records_have_target_residual) {}

  void add(const JournalRecord& r);

  std::optional<TargetResidualReport> target_residual() const;  // none: no TRACK cycle with a truth
  std::optional<CommandLatencyReport> latency() const;          // none: no acknowledged command

 private:
  bool per_axis_;
  std::int64_t n_ = 0;
  std::array<double, 6> mean_{}, m2_{};  // Welford, mm and rad
  std::int64_t over_1mm_ = 0, over_2mm_ = 0;
  std::int64_t beam_on_ = 0, beam_on_over_1mm_ = 0, beam_on_over_2mm_ = 0;
  Histogram error_3d_mm_{0.001, 100};
  Histogram latency_ms_{0.01, 2000};
};

// Their JSON forms: lftrack/records/loop_json.hpp.

}  // namespace lftrack::loop

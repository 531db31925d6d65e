#pragma once
// The latency chain of a cycle's correction, link by link, from the X-ray exposure to the
// actuator's acknowledgement, as a clinic measures it first (issue 56). Every link is timestamped
// on the loop's clock (CLOCK_MONOTONIC on the real clock) and journaled (format 5 on):
//
//   exposure        the older frame's exposure (JournalRecord::frame_time_ns, the detector's
//                   timestamp as its driver maps it onto the host's clock)
//   arrived         the pair complete on the host (the frame source returned it to the loop)
//   preprocessed    both frames to line integrals in their ROIs
//   registered      the registration and its verdict done
//   gated           the control law and the safety gate decided
//   written         the command handed to the actuator's driver (its command() called)
//   acknowledged    the driver's command() returned (a Modbus reply, the robot's CAN answer):
//                   the write on the wire is in this link, not in "write", which is the
//                   hand-over from the gate to the driver
//
// A link is the time between two neighbours; the links add up to exposure-to-acknowledgement.
// Only the real clock has a chain: on the simulated clock the cycle's work takes no time (the
// links are zero in the journal).

#include <array>
#include <cstdint>
#include <optional>

#include "lftrack/loop/histogram.hpp"
#include "lftrack/loop/journal.hpp"

namespace lftrack::loop {

enum class LatencyLink : int { kArrive, kPreprocess, kRegister, kGate, kWrite, kAcknowledge };
constexpr int kLatencyLinks = 6;
// "exposure to arrival", "preprocess", "register", "gate", "write", "acknowledge".
const char* to_string(LatencyLink link);
// A short key for tables and JSON: "arrive", "preprocess", ..., "acknowledge".
const char* key_of(LatencyLink link);
// The links' sum: exposure to acknowledgement.
double total_ms(const std::array<double, kLatencyLinks>& links_ms);

// The exposure a record's latency is counted from: the older of its frames' (one detector: its
// frame's; the journal keeps the first two detectors' times, so with three or four the older of
// those two). 0: none.
std::int64_t exposure_ns(const JournalRecord& r);

// Why a record has no chain.
enum class NoChain : int {
  kNoCommand,    // it sent no command
  kNotTimed,     // a timestamp is 0: the simulated clock, a journal before format 5, a link not reached
  kOutOfOrder,   // a link runs backwards: never on one monotonic clock, so damage
  kImplausible,  // a link longer than kMaxLinkMs: no cycle takes a minute, so damage
};
constexpr double kMaxLinkMs = 60'000;
const char* to_string(NoChain why);

// The links of the command `r` sent, in ms; none (and, where `why` is given, the reason) where
// the record has no whole, ordered, plausible chain.
std::optional<std::array<double, kLatencyLinks>> latency_links_ms(const JournalRecord& r,
                                                                  NoChain* why = nullptr);

struct LinkLatency {
  double p50_ms = 0, p95_ms = 0, p99_ms = 0, max_ms = 0;
};
struct LatencyChainReport {
  std::int64_t commands = 0;  // commands with a whole chain
  std::array<LinkLatency, kLatencyLinks> links{};
  LinkLatency total;  // exposure to acknowledgement over the same commands
};

// Gathers the chains of records; add() allocates nothing (fixed histograms, 0.01 ms bins to
// 250 ms, longer ones in the last bin with the maximum kept exactly).
class LatencyChain {
 public:
  void add(const JournalRecord& r);
  std::optional<LatencyChainReport> report() const;  // none: no command with a whole chain

 private:
  std::array<Histogram, kLatencyLinks> links_{Histogram{0.01, 250}, Histogram{0.01, 250},
                                              Histogram{0.01, 250}, Histogram{0.01, 250},
                                              Histogram{0.01, 250}, Histogram{0.01, 250}};
  Histogram total_{0.01, 250};
};

}  // namespace lftrack::loop

#pragma once
// The chaos soak (`lftrack sim --chaos SEED`, issue 23): the closed loop on the simulated clock
// with faults from the whole catalogue injected at random moments, and the safety invariants
// checked every cycle (chaos_invariants.hpp).
//
// The run is cut into segments, each a treatment session of its own: a fresh LoopSession with
// its own journal, patient (the scene's motion plus random sudden shifts) and actuator kind
// (every third segment drives the couch through the real Modbus driver against the virtual
// couch server, with the server's faults; every third, from the second on, the virtual robot
// through the real CAN driver, with the CAN controller's and robot's faults; the others the
// in-process virtual couch, and every other one of those, from the fourth segment on, images on
// demand: the patient breathes 6 mm, X-ray pairs come at 1 Hz and the simulated chest marker's
// correlation model corrects in between, with the surrogate's faults). A segment
// ends at its cycle count, or early where the catalogue's safe state is final: an exception out
// of a device (the loop holds the actuator, drops the beam and rethrows), a full disk (the loop
// holds for good), an operator's reset of a FAULT (the loop goes IDLE and waits for a start).
// Everything random is drawn from the seed, so a run's faults are reproducible; the states they
// lead to are not bit-for-bit (the Modbus driver's time-outs, the CAN heartbeats and the injected
// disk and stall faults are timed on the real clock).
//
// Faults, per cycle with probability `fault_rate` (a kind drawn uniformly from those that fit
// the segment): frames lost, late, stale, skewed, blank, saturated, torn, from a disconnected or
// faulty detector, or throwing; read-backs that time out, disconnect, report a fault, disagree
// with the command, carry NaN or throw; commands that time out, disconnect, fail or throw; the
// Modbus server's no reply, exception 4 and dropped connection; CAN bus-off, error-passive, error
// frame floods, a robot restart and a lost heartbeat; host stalls (overruns, runs of
// one to four); a full disk under the journal; sudden patient shifts; a breathing surrogate that
// stops, freezes, spikes, reads NaN or coughs (model segments); and an operator who answers
// each HOLD or FAULT after a random delay (sometimes too soon, sometimes naming another HOLD) and
// sends stale resumes while tracking. A full disk is each segment's own journal sink
// (JournalOptions::sink), so soaks in one process do not share it.

#include <array>
#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::chaos {

enum class ChaosFault : std::uint8_t {
  kFrameLost,             // the pair never arrives (timeout)
  kFrameLate,             // it arrives after the cycle's deadline (timeout), then is gone
  kFrameStale,            // a pair whose timestamps are a second old (an earlier exposure)
  kFrameSkewed,           // view B's timestamp 50 ms off view A's
  kFrameBlank,            // both frames read zero counts (generator off)
  kFrameSaturated,        // view A at full scale (a detector overexposed)
  kFrameTorn,             // view A's lower half zero (a torn transfer)
  kFrameDisconnected,     // the detector is gone
  kFrameDeviceFault,      // the detector reports a fault
  kFrameThrows,           // acquire() throws
  kReadbackTimeout,       // the actuator does not answer
  kReadbackDisconnected,  // the actuator is gone
  kReadbackFaultFlag,     // it answers and reports a fault
  kReadbackMismatch,      // it answers a position and target 1-5 mm from the truth
  kReadbackNonFinite,     // it answers NaN
  kReadbackThrows,        // readback() throws
  kCommandTimeout,        // a command unanswered (the couch may or may not have taken it)
  kCommandDisconnected,   // the actuator is gone at the command
  kCommandFault,          // the actuator refuses the command with a fault
  kCommandThrows,         // command() throws
  kModbusNoReply,         // the served couch does not reply to the next request (Modbus segments)
  kModbusException4,      // it answers exception 4, device failure
  kModbusDropConnection,  // it closes the TCP connection
  kCanBusOff,             // the robot's CAN controller goes bus-off (restarted 5 cycles later; CAN segments)
  kCanErrorPassive,       // it goes error-passive (error-active again 5 cycles later)
  kCanErrorFlood,         // a flood of bus-error frames
  kCanRobotRestart,       // the robot restarts (boot-up heartbeat, motion disabled)
  kCanHeartbeatLoss,      // the robot's heartbeat stops (and resumes 20 cycles later)
  kHostStall,             // the cycle overruns its period (one to four cycles in a row)
  kDiskFull,              // the journal's write() fails with ENOSPC from now on
  kPatientShift,          // a sudden shift of the patient, 1 to 8 mm (drawn into the motion)
  kSurrogateStop,         // the breathing surrogate's stream stops for 3 to 15 cycles (model segments)
  kSurrogateFreeze,       // its marker repeats its last reading for 8 to 20 cycles
  kSurrogateSpike,        // one reading jumps by three times surrogate.jump_mm
  kSurrogateNonFinite,    // one reading is NaN
  kSurrogateCough,        // the marker rises 8 mm over 6 cycles, the target does not follow
  kCount
};
inline constexpr std::size_t kChaosFaultKinds = static_cast<std::size_t>(ChaosFault::kCount);
const char* to_string(ChaosFault fault);

struct ChaosOptions {
  std::uint64_t seed = 1;
  std::int64_t cycles = 20000;         // simulated cycles in all, over every segment; 0: until interrupted
  std::int64_t segment_cycles = 2000;  // the longest segment (a treatment session), cycles
  double fault_rate = 0.03;            // per cycle: the chance that a fault is injected
  bool hil_segments = true;            // every third segment over Modbus, every third over CAN (else none)
  // The soak's journals go to a folder of its own in here, chaos-SEED-N (the first N free), one
  // segment-NNNNNN.lfj each (required).
  std::filesystem::path journal_dir;
  std::filesystem::path light_field_dir;
  // After each segment: cycles done so far, of options.cycles.
  std::function<void(std::int64_t done, std::int64_t total)> progress;
  // Set (from a signal handler or another thread) to end the soak after the current cycle; the
  // report then says it was interrupted.
  const std::atomic<bool>* interrupt = nullptr;
};
// Finite values in range, a journal folder that can be written: checked before anything runs.
Status check_chaos_options(const ChaosOptions& options);

struct ChaosViolation {
  std::int64_t segment = 0;
  std::int64_t cycle = 0;
  std::string what;
};

struct ChaosReport {
  std::uint64_t seed = 0;
  std::int64_t cycles = 0;          // cycles run (a cycle that threw into the loop included)
  std::int64_t cycles_checked = 0;  // cycles whose record the invariants were checked on
  bool interrupted = false;
  std::filesystem::path journal_dir;  // this soak's folder of journals
  std::int64_t segments = 0;          // of which over Modbus and over CAN, and imaging on demand:
  std::int64_t modbus_segments = 0, can_segments = 0, model_segments = 0;
  std::int64_t surrogate_fault_cycles = 0;  // cycles whose record says the surrogate failed (model segments)
  std::array<std::int64_t, kChaosFaultKinds> injected{};           // faults that met the loop, per kind
  std::array<std::int64_t, 5> states{};                            // cycles ending in each TrackingState
  std::int64_t commands = 0, holds = 0, faults = 0, overruns = 0;  // holds, faults: entries into them
  std::int64_t resumes_accepted = 0, resets_accepted = 0, operator_refused = 0;
  std::int64_t journal_records = 0;  // read back from the segments' journals and checked
  std::int64_t violation_count = 0;
  std::vector<ChaosViolation> violations;  // the first 100
  double wall_s = 0;
};
nlohmann::json to_json(const ChaosReport& report);

// Runs the soak on `scene` (a scene with simulated detectors and a virtual couch). Fails only on
// what stops it from running (a session that cannot be created); invariant violations are the
// report's, not an error.
Result<ChaosReport> run_chaos_soak(const session::PreparedScene& scene, const ChaosOptions& options,
                                   tracking::ThreadPool* pool);

}  // namespace lftrack::chaos

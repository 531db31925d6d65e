#include "lftrack/chaos/chaos_soak.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <memory>
#include <random>
#include <system_error>

#include "chaos_devices.hpp"
#include "lftrack/records/journal_reader.hpp"
#include "lftrack/session/loop_session.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"

namespace lftrack::chaos {

using records::read_journal;
using session::ActuatorSpec;
using session::HilProtocol;
using session::LoopSession;
using session::LoopSessionOptions;
using session::PreparedScene;

namespace {

constexpr std::size_t kViolationsKept = 100;
constexpr std::int64_t kCyclesAfterDiskFull =
    30;  // after the writer failed: the segment's safe state is final
constexpr std::int64_t kCyclesToHoldOnCan =
    50;  // and kWallToHoldOnCan: heartbeats time out on the real clock
constexpr std::chrono::seconds kWallToHoldOnCan{3};
constexpr std::chrono::seconds kWriterMustFailWithin{10};  // a full disk the journal writer never meets

void add_violation(ChaosReport* report, std::int64_t segment, std::int64_t cycle, std::string what) {
  ++report->violation_count;
  if (report->violations.size() < kViolationsKept)
    report->violations.push_back({segment, cycle, std::move(what)});
}

// Watches one segment's cycles: the invariants, the tallies, a CAN fault's HOLD, the end of a
// segment whose disk is full, and the operator's interrupt.
class SegmentObserver final : public loop::CycleObserver {
 public:
  SegmentObserver(const PreparedScene& scene, chaos::Injector* injector, ChaosReport* report,
                  std::int64_t segment, const std::atomic<bool>* interrupt)
      : checker_(scene.scene.safety, 1e-3 * scene.scene.loop.period_ms),
        injector_(injector),
        report_(report),
        segment_(segment),
        interrupt_(interrupt) {}
  void set_session(LoopSession* session) { session_ = session; }
  std::int64_t cycles_seen() const { return cycles_; }

  std::int64_t simulated_stall_ns(std::int64_t cycle) override {
    (void)cycle;
    return injector_->injection.stalled ? injector_->stall_ns() : 0;
  }

  void on_cycle(const JournalRecord& r) override {
    violations_.clear();
    checker_.check(r, injector_->calls, injector_->injection, injector_->action, &violations_);
    for (std::string& v : violations_) add_violation(report_, segment_, std::int64_t(r.cycle), std::move(v));
    ++cycles_;
    tally(r);
    check_can_fault(r);
    check_full_disk(r);
    if (interrupt_ != nullptr && interrupt_->load(std::memory_order_relaxed)) stop();
  }

 private:
  void tally(const JournalRecord& r) {
    if (r.state < report_->states.size()) ++report_->states[r.state];
    report_->commands += r.command_sent;
    if (r.state != r.previous_state && r.state == std::uint8_t(TrackingState::kHold)) ++report_->holds;
    if (r.state != r.previous_state && r.state == std::uint8_t(TrackingState::kFault)) ++report_->faults;
    report_->overruns += r.overrun;
    if (r.surrogate_fault != 0) ++report_->surrogate_fault_cycles;
    report_->operator_refused += r.operator_refused;
    if (r.operator_command == 1 + int(OperatorCommand::kResume)) ++report_->resumes_accepted;
    if (r.operator_command == 1 + int(OperatorCommand::kReset)) ++report_->resets_accepted;
  }

  // A CAN fault reaches the loop through the driver (a read-back or command that fails, a
  // heartbeat that times out on the real clock; each lasts at least half a second of wall
  // time): a HOLD or FAULT for an actuator fault within 50 cycles and 3 s.
  void check_can_fault(const JournalRecord& r) {
    const auto& pending = injector_->can_fault_pending();
    if (!pending) return;
    const bool held =
        r.state == std::uint8_t(TrackingState::kHold) || r.state == std::uint8_t(TrackingState::kFault);
    const bool actuator_reason = r.gate_reason == std::uint8_t(GateReason::kActuatorFault) ||
                                 r.gate_reason == std::uint8_t(GateReason::kCommandRefused);
    if (held && actuator_reason) {
      injector_->clear_can_fault();
    } else if (std::int64_t(r.cycle) - pending->cycle > kCyclesToHoldOnCan &&
               std::chrono::steady_clock::now() - pending->wall > kWallToHoldOnCan) {
      add_violation(report_, segment_, std::int64_t(r.cycle),
                    std::string("no HOLD for an actuator fault after ") + to_string(pending->fault));
      injector_->clear_can_fault();
    }
  }

  // A full disk: the journal writer fails at its next write. From the cycle after the session
  // reports that failure, nothing may be sent and the beam must stay off (whatever reason the
  // gate gives first: an actuator fault stands before "journal write failed"). Then the
  // segment's safe state is final and it ends.
  void check_full_disk(const JournalRecord& r) {
    if (!injector_->disk_full_injected() || session_ == nullptr) return;
    if (writer_failed_) {
      if (r.command_sent != 0 || r.beam_permit != 0)
        add_violation(report_, segment_, std::int64_t(r.cycle),
                      std::string(r.command_sent != 0 ? "sent a command" : "armed the beam") +
                          " after the journal writer failed on a full disk");
      if (++cycles_after_writer_failed_ >= kCyclesAfterDiskFull) stop();
    } else if (session_->journal_failed()) {
      writer_failed_ = true;
    } else if (std::chrono::steady_clock::now() - injector_->disk_full_wall() > kWriterMustFailWithin) {
      add_violation(report_, segment_, std::int64_t(r.cycle), "the journal writer never met the full disk");
      stop();
    }
  }

  void stop() {
    injector_->end_draws();
    if (session_ != nullptr) session_->request_stop();
  }

  InvariantChecker checker_;
  chaos::Injector* injector_;
  ChaosReport* report_;
  std::int64_t segment_;
  const std::atomic<bool>* interrupt_;
  LoopSession* session_ = nullptr;
  std::vector<std::string> violations_;
  std::int64_t cycles_ = 0;
  bool writer_failed_ = false;
  std::int64_t cycles_after_writer_failed_ = 0;
};

// The scene must be one the soak can drive: a couch or robot (its simulated twin moves the
// patient, and the Modbus and CAN segments need one) on the room's own axes (a calibrated couch
// would put the wrapper's commands in another frame than the journal's).
Status check_chaos_scene(const PreparedScene& p) {
  const ActuatorSpec& a = p.scene.actuator;
  if (a.type == "none")
    return invalid_argument(
        "chaos: the scene has no actuator (actuator.type none); the soak needs a couch or robot");
  if (a.mounting || a.calibration)
    return invalid_argument(
        "chaos: the scene's couch has a mounting or calibration; the soak checks commands in the "
        "room's axes and needs a couch on them");
  return {};
}

// A folder of this soak's own under `parent`: chaos-SEED-1, or the next number free (a second
// soak over the first one's folder never mixes with it).
Result<std::filesystem::path> claim_run_folder(const std::filesystem::path& parent, std::uint64_t seed) {
  std::error_code ec;
  std::filesystem::create_directories(parent, ec);
  if (ec) return io_error("chaos: cannot create " + parent.string() + ": " + ec.message());
  for (int k = 1; k < 10000; ++k) {
    const std::filesystem::path run = parent / ("chaos-" + std::to_string(seed) + "-" + std::to_string(k));
    if (std::filesystem::create_directory(run, ec)) return run;
    if (ec) return io_error("chaos: cannot create " + run.string() + ": " + ec.message());
  }
  return io_error("chaos: 9999 soaks of seed " + std::to_string(seed) + " in " + parent.string() +
                  " already");
}

// A segment that images on demand: X-ray pairs at 1 Hz and the correlation model between them,
// following the simulated chest marker, with the scene's breathing (6 mm if it has less).
void image_on_demand(session::Scene* scene, std::uint64_t seed) {
  sim_spec::PatientMotionSpec& motion = scene->motion.motion;
  if (motion.breathing_amplitude.head<3>().norm() < 6)
    motion.breathing_amplitude.head<3>() = Eigen::Vector3d(0.5, 1.5, 6);
  loop::ImagingSpec& imaging = scene->loop.imaging;
  imaging.mode = loop::ImagingSpec::Mode::kModel;
  imaging.xray_hz = 1;
  imaging.model.min_span_s = std::max(1.0, motion.breathing_period_s);
  scene->surrogate.source = "sim";
  sim_spec::BreathingSurrogateSpec& marker = scene->surrogate.sim;
  marker.period_s = motion.breathing_period_s;
  marker.sample_rate_hz = imaging.surrogate.rate_hz;
  marker.seed = seed;
}

// Sudden shifts of the patient, drawn for a segment of `cycles`: at any cycle with the chance of
// one fault kind, 1 to 8 mm in a random direction, each undone by a later one (the patient moves
// back), so that the patient stays near the envelope over a long segment.
std::vector<sim_spec::MotionStep> draw_shifts(std::mt19937_64& random, std::int64_t cycles, double period_s,
                                              double fault_rate) {
  std::vector<sim_spec::MotionStep> shifts;
  std::uniform_real_distribution<double> unit(0, 1), signed_unit(-1, 1);
  const double chance = fault_rate / double(kChaosFaultKinds);
  Eigen::Vector3d displaced = Eigen::Vector3d::Zero();
  for (std::int64_t k = 1; k < cycles; ++k) {
    if (unit(random) >= chance) continue;
    sim_spec::MotionStep step;
    step.time_s = double(k) * period_s;
    if (displaced.isZero()) {
      Eigen::Vector3d d(signed_unit(random), signed_unit(random), signed_unit(random));
      if (d.norm() < 1e-6) d = Eigen::Vector3d::UnitX();
      displaced = d.normalized() * (1.0 + 7.0 * unit(random));
      step.delta.head<3>() = displaced;
    } else {
      step.delta.head<3>() = -displaced;
      displaced.setZero();
    }
    shifts.push_back(step);
  }
  return shifts;
}

// The segment's journal, read back: one valid record per cycle seen, in order, up to a full disk.
void check_journal(const std::filesystem::path& path, std::int64_t cycles_seen, bool disk_full,
                   std::int64_t segment, ChaosReport* report) {
  auto journal = read_journal(path);
  if (!journal.ok()) {
    add_violation(report, segment, -1, "journal unreadable: " + journal.status().message());
    return;
  }
  const std::vector<JournalRecord>& records = journal->records;
  report->journal_records += std::int64_t(records.size());
  if (journal->damaged()) add_violation(report, segment, -1, "journal damaged: " + path.string());
  if (!disk_full && std::int64_t(records.size()) != cycles_seen)
    add_violation(report, segment, -1,
                  "journal holds " + std::to_string(records.size()) + " records for " +
                      std::to_string(cycles_seen) + " cycles");
  if (disk_full && std::int64_t(records.size()) > cycles_seen)
    add_violation(report, segment, -1, "journal holds more records than cycles");
  for (std::size_t i = 1; i < records.size(); ++i) {
    if (records[i].cycle <= records[i - 1].cycle) {
      add_violation(report, segment, std::int64_t(records[i].cycle), "journal cycles out of order");
      break;
    }
  }
}

}  // namespace

Result<ChaosReport> run_chaos_soak(const session::PreparedScene& scene, const ChaosOptions& options,
                                   tracking::ThreadPool* pool) {
  LFTRACK_RETURN_IF_ERROR(check_chaos_options(options));
  LFTRACK_RETURN_IF_ERROR(check_chaos_scene(scene));
  auto run_folder = claim_run_folder(options.journal_dir, options.seed);
  if (!run_folder.ok()) return run_folder.status();
  const auto wall_start = std::chrono::steady_clock::now();
  const double period_s = 1e-3 * scene.scene.loop.period_ms;
  const std::int64_t period_ns = std::int64_t(std::llround(period_s * 1e9));
  ChaosReport report;
  report.seed = options.seed;
  report.journal_dir = *run_folder;
  std::int64_t done = 0;
  const auto interrupted = [&] { return options.interrupt != nullptr && options.interrupt->load(); };
  for (std::int64_t segment = 0; (options.cycles == 0 || done < options.cycles) && !interrupted();
       ++segment) {
    const std::int64_t cycles = options.cycles == 0 ? options.segment_cycles
                                                    : std::min(options.segment_cycles, options.cycles - done);
    const bool modbus = options.hil_segments && segment % 3 == 2;
    const bool can = options.hil_segments && segment % 3 == 1;
    const bool model = !modbus && !can && segment % 2 == 1;
    std::mt19937_64 segment_random(options.seed * 1'000'003 + std::uint64_t(segment));
    PreparedScene patient = scene;  // volumes are shared; only the motion differs
    std::vector<sim_spec::MotionStep>& shifts = patient.scene.motion.motion.shifts;
    const std::size_t scene_shifts = shifts.size();  // the scene's own, before the soak's
    for (const sim_spec::MotionStep& s : draw_shifts(segment_random, cycles, period_s, options.fault_rate))
      shifts.push_back(s);

    LoopSessionOptions so;
    so.simulator = sim_devices::room_simulator();
    so.cycles = cycles;
    so.simulated_clock = true;
    so.light_field_dir = options.light_field_dir;
    char name[32];
    std::snprintf(name, sizeof name, "segment-%06lld.lfj", static_cast<long long>(segment));
    so.journal = *run_folder / name;
    // The segment's own disk, which the injector may fill; the journal's writer keeps it.
    const auto journal_disk = std::make_shared<chaos::DiskThatFills>();
    so.journal_options.sink = journal_disk;
    so.hil = modbus ? HilProtocol::kModbus : can ? HilProtocol::kCan : HilProtocol::kNone;
    if (model) image_on_demand(&patient.scene, segment_random());
    // The invariants read the ROI windows, the gate and the journal, never the rest of a
    // detector: frames of the windows alone (the rest of the built-in detectors costs about
    // 4 ms a pair, 80 s of a 20,000-cycle soak).
    so.frames.detectors.whole_detector = false;

    // The wrappers are made when the session asks for them (it builds the devices they wrap);
    // everything here is declared before the session, so it outlives it.
    auto injector = std::make_unique<chaos::Injector>(segment_random(), options.fault_rate, period_s, cycles,
                                                      scene.scene.safety, journal_disk);
    auto operator_input = std::make_unique<chaos::ChaosOperator>(injector.get());
    auto observer =
        std::make_unique<SegmentObserver>(patient, injector.get(), &report, segment, options.interrupt);
    std::unique_ptr<chaos::ChaosFrameSource> frames;
    std::unique_ptr<chaos::ChaosActuator> actuator;
    std::unique_ptr<chaos::ChaosSurrogate> surrogate;
    so.hooks.wrap_frames = [&](drivers::FrameSource* inner) -> drivers::FrameSource* {
      frames = std::make_unique<chaos::ChaosFrameSource>(inner, injector.get(), period_ns);
      return frames.get();
    };
    so.hooks.wrap_actuator = [&](drivers::Actuator* inner) -> drivers::Actuator* {
      actuator = std::make_unique<chaos::ChaosActuator>(inner, injector.get());
      return actuator.get();
    };
    so.hooks.wrap_surrogate = [&](drivers::SurrogateSource* inner) -> drivers::SurrogateSource* {
      surrogate = std::make_unique<chaos::ChaosSurrogate>(inner, injector.get(),
                                                          patient.scene.loop.imaging.surrogate.jump);
      return surrogate.get();
    };
    if (model) {
      injector->set_surrogate_segment();
      ++report.model_segments;
    }
    so.hooks.operator_input = operator_input.get();
    so.hooks.observer = observer.get();
    auto session = LoopSession::create(patient, so, pool);
    if (!session.ok()) return session.status().with_context("chaos segment " + std::to_string(segment));
    if (modbus) {
      injector->set_modbus_server(sim_devices::modbus_couch_server(**session));
      ++report.modbus_segments;
    }
    if (can) {
      injector->set_can_robot(sim_devices::virtual_robot(**session));
      ++report.can_segments;
    }
    observer->set_session(session->get());
    const std::filesystem::path journal = (*session)->journal_path();
    bool threw = false;
    try {
      auto summary = (*session)->run();
      if (!summary.ok())
        add_violation(&report, segment, -1, "the loop failed: " + summary.status().message());
    } catch (const std::exception& e) {
      threw = true;
      if (!injector->threw)
        add_violation(&report, segment, observer->cycles_seen(), std::string("the loop threw: ") + e.what());
    }
    if (threw && !(injector->held_after_throw && injector->beam_dropped_after_throw))
      add_violation(&report, segment, observer->cycles_seen(),
                    "after an exception the actuator was not held or the beam not dropped");
    session->reset();  // closes the journal (drains it) before it is read
    for (std::size_t k = 0; k < kChaosFaultKinds; ++k) report.injected[k] += injector->injected[k];
    // The shifts alternate: one displaces the patient, the next brings them back.
    for (std::size_t i = scene_shifts; i < shifts.size(); i += 2)
      if (shifts[i].time_s < double(observer->cycles_seen()) * period_s)
        ++report.injected[std::size_t(ChaosFault::kPatientShift)];
    check_journal(journal, observer->cycles_seen(), injector->disk_full_injected(), segment, &report);
    // The cycle that threw ran too, up to the throw; it has no record.
    const std::int64_t cycles_run = observer->cycles_seen() + (threw ? 1 : 0);
    report.cycles += cycles_run;
    report.cycles_checked += observer->cycles_seen();
    ++report.segments;
    done += std::max<std::int64_t>(cycles_run, 1);
    if (options.progress) options.progress(done, options.cycles);
  }
  report.interrupted = interrupted();
  report.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  return report;
}

}  // namespace lftrack::chaos

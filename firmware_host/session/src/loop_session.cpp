#include "lftrack/session/loop_session.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/session/scene_default_plans.hpp"
#include "lftrack/session/scene_fingerprint.hpp"
#include "session_parts.hpp"

namespace lftrack::session {

using loop::ControlSocket;
using loop::CycleFeed;
using loop::FrameArchive;
using loop::FrameArchiveOptions;
using loop::JournalOptions;
using loop::JournalWriter;
using loop::judges_view_shift;
using loop::LoopGeometry;
using loop::LoopParts;
using loop::LoopSettings;
using loop::LoopSummary;
using loop::OperatorInput;
using loop::OperatorPoll;
using loop::OperatorView;
using loop::PlannedRegistration;
using loop::ScriptedOperator;
using loop::TerminalOperator;
using loop::TrackingLoop;

using watch::CycleHub;
using watch::HubOptions;
using watch::IgtlOptions;
using watch::IgtlServer;
using watch::MonitorServer;
using watch::PageOperator;
using watch::reachable_warning;

namespace {

// An operator input someone else owns (SessionHooks::operator_input) among the session's own.
class BorrowedOperator final : public OperatorInput {
 public:
  explicit BorrowedOperator(OperatorInput* input) : input_(input) {}
  void poll(const OperatorView& view, OperatorPoll* out) override { input_->poll(view, out); }
  void on_hold(const OperatorView& view, OperatorPoll* out) override { input_->on_hold(view, out); }
  bool unattended() const override { return input_->unattended(); }

 private:
  OperatorInput* input_;
};

// The monitor page and the OpenIGTLink server, when asked for, on a hub fed by the loop.
Status start_watchers(const PreparedScene& p, const LoopSessionOptions& o, LoopSession::Parts* parts) {
  if (!o.monitor && !o.igtl) return {};
  parts->feed = std::make_unique<CycleFeed>();
  HubOptions h;
  h.scene = p.scene.name;
  h.period_ms = p.scene.loop.period_ms;
  for (const DetectorSpec& d : p.scene.detectors) h.views.push_back(d.view);
  h.roi_windows = p.roi_windows;
  h.nominal_T_room_from_ct = p.nominal_T_room_from_ct;
  h.registration_origin_room_mm = p.registration_origin_room_mm();
  h.renderer = parts->registration_renderer;
  auto hub = CycleHub::start(parts->feed.get(), h);
  if (!hub.ok()) return hub.status();
  parts->hub = std::move(hub).value();
  if (o.monitor) {
    parts->page_operator = std::make_unique<PageOperator>();
    auto monitor = MonitorServer::start(parts->hub.get(), parts->page_operator.get(), *o.monitor);
    if (!monitor.ok()) return monitor.status();
    parts->monitor = std::move(monitor).value();
    if (const std::string w = reachable_warning(o.monitor->listen, "the monitor page", "watch the treatment");
        !w.empty())
      spdlog::warn("{}", w);
    parts->operators.add(std::make_unique<BorrowedOperator>(parts->page_operator.get()));
  }
  if (o.igtl) {
    IgtlOptions igtl_options = *o.igtl;
    igtl_options.simulated_clock = o.simulated_clock;
    auto igtl = IgtlServer::start(parts->hub.get(), igtl_options);
    if (!igtl.ok()) return igtl.status();
    parts->igtl = std::move(igtl).value();
    if (const std::string w =
            reachable_warning(o.igtl->listen, "the OpenIGTLink server", "read the registered pose");
        !w.empty())
      spdlog::warn("{}", w);
  }
  return {};
}

}  // namespace

LoopGeometry loop_geometry(const PreparedScene& p) {
  LoopGeometry g;
  for (const DetectorSpec& d : p.scene.detectors) g.views.push_back(d.view);
  g.roi_windows = p.roi_windows;
  g.nominal_T_room_from_ct = p.nominal_T_room_from_ct;
  g.registration_origin_room_mm = p.registration_origin_room_mm();
  return g;
}

Eigen::Isometry3d couch_mounting(const CouchMountingSpec& m, const PreparedScene& p) {
  Eigen::Isometry3d x = Eigen::Isometry3d::Identity();
  x.linear() = tracking::rotation_exp(m.rotation_rad);
  x.translation() = m.centre_room_mm.value_or(p.registration_origin_room_mm());
  return x;
}

namespace {

// The Modbus or CAN driver: the scene's (lftrack run), or the room's behind its protocol (HIL).
const drivers::Actuator* device_driver(const LoopSession::Parts& parts) {
  if (parts.room != nullptr && parts.room->protocol_driver() != nullptr) return parts.room->protocol_driver();
  return parts.actuator.get();
}

}  // namespace

LoopSession::LoopSession(std::unique_ptr<Parts> parts) : parts_(std::move(parts)) {}
LoopSession::~LoopSession() = default;

Result<std::unique_ptr<LoopSession>> LoopSession::create(const PreparedScene& p, const LoopSessionOptions& o,
                                                         tracking::ThreadPool* pool) {
  // Options first: a bad one is refused before minutes of light-field building, and before the
  // earlier archive is removed (--overwrite) or anything else is created.
  LFTRACK_RETURN_IF_ERROR(check_session_options(o));
  LFTRACK_RETURN_IF_ERROR(check_attended(p, o));
  // One view cannot see depth along its central ray: tracked only when the scene says so.
  LFTRACK_RETURN_IF_ERROR(check_views_observable(p.scene));
  LFTRACK_RETURN_IF_ERROR(check_simulator(p, o));  // before minutes of light-field building
  if (const auto blind = unobservable_direction_room(p.scene))
    spdlog::warn("one view: a registration cannot see motion along ({:.3f}, {:.3f}, {:.3f}) in the room; "
                 "corrections along it are not measured",
                 blind->x(), blind->y(), blind->z());
  auto parts = std::make_unique<Parts>();
  auto renderer = make_scene_renderer(p, p.scene.renderer, o.light_field_dir, pool);
  if (!renderer.ok()) return renderer.status().with_context("tracking renderer");
  parts->registration_renderer = *renderer;
  auto registration = make_scene_registration(p, parts->registration_renderer, p.scene.registration, pool);
  if (!registration.ok()) return registration.status();
  parts->registration = std::move(registration).value();
  parts->planned_registration = std::make_unique<PlannedRegistration>(parts->registration.get());

  std::vector<drivers::DetectorShape> shapes;
  for (const DetectorSpec& d : p.scene.detectors) shapes.push_back({d.view.name, d.view.rows, d.view.cols});
  auto frames_spec = frame_source_spec(p, o, pool, parts.get());
  if (!frames_spec.ok()) return frames_spec.status();
  auto frames = drivers::make_frame_source(std::move(frames_spec).value());
  if (!frames.ok()) return frames.status();
  parts->frames = std::move(frames).value();
  parts->replay_frames = dynamic_cast<const drivers::ReplayFrameSource*>(parts->frames.get());
  if (parts->replay_frames != nullptr) {
    const std::string& note = parts->replay_frames->sequence().note;
    if (!note.empty()) spdlog::warn("{}: {}", parts->replay_frames->sequence().directory.string(), note);
  }
  auto actuator_spec = session_actuator_spec(p, o, parts.get());
  if (!actuator_spec.ok()) return actuator_spec.status();
  if (*actuator_spec) {
    auto actuator = drivers::make_actuator(std::move(**actuator_spec));
    if (!actuator.ok()) return actuator.status();
    parts->actuator = std::move(actuator).value();
    LFTRACK_RETURN_IF_ERROR(parts->actuator->open().with_context("actuator"));
  }
  const bool moves_patient = parts->actuator != nullptr && parts->replay_frames == nullptr;
  // The control socket before the records: its path is checked (never another file removed)
  // before the journal and the archive create anything.
  if (!o.control_socket.empty()) {
    auto socket = ControlSocket::open(o.control_socket);
    if (!socket.ok()) return socket.status();
    parts->operators.add(std::move(socket).value());
  }
  // The watchers next, also before the records: a port in use is refused with no journal made.
  LFTRACK_RETURN_IF_ERROR(start_watchers(p, o, parts.get()));
  if (!o.archive.empty()) {
    FrameArchiveOptions archive_options;
    archive_options.with_actuator = moves_patient;
    archive_options.overwrite = o.overwrite_archive;
    auto archive = FrameArchive::open(o.archive, shapes, archive_options);
    if (!archive.ok()) return archive.status();
    parts->archive = std::move(archive).value();
  }

  if (!o.journal.empty()) {
    JournalOptions journal_options = o.journal_options;
    journal_options.scene_fingerprint = scene_fingerprint(p.scene);
    auto journal = JournalWriter::open(o.journal, journal_options);
    if (!journal.ok()) return journal.status();
    parts->journal = std::move(journal).value();
  }
  if (o.terminal_operator) {
    auto terminal = TerminalOperator::open();
    if (terminal.ok()) parts->operators.add(std::move(terminal).value());
  }
  if (o.hooks.operator_input != nullptr)
    parts->operators.add(std::make_unique<BorrowedOperator>(o.hooks.operator_input));
  if (o.auto_resume_s) {
    const double period_s = 1e-3 * p.scene.loop.period_ms;
    parts->operators.add(std::make_unique<ScriptedOperator>(
        static_cast<std::int64_t>(std::ceil(*o.auto_resume_s / period_s))));
  }

  LoopParts lp;
  lp.geometry = loop_geometry(p);
  lp.registration = parts->planned_registration.get();
  lp.check_renderer = parts->registration_renderer.get();
  lp.frames = o.hooks.wrap_frames ? o.hooks.wrap_frames(parts->frames.get()) : parts->frames.get();
  lp.archive = parts->archive.get();
  auto corrections = scene_detector_corrections(p, parts->room != nullptr);
  if (!corrections.ok()) return corrections.status();
  lp.corrections = std::move(corrections).value();
  lp.actuator = parts->actuator.get();
  if (lp.actuator != nullptr && o.hooks.wrap_actuator) lp.actuator = o.hooks.wrap_actuator(lp.actuator);
  if (moves_patient && p.scene.actuator.calibration) {
    parts->calibrated_couch = std::make_unique<CalibratedCouch>(
        lp.actuator, couch_mounting(*p.scene.actuator.calibration, p), p.registration_origin_room_mm());
    lp.actuator = parts->calibrated_couch.get();
    spdlog::info("couch commands go through the couch calibration {}", p.scene.actuator.calibration_file);
  } else if (moves_patient && p.scene.actuator.mounting) {
    spdlog::warn(
        "the couch is mounted off the room's axes but the scene names no actuator.calibration: "
        "corrections assume the room's axes");
  }
  lp.journal = parts->journal.get();
  lp.operator_input = parts->operators.empty() ? nullptr : &parts->operators;
  lp.truth = parts->room ? parts->room->truth() : nullptr;  // null when replaying
  lp.allocation_count = o.allocation_count;
  lp.observer = o.hooks.observer;
  lp.feed = parts->feed.get();
  lp.pool = pool;
  LoopSettings settings;
  settings.loop = p.scene.loop;
  settings.limits = p.scene.safety;
  settings.actuator_latency_s = lp.actuator != nullptr ? p.scene.actuator.dynamics.latency_s : 0.0;
  settings.cycles = o.cycles;
  settings.simulated_clock = o.simulated_clock;
  settings.status_line = o.status_line;
  settings.announce_holds = o.announce_holds;
  LFTRACK_RETURN_IF_ERROR(make_session_surrogate(p, o, parts.get(), &settings));
  lp.surrogate = parts->surrogate.get();
  if (lp.surrogate != nullptr && o.hooks.wrap_surrogate) lp.surrogate = o.hooks.wrap_surrogate(lp.surrogate);
  warn_if_prediction_window_short(settings);
  warn_if_beam_wait_short(p.scene);
  spdlog::info("registration plans: {}", describe_loop_plans(p.scene));
  std::string floors_from;
  auto verdict = scene_verdict_limits(p, p.scene.registration.similarity, &floors_from);
  if (!verdict.ok()) return verdict.status();
  settings.judge_tracking = p.scene.loop.judge_tracking.value_or(!p.scene.commissioning_file.empty());
  spdlog::info("registration verdict floors: {}; judging {}", floors_from,
               settings.judge_tracking ? "the alignment and every tracking cycle" : "the alignment only");
  settings.verdict = *verdict;
  if (judges_view_shift(*verdict)) {
    auto track_plan = tracking::registration_plan(p.scene.loop.track_plan);
    if (!track_plan.ok()) return track_plan.status().with_context("loop.track_plan");
    auto agreement = make_scene_view_agreement(p, parts->registration_renderer, p.scene.registration, *track_plan, pool);
    if (!agreement.ok()) return agreement.status().with_context("the verdict's view check");
    parts->view_agreement = std::move(agreement).value();
    lp.view_agreement = parts->view_agreement.get();
    settings.view_check_every = p.scene.verdict_checks.view_check_every;
    spdlog::info("registration verdict: each view registered alone at every alignment{} (at most {:.3g} mm across it)",
                 settings.judge_tracking && settings.view_check_every > 0
                     ? " and once every " + std::to_string(settings.view_check_every) + " tracking cycles"
                     : std::string(),
                 verdict->max_view_shift_mm);
  } else {
    spdlog::info("registration verdict: no view check (safety.max_view_shift_mm: 0, or one view)");
  }
  auto loop = TrackingLoop::create(lp, settings);
  if (!loop.ok()) return loop.status();
  parts->loop = std::move(loop).value();
  return std::unique_ptr<LoopSession>(new LoopSession(std::move(parts)));
}

Result<LoopSummary> LoopSession::run() {
  auto summary = parts_->loop->run();
  if (parts_->actuator) parts_->actuator->close();
  // The room's other systems get the last cycles (the final pose, and the state the loop ended
  // in) before the servers close; bounded, for a watcher that cannot keep up.
  if (parts_->hub) {
    const std::uint64_t seq = parts_->hub->catch_up(std::chrono::milliseconds(500));
    if (parts_->igtl) parts_->igtl->catch_up(seq, std::chrono::milliseconds(500));
  }
  if (parts_->journal) {
    if (Status s = parts_->journal->close(); !s.ok() && summary.ok()) summary->journal_error = s.message();
  }
  if (parts_->archive) {
    if (Status s = parts_->archive->close(); !s.ok() && summary.ok()) return s;
  }
  return summary;
}

void LoopSession::request_stop() {
  parts_->loop->request_stop();
}
RoomSimulation* LoopSession::simulation() {
  return parts_->room.get();
}
const RoomSimulation* LoopSession::simulation() const {
  return parts_->room.get();
}
const drivers::ReplayFrameSource* LoopSession::replay() const {
  return parts_->replay_frames;
}
const FrameArchive* LoopSession::archive() const {
  return parts_->archive.get();
}
const drivers::ModbusCouch* LoopSession::modbus_couch() const {
  const drivers::Actuator* a = device_driver(*parts_);
  return dynamic_cast<const drivers::ModbusCouch*>(a);
}
std::filesystem::path LoopSession::journal_path() const {
  return parts_->journal ? parts_->journal->path() : std::filesystem::path();
}
bool LoopSession::journal_failed() const {
  return parts_->journal != nullptr && parts_->journal->failed();
}
const drivers::CanRobot* LoopSession::can_robot() const {
  const drivers::Actuator* a = device_driver(*parts_);
  return dynamic_cast<const drivers::CanRobot*>(a);
}
const MonitorServer* LoopSession::monitor() const {
  return parts_->monitor.get();
}
const IgtlServer* LoopSession::igtl() const {
  return parts_->igtl.get();
}
const CycleHub* LoopSession::hub() const {
  return parts_->hub.get();
}

}  // namespace lftrack::session

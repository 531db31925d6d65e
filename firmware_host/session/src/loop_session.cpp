#include "lftrack/host/loop_session.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/host/calibrated_couch.hpp"
#include "lftrack/host/scene_verdict.hpp"
#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/host/scene_registration.hpp"
#include "lftrack/sim/room_clocked_actuator.hpp"

namespace lftrack::host {

namespace {

// The simulated room's truth as the loop reads it (tracking_loop.hpp never sees sim/).
class RoomTruth final : public SimulatedTruth {
 public:
  explicit RoomTruth(const sim::SimulatedRoom* room) : room_(room) {}
  double residual_mm() const override { return room_->residual_mm(); }

 private:
  const sim::SimulatedRoom* room_;
};

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

struct LoopSession::Parts {
  std::shared_ptr<const tracking::DrrRenderer> registration_renderer, frame_renderer;
  std::unique_ptr<tracking::Registration> registration;
  std::unique_ptr<sim::SimulatedRoom> room;
  std::unique_ptr<SimFrameSource> sim_frames;
  // Devices the drivers' factory made (device_factory.hpp), and typed views of them for the
  // session's accessors.
  std::unique_ptr<drivers::FrameSource> device_frames;  // replay
  std::unique_ptr<drivers::Actuator> recorded_couch;    // replay, when the sequence has read-backs
  std::unique_ptr<drivers::Actuator> hil_driver;        // HIL: the Modbus or CAN driver
  const drivers::ReplayFrameSource* replay_frames = nullptr;
  std::unique_ptr<sim::ModbusCouchServer> couch_server;  // HIL: serves the room's couch
  std::unique_ptr<sim::VirtualRobot> robot;  // HIL over CAN: moves the room's couch
  std::unique_ptr<sim::RoomClockedActuator> hil_couch;
  std::unique_ptr<RoomTruth> truth;  // simulation only
  std::unique_ptr<CalibratedCouch> calibrated_couch;  // the couch through its calibration
  std::unique_ptr<JournalWriter> journal;
  std::unique_ptr<FrameArchive> archive;
  OperatorInputs operators;
  std::unique_ptr<TrackingLoop> loop;
};

LoopSession::LoopSession(std::unique_ptr<Parts> parts) : parts_(std::move(parts)) {}
LoopSession::~LoopSession() = default;

namespace {

// The journal, the archive and the control socket are three different places: a socket opened
// over the journal (or the other way round) would lose the record.
Status check_distinct_paths(const LoopSessionOptions& o) {
  namespace fs = std::filesystem;
  const auto same = [](const fs::path& a, const fs::path& b) {
    return !a.empty() && !b.empty() && fs::weakly_canonical(a) == fs::weakly_canonical(b);
  };
  const auto inside = [](const fs::path& file, const fs::path& dir) {
    if (file.empty() || dir.empty()) return false;
    const fs::path f = fs::weakly_canonical(file), d = fs::weakly_canonical(dir);
    const auto mismatch = std::mismatch(d.begin(), d.end(), f.begin(), f.end());
    return mismatch.first == d.end();
  };
  if (same(o.control_socket, o.journal))
    return invalid_argument("--control and --journal name the same file " + o.journal.string());
  if (inside(o.control_socket, o.archive) || inside(o.journal, o.archive))
    return invalid_argument("the journal and the control socket cannot be inside the frame archive " +
                            o.archive.string());
  if (inside(o.journal, o.replay_sequence) || inside(o.archive, o.replay_sequence))
    return invalid_argument("the journal and the archive cannot be inside the replayed sequence " +
                            o.replay_sequence.string());
  return {};
}

}  // namespace

Status check_session_options(const LoopSessionOptions& o) {
  if (o.auto_resume_s) LFTRACK_RETURN_IF_ERROR(check_auto_resume_s(*o.auto_resume_s));
  LFTRACK_RETURN_IF_ERROR(check_distinct_paths(o));
  if (!o.control_socket.empty()) LFTRACK_RETURN_IF_ERROR(ControlSocket::check_path(o.control_socket));
  if (!o.journal.empty() && !o.journal_options.add_suffix)
    LFTRACK_RETURN_IF_ERROR(check_journal_path(o.journal, o.journal_options.overwrite));
  if (!o.archive.empty()) LFTRACK_RETURN_IF_ERROR(check_archive_directory(o.archive, o.overwrite_archive));
  return {};
}

Result<std::unique_ptr<LoopSession>> LoopSession::create(const PreparedScene& p, const LoopSessionOptions& o,
                                                         tracking::ThreadPool* pool) {
  // Options first: a bad one is refused before minutes of light-field building, and before the
  // earlier archive is removed (--overwrite) or anything else is created.
  LFTRACK_RETURN_IF_ERROR(check_session_options(o));
  // One view cannot see depth along its central ray: tracked only when the scene says so.
  LFTRACK_RETURN_IF_ERROR(check_views_observable(p.scene));
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

  std::vector<drivers::DetectorShape> shapes;
  for (const DetectorSpec& d : p.scene.detectors) shapes.push_back({d.view.name, d.view.rows, d.view.cols});
  const bool replaying = !o.replay_sequence.empty();
  if (replaying) {
    drivers::ReplaySourceSpec replay;
    replay.sequence = o.replay_sequence;
    replay.detectors = shapes;
    replay.options.realtime = !o.simulated_clock;
    auto frames = drivers::make_frame_source(std::move(replay));
    if (!frames.ok()) return frames.status();
    parts->device_frames = std::move(frames).value();
    parts->replay_frames = dynamic_cast<const drivers::ReplayFrameSource*>(parts->device_frames.get());
    const std::string& note = parts->replay_frames->sequence().note;
    if (!note.empty()) spdlog::warn("{}: {}", o.replay_sequence.string(), note);
    if (parts->replay_frames->sequence().has_actuator) {
      auto recorded = drivers::make_actuator(drivers::RecordedActuatorSpec{parts->replay_frames});
      if (!recorded.ok()) return recorded.status();
      parts->recorded_couch = std::move(recorded).value();
      LFTRACK_RETURN_IF_ERROR(parts->recorded_couch->open());
    }
  } else {
    auto frame_renderer = make_sim_frame_renderer(p, o.light_field_dir, pool);
    if (!frame_renderer.ok()) return frame_renderer.status();
    parts->frame_renderer = *frame_renderer;
    sim::SimulatedRoomSpec room;
    room.nominal_T_room_from_ct = p.nominal_T_room_from_ct;
    room.origin_room_mm = p.registration_origin_room_mm();
    room.setup_error = p.scene.motion.setup_error;
    room.motion = p.scene.motion.motion;
    room.couch = p.scene.actuator.couch;
    if (p.scene.actuator.mounting)
      room.couch_T_room_from_couch = couch_mounting(*p.scene.actuator.mounting, p);
    room.residual_box_mm = p.scene.registration.tre_box_mm;
    parts->room = std::make_unique<sim::SimulatedRoom>(room);
    SimFrameSourceOptions frame_options = o.frames;
    frame_options.wait_for_frames = o.simulated_clock;
    if (p.scene.sim.renderer == "lightfield") frame_options.margin_px = 0;  // the field covers the ROI only
    parts->sim_frames =
        std::make_unique<SimFrameSource>(p, parts->frame_renderer, parts->room.get(), frame_options);
  }
  const bool has_couch = !replaying && p.scene.actuator.type == "virtual";
  if (o.hil != HilProtocol::kNone) {
    if (!has_couch)
      return invalid_argument(
          "hardware in the loop needs a simulated scene with `actuator: {type: virtual}`");
    // The simulator's side of the protocol (the couch's Modbus server, or the robot on a CAN
    // link), then the driver the factory makes for it.
    drivers::ActuatorSpec driver_spec;
    std::string endpoint;
    if (o.hil == HilProtocol::kModbus) {
      auto server = sim::ModbusCouchServer::start(&parts->room->couch_device());
      if (!server.ok()) return server.status();
      parts->couch_server = std::move(server).value();
      drivers::ModbusActuatorSpec couch;
      couch.options.port = parts->couch_server->port();
      couch.options.response_timeout_s = std::min(0.02, 0.5e-3 * p.scene.loop.period_ms);
      driver_spec = couch;
    } else {
      auto link = sim::can_socket_pair();
      if (!link.ok()) return link.status();
      auto robot = sim::VirtualRobot::start(&parts->room->couch_device(), (*link)[1]);
      if (!robot.ok()) return robot.status();
      parts->robot = std::move(robot).value();
      driver_spec = drivers::CanActuatorSpec{drivers::CanRobotOptions{}, (*link)[0]};
      endpoint = "CAN node 1 over a socket pair";
    }
    auto driver = drivers::make_actuator(std::move(driver_spec));
    if (!driver.ok()) return driver.status();
    parts->hil_driver = std::move(driver).value();
    if (const auto* modbus = dynamic_cast<const drivers::ModbusCouch*>(parts->hil_driver.get()))
      endpoint = modbus->endpoint();
    parts->hil_couch =
        std::make_unique<sim::RoomClockedActuator>(parts->room.get(), parts->hil_driver.get(), o.simulated_clock);
    LFTRACK_RETURN_IF_ERROR(parts->hil_couch->open());
    spdlog::info("hardware in the loop: the couch is {}", endpoint);
  }
  // The control socket before the records: its path is checked (never another file removed)
  // before the journal and the archive create anything.
  if (!o.control_socket.empty()) {
    auto socket = ControlSocket::open(o.control_socket);
    if (!socket.ok()) return socket.status();
    parts->operators.add(std::move(socket).value());
  }
  if (!o.archive.empty()) {
    FrameArchiveOptions archive_options;
    archive_options.with_actuator = has_couch;
    archive_options.overwrite = o.overwrite_archive;
    auto archive = FrameArchive::open(o.archive, shapes, archive_options);
    if (!archive.ok()) return archive.status();
    parts->archive = std::move(archive).value();
  }

  if (!o.journal.empty()) {
    auto journal = JournalWriter::open(o.journal, o.journal_options);
    if (!journal.ok()) return journal.status();
    parts->journal = std::move(journal).value();
  }
  if (o.terminal_operator) {
    auto terminal = TerminalOperator::open();
    if (terminal.ok()) parts->operators.add(std::move(terminal).value());
  }
  if (o.auto_resume_s) {
    const double period_s = 1e-3 * p.scene.loop.period_ms;
    parts->operators.add(std::make_unique<ScriptedOperator>(
        static_cast<std::int64_t>(std::ceil(*o.auto_resume_s / period_s))));
  }

  LoopParts lp;
  lp.geometry = loop_geometry(p);
  lp.registration = parts->registration.get();
  lp.check_renderer = parts->registration_renderer.get();
  lp.frames =
      replaying ? parts->device_frames.get() : static_cast<drivers::FrameSource*>(parts->sim_frames.get());
  lp.archive = parts->archive.get();
  lp.corrections.assign(p.scene.detectors.size(), sim::detector_correction(scene_detector_model(p)));
  lp.actuator = parts->hil_couch ? static_cast<drivers::Actuator*>(parts->hil_couch.get())
                : has_couch      ? &parts->room->couch_actuator()
                                 : parts->recorded_couch.get();
  if (has_couch && p.scene.actuator.calibration) {
    parts->calibrated_couch = std::make_unique<CalibratedCouch>(
        lp.actuator, couch_mounting(*p.scene.actuator.calibration, p), p.registration_origin_room_mm());
    lp.actuator = parts->calibrated_couch.get();
    spdlog::info("couch commands go through the couch calibration {}", p.scene.actuator.calibration_file);
  } else if (has_couch && p.scene.actuator.mounting) {
    spdlog::warn(
        "the couch is mounted off the room's axes but the scene names no actuator.calibration: "
        "corrections assume the room's axes");
  }
  lp.journal = parts->journal.get();
  lp.operator_input = parts->operators.empty() ? nullptr : &parts->operators;
  if (parts->room) parts->truth = std::make_unique<RoomTruth>(parts->room.get());
  lp.truth = parts->truth.get();  // null when replaying
  lp.allocation_count = o.allocation_count;
  LoopSettings settings;
  settings.loop = p.scene.loop;
  settings.limits = p.scene.safety;
  settings.actuator_latency_s = lp.actuator != nullptr ? p.scene.actuator.couch.latency_s : 0.0;
  settings.cycles = o.cycles;
  settings.simulated_clock = o.simulated_clock;
  settings.status_line = o.status_line;
  settings.announce_holds = o.announce_holds;
  auto verdict = verdict_limits(p.scene, p.scene.registration.similarity);
  if (!verdict.ok()) return verdict.status();
  settings.verdict = *verdict;
  auto loop = TrackingLoop::create(lp, settings);
  if (!loop.ok()) return loop.status();
  parts->loop = std::move(loop).value();
  return std::unique_ptr<LoopSession>(new LoopSession(std::move(parts)));
}

Result<LoopSummary> LoopSession::run() {
  auto summary = parts_->loop->run();
  if (parts_->hil_couch) parts_->hil_couch->close();
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
const sim::SimulatedRoom* LoopSession::room() const {
  return parts_->room.get();
}
const drivers::ReplayFrameSource* LoopSession::replay() const {
  return parts_->replay_frames;
}
const FrameArchive* LoopSession::archive() const {
  return parts_->archive.get();
}
const drivers::ModbusCouch* LoopSession::modbus_couch() const {
  return dynamic_cast<const drivers::ModbusCouch*>(parts_->hil_driver.get());
}
sim::ModbusCouchServer* LoopSession::modbus_couch_server() {
  return parts_->couch_server.get();
}
std::filesystem::path LoopSession::journal_path() const {
  return parts_->journal ? parts_->journal->path() : std::filesystem::path();
}
const drivers::CanRobot* LoopSession::can_robot() const {
  return dynamic_cast<const drivers::CanRobot*>(parts_->hil_driver.get());
}
sim::VirtualRobot* LoopSession::virtual_robot() {
  return parts_->robot.get();
}

}  // namespace lftrack::host

#include "lftrack/host/loop_session.hpp"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include <unistd.h>

#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/drivers/forwarding_actuator.hpp"
#include "lftrack/host/actuator_lock.hpp"
#include "lftrack/host/calibrated_couch.hpp"
#include "lftrack/host/scene_devices.hpp"
#include "lftrack/host/scene_fingerprint.hpp"
#include "lftrack/host/scene_registration.hpp"
#include "lftrack/host/scene_verdict.hpp"
#include "lftrack/loop/motion_predictor.hpp"
#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/sim/room_clocked_actuator.hpp"
#include "lftrack/watch/operator_token.hpp"

namespace lftrack::host {

namespace {

// The simulated room's truth as the loop reads it (tracking_loop.hpp never sees sim/).
class RoomTruth final : public SimulatedTruth {
 public:
  explicit RoomTruth(const sim::SimulatedRoom* room) : room_(room) {}
  double residual_mm() const override { return room_->residual_mm(); }
  tracking::Vector6d target_residual() const override { return room_->target_residual(); }

 private:
  const sim::SimulatedRoom* room_;
};

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
  std::unique_ptr<PlannedRegistration> planned_registration;  // the loop's view of `registration`
  std::unique_ptr<ViewAgreement> view_agreement;  // the verdict's view check; null: none
  std::unique_ptr<sim::SimulatedRoom> room;  // simulated detectors only
  // Every device comes from the drivers' factory (device_factory.hpp); the simulator's are made
  // through its hooks.
  std::unique_ptr<drivers::FrameSource> frames;
  // A device actuator's lock (actuator_lock.hpp), released after the actuator is closed.
  std::shared_ptr<const ActuatorLock> actuator_lock;
  const drivers::ReplayFrameSource* replay_frames = nullptr;  // a view of `frames` when replaying
  std::unique_ptr<drivers::Actuator> actuator;                // virtual, recorded, Modbus or CAN
  std::unique_ptr<drivers::Actuator> device_actuator;         // the Modbus or CAN driver (HIL or run)
  std::unique_ptr<sim::ModbusCouchServer> couch_server;  // HIL: serves the room's couch
  std::unique_ptr<sim::VirtualRobot> robot;              // HIL over CAN: moves the room's couch
  std::unique_ptr<RoomTruth> truth;                   // simulation only
  std::unique_ptr<CalibratedCouch> calibrated_couch;  // the couch through its calibration
  std::unique_ptr<JournalWriter> journal;
  std::unique_ptr<FrameArchive> archive;
  // The watchers, in the order they depend on each other (destroyed in reverse: the servers,
  // then the hub that feeds them, then what the hub reads).
  std::unique_ptr<CycleFeed> feed;
  std::unique_ptr<PageOperator> page_operator;
  std::unique_ptr<CycleHub> hub;
  std::unique_ptr<MonitorServer> monitor;
  std::unique_ptr<IgtlServer> igtl;
  OperatorInputs operators;
  std::unique_ptr<TrackingLoop> loop;
};

namespace {

// The simulated room of a scene: its patient, set-up error and couch; with `couch_link`, the
// couch is another process's.
Result<std::unique_ptr<sim::SimulatedRoom>> make_room(const PreparedScene& p, const LoopSessionOptions& o) {
  sim::SimulatedRoomSpec room;
  room.nominal_T_room_from_ct = p.nominal_T_room_from_ct;
  room.origin_room_mm = p.registration_origin_room_mm();
  room.setup_error = p.scene.motion.setup_error;
  room.motion = p.scene.motion.motion;
  room.couch = p.scene.actuator.couch;
  if (p.scene.actuator.mounting) room.couch_T_room_from_couch = couch_mounting(*p.scene.actuator.mounting, p);
  room.residual_box_mm = p.scene.registration.tre_box_mm;
  if (o.devices == SessionDevices::kScene && actuator_is_device(p.scene)) {
    // Simulated detectors and a real protocol's couch: the patient must move with that couch.
    if (p.scene.sim.couch_link.empty())
      return failed_precondition(
          "simulated detectors with a " + p.scene.actuator.type +
          " actuator: the simulated patient would never move with it; name the served couch's room link as "
          "sim.couch_link (lftrack serve couch|robot --room FILE), or use real detectors");
    auto link = sim::RoomLinkReader::open(p.scene.sim.couch_link);
    if (!link.ok()) return link.status().with_context("sim.couch_link");
    room.couch_link = std::move(link).value();
  }
  return std::make_unique<sim::SimulatedRoom>(room);
}

Result<drivers::FrameSourceSpec> frame_source_spec(const PreparedScene& p, const LoopSessionOptions& o,
                                                  tracking::ThreadPool* pool, LoopSession::Parts* parts) {
  std::vector<drivers::DetectorShape> shapes;
  for (const DetectorSpec& d : p.scene.detectors) shapes.push_back({d.view.name, d.view.rows, d.view.cols});
  if (!o.replay_sequence.empty()) {  // lftrack replay --sequence DIR
    drivers::ReplaySourceSpec replay;
    replay.sequence = o.replay_sequence;
    replay.detectors = shapes;
    replay.options.realtime = !o.simulated_clock;
    return drivers::FrameSourceSpec(std::move(replay));
  }
  if (o.devices == SessionDevices::kScene && !frames_are_simulated(p.scene))
    return device_frame_source_spec(p.scene);
  drivers::SimulatedSourceSpec simulated;
  simulated.make = [&p, &o, pool, parts]() -> Result<std::unique_ptr<drivers::FrameSource>> {
    auto patient = make_scene_patient(p, o.light_field_dir, pool);  // realistic physics (null: ideal frames)
    if (!patient.ok()) return patient.status();
    if (!*patient) {
      auto frame_renderer = make_sim_frame_renderer(p, o.light_field_dir, pool);
      if (!frame_renderer.ok()) return frame_renderer.status();
      parts->frame_renderer = *frame_renderer;
    }
    auto room = make_room(p, o);
    if (!room.ok()) return room.status();
    parts->room = std::move(room).value();
    SimFrameSourceOptions frame_options = o.frames;
    frame_options.wait_for_frames = o.simulated_clock;
    frame_options.detectors.margin_px = sim_frame_margin_px(p);
    return std::unique_ptr<drivers::FrameSource>(
        new SimFrameSource(p, parts->frame_renderer, parts->room.get(), frame_options, *patient));
  };
  return drivers::FrameSourceSpec(std::move(simulated));
}

// The simulator's side of a hardware-in-the-loop protocol (the couch's Modbus server, or the
// robot on a CAN link) and the driver the factory makes for it, clocked by the room.
Result<drivers::ActuatorSpec> hil_actuator_spec(const PreparedScene& p, const LoopSessionOptions& o,
                                                LoopSession::Parts* parts) {
  drivers::ActuatorSpec driver_spec;
  std::string endpoint;
  if (o.hil == HilProtocol::kModbus) {
    auto server = sim::ModbusCouchServer::start(&parts->room->couch_device());
    if (!server.ok()) return server.status();
    parts->couch_server = std::move(server).value();
    drivers::ModbusActuatorSpec couch;
    couch.options.port = parts->couch_server->port();
    // On the real clock a reply must come within the cycle; on the simulated clock the cycle has
    // no wall-clock length, and the budget only has to outlast a loaded host's scheduling (a
    // server thread preempted past 20 ms made a simulated run hold).
    couch.options.response_timeout_s = o.simulated_clock ? 0.25 : std::min(0.02, 0.5e-3 * p.scene.loop.period_ms);
    driver_spec = couch;
  } else {
    auto link = sim::can_socket_pair();
    if (!link.ok()) return link.status();
    auto robot = sim::VirtualRobot::start(&parts->room->couch_device(), (*link)[1]);
    if (!robot.ok()) return robot.status();
    parts->robot = std::move(robot).value();
    drivers::CanRobotOptions can_options;
    // As the Modbus reply's budget above: on the simulated clock the heartbeat's wall-clock
    // timeout only has to outlast a loaded host's scheduling of the robot's thread (0.3 s, six
    // heartbeats, is the real clock's).
    if (o.simulated_clock) can_options.heartbeat_timeout_s = 1.0;
    driver_spec = drivers::CanActuatorSpec{can_options, (*link)[0]};
    endpoint = "CAN node 1 over a socket pair";
  }
  auto driver = drivers::make_actuator(std::move(driver_spec));
  if (!driver.ok()) return driver.status();
  parts->device_actuator = std::move(driver).value();
  if (const auto* modbus = dynamic_cast<const drivers::ModbusCouch*>(parts->device_actuator.get()))
    endpoint = modbus->endpoint();
  spdlog::info("hardware in the loop: the couch is {}", endpoint);
  drivers::VirtualActuatorSpec clocked;
  clocked.make = [parts, simulated_clock = o.simulated_clock]() -> Result<std::unique_ptr<drivers::Actuator>> {
    return std::unique_ptr<drivers::Actuator>(
        new sim::RoomClockedActuator(parts->room.get(), parts->device_actuator.get(), simulated_clock));
  };
  return drivers::ActuatorSpec(std::move(clocked));
}

// What moves the patient, if anything: the recorded read-backs of a replayed sequence, the
// scene's Modbus couch or CAN robot (lftrack run), or the simulated room's couch, in process or
// behind its protocol (--hil).
Result<std::optional<drivers::ActuatorSpec>> session_actuator_spec(const PreparedScene& p,
                                                                   const LoopSessionOptions& o,
                                                                   LoopSession::Parts* parts) {
  using Spec = std::optional<drivers::ActuatorSpec>;
  if (o.hil != HilProtocol::kNone && (o.devices != SessionDevices::kSimulated || !o.replay_sequence.empty()))
    return invalid_argument("hardware in the loop (--hil) is a simulation: it needs `lftrack sim`");
  if (parts->replay_frames != nullptr) {
    if (!parts->replay_frames->sequence().has_actuator) return Spec();
    return Spec(drivers::RecordedActuatorSpec{parts->replay_frames});
  }
  if (o.devices == SessionDevices::kScene && actuator_is_device(p.scene)) {
    auto spec = device_actuator_spec(p.scene);
    if (!spec.ok()) return spec.status();
    auto lock = ActuatorLock::acquire(p.scene);  // before it is opened: one program drives a couch
    if (!lock.ok()) return lock.status();
    parts->actuator_lock = std::move(lock).value();
    spdlog::info("the actuator is {}", describe_actuator(p.scene.actuator));
    return Spec(std::move(spec).value());
  }
  // Simulated: a scene's couch or robot is simulated by the room's couch (its twin).
  const bool couch =
      o.devices == SessionDevices::kSimulated ? actuator_moves(p.scene) : actuator_is_virtual(p.scene);
  if (!couch) {
    if (o.hil != HilProtocol::kNone)
      return invalid_argument("hardware in the loop needs a scene with a couch (actuator.type other than none)");
    return Spec();
  }
  if (parts->room == nullptr)
    return failed_precondition("the virtual couch moves a simulated patient: it needs simulated detectors");
  if (o.hil != HilProtocol::kNone) {
    auto spec = hil_actuator_spec(p, o, parts);
    if (!spec.ok()) return spec.status();
    return Spec(std::move(spec).value());
  }
  if (actuator_is_device(p.scene))
    spdlog::info("the scene's {} is simulated by its twin, the virtual couch", describe_actuator(p.scene.actuator));
  drivers::VirtualActuatorSpec simulated;
  simulated.make = [room = parts->room.get()]() -> Result<std::unique_ptr<drivers::Actuator>> {
    // The room owns its couch; the session borrows it.
    return std::unique_ptr<drivers::Actuator>(new drivers::ForwardingActuator(&room->couch_actuator()));
  };
  return Spec(std::move(simulated));
}

}  // namespace

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

// A prediction window too short for its order is not an error (the predictor drops to a line, or
// to the newest estimate, MotionPredictor::kMaxNoiseGain), but the scene's author should know.
void warn_if_prediction_window_short(const LoopSettings& s) {
  const LoopSpec& l = s.loop;
  if (l.prediction_cycles < 2) return;
  const double lookahead_s = prediction_lookahead_s(s);
  const MotionPredictor::FullWindow w = MotionPredictor::full_window(
      l.prediction_cycles, l.prediction_order, 1e-9 * double(loop_period_ns(s)), lookahead_s);
  if (w.order_used >= l.prediction_order) return;
  const std::string used = w.order_used == 1 ? fmt::format("a line (noise gain {:.2f})", w.gain_used)
                                             : std::string("the newest estimate alone");
  const std::string advice = "a longer prediction_cycles or a lower prediction_order says so";
  if (!std::isfinite(w.gain_configured)) {
    spdlog::warn("loop: prediction_order {} needs at least {} prediction_cycles ({} given): the loop predicts with {}; {}",
                 l.prediction_order, l.prediction_order + 2, l.prediction_cycles, used, advice);
    return;
  }
  spdlog::warn(
      "loop: prediction_order {} over prediction_cycles {} ({} ms apart, {:.3f} s ahead) would multiply the "
      "registration's noise by {:.2f}, more than {}: the loop predicts with {}; {}",
      l.prediction_order, l.prediction_cycles, l.period_ms, lookahead_s, w.gain_configured,
      MotionPredictor::kMaxNoiseGain, used, advice);
}

// The simulator's couch, where its largest allowed move (safety.max_total_mm at its speed, after its
// latency) takes longer than the beam may wait: such a move would end in a HOLD "patient not in
// place" before the couch arrives. A real couch's speed is its own, not the scene's.
void warn_if_beam_wait_short(const Scene& scene) {
  if (scene.actuator.type != "virtual") return;
  const sim::VirtualCouchSpec& couch = scene.actuator.couch;
  const double largest_move_s = scene.safety.max_total_mm / couch.max_speed_mm_s + couch.latency_s;
  if (largest_move_s < scene.safety.max_beam_withheld_s) return;
  spdlog::warn(
      "safety: the couch's largest allowed move ({} mm at {} mm/s after {} s) takes {:.1f} s, not less than "
      "safety.max_beam_withheld_s ({} s): a move that large ends in a HOLD \"patient not in place\" before it "
      "is made; a longer max_beam_withheld_s or a smaller max_total_mm says so",
      scene.safety.max_total_mm, couch.max_speed_mm_s, couch.latency_s, largest_move_s,
      scene.safety.max_beam_withheld_s);
}

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

// A watcher's port that is taken now is refused before minutes of preparation (a later bind
// can still fail; the server says so then).
static Status check_watcher_ports(const LoopSessionOptions& o) {
  if (o.monitor && o.igtl && o.monitor->listen.port != 0 && o.monitor->listen.port == o.igtl->listen.port)
    return invalid_argument("--monitor and --igtl name the same port " + std::to_string(o.igtl->listen.port));
  if (o.monitor) LFTRACK_RETURN_IF_ERROR(check_monitor_origins(*o.monitor));
  for (const ListenAddress* at : {o.monitor ? &o.monitor->listen : nullptr, o.igtl ? &o.igtl->listen : nullptr}) {
    if (at == nullptr || at->port == 0) continue;
    int port = 0;
    auto fd = open_listening_socket(*at, &port);
    if (!fd.ok()) return fd.status().with_context(o.monitor && at == &o.monitor->listen ? "--monitor" : "--igtl");
    ::close(*fd);
  }
  return {};
}

Status check_session_options(const LoopSessionOptions& o) {
  if (o.auto_resume_s) LFTRACK_RETURN_IF_ERROR(check_auto_resume_s(*o.auto_resume_s));
  LFTRACK_RETURN_IF_ERROR(check_watcher_ports(o));
  LFTRACK_RETURN_IF_ERROR(check_distinct_paths(o));
  if (!o.control_socket.empty()) LFTRACK_RETURN_IF_ERROR(ControlSocket::check_path(o.control_socket));
  if (!o.journal.empty() && !o.journal_options.add_suffix)
    LFTRACK_RETURN_IF_ERROR(check_journal_path(o.journal, o.journal_options.overwrite));
  if (!o.archive.empty()) LFTRACK_RETURN_IF_ERROR(check_archive_directory(o.archive, o.overwrite_archive));
  // What would otherwise be found only after the CT load and minutes of light-field building
  // (issue 50 probe): a light-field folder that is a file, a sequence that is not there, a token
  // file that is another's.
  std::error_code ec;
  if (!o.light_field_dir.empty() && std::filesystem::exists(o.light_field_dir, ec) &&
      !std::filesystem::is_directory(o.light_field_dir, ec))
    return failed_precondition("--lf-dir " + o.light_field_dir.string() + ": not a folder");
  if (!o.replay_sequence.empty() && !std::filesystem::is_directory(o.replay_sequence, ec))
    return not_found(o.replay_sequence.string() + ": no such sequence directory");
  if (o.monitor && !o.monitor->token_file.empty())
    LFTRACK_RETURN_IF_ERROR(TokenFile::check(o.monitor->token_file).with_context("--monitor-token-file"));
  return {};
}

// The real devices a session opens (the scene's V4L2 or GigE detectors, Modbus couch or CAN robot
// under kScene), in words; empty when every device is simulated or replayed.
static std::string real_devices(const PreparedScene& p, const LoopSessionOptions& o) {
  if (o.devices != SessionDevices::kScene) return {};
  std::string devices;
  if (o.replay_sequence.empty() && !p.scene.detectors.empty() && frames_from_device(p.scene.detectors[0].frames))
    devices = "detectors " + describe_frames(p.scene.detectors[0].frames) + (p.scene.detectors.size() > 1 ? ", ..." : "");
  if (actuator_is_device(p.scene))
    devices += (devices.empty() ? "" : "; ") + describe_actuator(p.scene.actuator);
  return devices;
}

// In the room a HOLD ends only by a person's decision: a session on real devices takes no
// unattended operator (auto_resume_s, or an unattended input among the hooks), whoever asks.
static Status check_attended(const PreparedScene& p, const LoopSessionOptions& o) {
  const std::string devices = real_devices(p, o);
  if (devices.empty()) return {};
  std::string unattended;
  if (o.auto_resume_s) unattended = fmt::format("an automatic resume {} s into each HOLD", *o.auto_resume_s);
  else if (o.hooks.operator_input != nullptr && o.hooks.operator_input->unattended())
    unattended = "a scripted operator";
  if (unattended.empty()) return {};
  return failed_precondition("the room's devices (" + devices + ") take no unattended operator (" + unattended +
                             "): a HOLD there ends only by a person's decision (the terminal, the control socket or "
                             "the monitor page)");
}

Result<std::unique_ptr<LoopSession>> LoopSession::create(const PreparedScene& p, const LoopSessionOptions& o,
                                                         tracking::ThreadPool* pool) {
  // Options first: a bad one is refused before minutes of light-field building, and before the
  // earlier archive is removed (--overwrite) or anything else is created.
  LFTRACK_RETURN_IF_ERROR(check_session_options(o));
  LFTRACK_RETURN_IF_ERROR(check_attended(p, o));
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
  if (parts->room) parts->truth = std::make_unique<RoomTruth>(parts->room.get());
  lp.truth = parts->truth.get();  // null when replaying
  lp.allocation_count = o.allocation_count;
  lp.observer = o.hooks.observer;
  lp.feed = parts->feed.get();
  lp.pool = pool;
  LoopSettings settings;
  settings.loop = p.scene.loop;
  settings.limits = p.scene.safety;
  settings.actuator_latency_s = lp.actuator != nullptr ? p.scene.actuator.couch.latency_s : 0.0;
  settings.cycles = o.cycles;
  settings.simulated_clock = o.simulated_clock;
  settings.status_line = o.status_line;
  settings.announce_holds = o.announce_holds;
  warn_if_prediction_window_short(settings);
  warn_if_beam_wait_short(p.scene);
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
  const drivers::Actuator* a = parts_->device_actuator ? parts_->device_actuator.get() : parts_->actuator.get();
  return dynamic_cast<const drivers::ModbusCouch*>(a);
}
sim::ModbusCouchServer* LoopSession::modbus_couch_server() {
  return parts_->couch_server.get();
}
std::filesystem::path LoopSession::journal_path() const {
  return parts_->journal ? parts_->journal->path() : std::filesystem::path();
}
bool LoopSession::journal_failed() const {
  return parts_->journal != nullptr && parts_->journal->failed();
}
const drivers::CanRobot* LoopSession::can_robot() const {
  const drivers::Actuator* a = parts_->device_actuator ? parts_->device_actuator.get() : parts_->actuator.get();
  return dynamic_cast<const drivers::CanRobot*>(a);
}
sim::VirtualRobot* LoopSession::virtual_robot() {
  return parts_->robot.get();
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

}  // namespace lftrack::host

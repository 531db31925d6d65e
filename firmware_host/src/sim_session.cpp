#include "lftrack/host/sim_session.hpp"

#include <cmath>

#include "lftrack/host/scene_registration.hpp"

namespace lftrack::host {

struct SimSession::Parts {
  std::shared_ptr<const tracking::DrrRenderer> registration_renderer, frame_renderer;
  std::unique_ptr<tracking::Registration> registration;
  std::unique_ptr<sim::SimulatedRoom> room;
  std::unique_ptr<SimFrameSource> frames;
  std::unique_ptr<JournalWriter> journal;
  OperatorInputs operators;
  std::unique_ptr<TrackingLoop> loop;
};

SimSession::SimSession(std::unique_ptr<Parts> parts) : parts_(std::move(parts)) {}
SimSession::~SimSession() = default;

Result<std::unique_ptr<SimSession>> SimSession::create(const PreparedScene& p, const SimSessionOptions& o,
                                                       tracking::ThreadPool* pool) {
  auto parts = std::make_unique<Parts>();
  auto renderer = make_scene_renderer(p, p.scene.renderer, o.light_field_dir, pool);
  if (!renderer.ok()) return renderer.status().with_context("tracking renderer");
  parts->registration_renderer = *renderer;
  auto frame_renderer = make_sim_frame_renderer(p, o.light_field_dir, pool);
  if (!frame_renderer.ok()) return frame_renderer.status();
  parts->frame_renderer = *frame_renderer;
  auto registration = make_scene_registration(p, parts->registration_renderer, p.scene.registration, pool);
  if (!registration.ok()) return registration.status();
  parts->registration = std::move(registration).value();

  sim::SimulatedRoomSpec room;
  room.nominal_T_room_from_ct = p.nominal_T_room_from_ct;
  room.origin_room_mm = p.registration_origin_room_mm();
  room.setup_error = p.scene.motion.setup_error;
  room.motion = p.scene.motion.motion;
  room.couch = p.scene.actuator.couch;
  room.residual_box_mm = p.scene.registration.tre_box_mm;
  parts->room = std::make_unique<sim::SimulatedRoom>(room);

  SimFrameSourceOptions frame_options = o.frames;
  frame_options.wait_for_frames = o.simulated_clock;
  if (p.scene.sim.renderer == "lightfield") frame_options.margin_px = 0;  // the field covers the ROI only
  parts->frames =
      std::make_unique<SimFrameSource>(p, parts->frame_renderer, parts->room.get(), frame_options);

  if (!o.journal.empty()) {
    auto journal = JournalWriter::open(o.journal);
    if (!journal.ok()) return journal.status();
    parts->journal = std::move(journal).value();
  }
  if (o.terminal_operator) {
    auto terminal = TerminalOperator::open();
    if (terminal.ok()) parts->operators.add(std::move(terminal).value());
  }
  if (!o.control_socket.empty()) {
    auto socket = ControlSocket::open(o.control_socket);
    if (!socket.ok()) return socket.status();
    parts->operators.add(std::move(socket).value());
  }
  if (o.auto_resume_s) {
    const double period_s = 1e-3 * p.scene.loop.period_ms;
    parts->operators.add(std::make_unique<ScriptedOperator>(
        static_cast<std::int64_t>(std::ceil(*o.auto_resume_s / period_s))));
  }

  LoopParts lp;
  lp.scene = &p;
  lp.registration = parts->registration.get();
  lp.frames = parts->frames.get();
  lp.corrections.assign(p.scene.detectors.size(), sim::detector_correction(scene_detector_model(p)));
  const bool has_couch = p.scene.actuator.type == "virtual";
  lp.actuator = has_couch ? &parts->room->couch_actuator() : nullptr;
  lp.journal = parts->journal.get();
  lp.operator_input = parts->operators.empty() ? nullptr : &parts->operators;
  lp.truth = parts->room.get();
  lp.allocation_count = o.allocation_count;
  LoopSettings settings;
  settings.loop = p.scene.loop;
  settings.limits = p.scene.safety;
  settings.actuator_latency_s = has_couch ? p.scene.actuator.couch.latency_s : 0.0;
  settings.cycles = o.cycles;
  settings.simulated_clock = o.simulated_clock;
  settings.status_line = o.status_line;
  auto loop = TrackingLoop::create(lp, settings);
  if (!loop.ok()) return loop.status();
  parts->loop = std::move(loop).value();
  return std::unique_ptr<SimSession>(new SimSession(std::move(parts)));
}

Result<LoopSummary> SimSession::run() {
  auto summary = parts_->loop->run();
  if (parts_->journal) {
    if (Status s = parts_->journal->close(); !s.ok() && summary.ok()) return s;
  }
  return summary;
}

void SimSession::request_stop() {
  parts_->loop->request_stop();
}
const sim::SimulatedRoom& SimSession::room() const {
  return *parts_->room;
}

}  // namespace lftrack::host

#pragma once
// What a LoopSession owns (loop_session.cpp assembles it), and the parts of its assembly kept in
// files of their own: the devices (session_devices.cpp) and the checks before anything is made
// (session_checks.cpp). Private to the session library.

#include <memory>
#include <optional>

#include "lftrack/drivers/device_factory.hpp"
#include "lftrack/drivers/igtl_surrogate.hpp"
#include "lftrack/session/actuator_lock.hpp"
#include "lftrack/session/calibrated_couch.hpp"
#include "lftrack/session/loop_session.hpp"
#include "lftrack/session/room_simulator.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/session/scene_verdict.hpp"

namespace lftrack::session {

struct LoopSession::Parts {
  std::shared_ptr<const tracking::DrrRenderer> registration_renderer;
  std::unique_ptr<tracking::Registration> registration;
  std::unique_ptr<loop::PlannedRegistration> planned_registration;  // the loop's view of `registration`
  std::unique_ptr<loop::ViewAgreement> view_agreement;              // the verdict's view check; null: none
  // The simulated room (simulated detectors only), made by LoopSessionOptions::simulator;
  // destroyed after every device made from it. Every device comes from the drivers' factory
  // (device_factory.hpp); the simulator's are made through its hooks.
  std::unique_ptr<RoomSimulation> room;
  std::unique_ptr<drivers::FrameSource> frames;
  // A device actuator's lock (actuator_lock.hpp), released after the actuator is closed.
  std::shared_ptr<const ActuatorLock> actuator_lock;
  const drivers::ReplayFrameSource* replay_frames = nullptr;  // a view of `frames` when replaying
  std::unique_ptr<drivers::Actuator> actuator;                // virtual, recorded, Modbus or CAN
  // tracking.imaging model only: the surrogate (in lftrack sim with surrogate.source igtl, the
  // client of the room's tracker twin).
  std::unique_ptr<drivers::SurrogateSource> surrogate;
  std::unique_ptr<CalibratedCouch> calibrated_couch;          // the couch through its calibration
  std::unique_ptr<loop::JournalWriter> journal;
  std::unique_ptr<loop::FrameArchive> archive;
  // The watchers, in the order they depend on each other (destroyed in reverse: the servers,
  // then the hub that feeds them, then what the hub reads).
  std::unique_ptr<loop::CycleFeed> feed;
  std::unique_ptr<watch::PageOperator> page_operator;
  std::unique_ptr<watch::CycleHub> hub;
  std::unique_ptr<watch::MonitorServer> monitor;
  std::unique_ptr<watch::IgtlServer> igtl;
  loop::OperatorInputs operators;
  std::unique_ptr<loop::TrackingLoop> loop;
};

// Whether the session's devices need the simulated room (a simulation, or the scene's simulated
// detectors), and a refusal where they do and the options give no simulator.
bool needs_simulated_room(const PreparedScene& p, const LoopSessionOptions& o);
Status check_simulator(const PreparedScene& p, const LoopSessionOptions& o);
// The frame source of the session: an archived sequence (replay), the scene's detectors, or the
// simulated room's (made with the room, into `parts`).
Result<drivers::FrameSourceSpec> frame_source_spec(const PreparedScene& p, const LoopSessionOptions& o,
                                                   tracking::ThreadPool* pool, LoopSession::Parts* parts);
// What moves the patient, if anything (see session_devices.cpp); a device actuator's lock taken
// into `parts`.
Result<std::optional<drivers::ActuatorSpec>> session_actuator_spec(const PreparedScene& p,
                                                                   const LoopSessionOptions& o,
                                                                   LoopSession::Parts* parts);

// Imaging on demand (session_surrogate.cpp): the scene's breathing surrogate into `parts` where
// its imaging is `model`, and the dose per pair into `settings` (every mode: the summary compares).
// A replay registers every archived pair: its imaging is every_cycle.
Status make_session_surrogate(const PreparedScene& p, const LoopSessionOptions& o, LoopSession::Parts* parts,
                              loop::LoopSettings* settings);
// The OpenIGTLink client's options for the scene's surrogate.igtl (the session's and the start-up
// checks').
drivers::IgtlSurrogateOptions igtl_surrogate_options(const Scene& scene);

// In the room a HOLD ends only by a person's decision: a session on real devices takes no
// unattended operator.
Status check_attended(const PreparedScene& p, const LoopSessionOptions& o);
// Warnings for the scene's author: a prediction window too short for its order, a couch whose
// largest allowed move outlasts the beam's allowed wait.
void warn_if_prediction_window_short(const loop::LoopSettings& s);
void warn_if_beam_wait_short(const Scene& scene);

}  // namespace lftrack::session

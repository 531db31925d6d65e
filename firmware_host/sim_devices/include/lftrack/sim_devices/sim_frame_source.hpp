#pragma once
// The simulator's detectors: a FrameSource whose frames show the simulated room's anatomy at the
// requested exposure time (true pose from the room; SimDetectors: each ROI window rendered by the
// scene's sim renderer with photon noise, detector blur and quantisation, the rest of the
// detector coarser).
//
// Rendering runs on a thread of its own, started by request_exposure() (on the loop's thread,
// which reads the room's true pose then) and collected by acquire(), so frame k+1 renders while
// the loop sleeps after cycle k. This is exact, not an approximation: the room's couch state at
// an exposure time is settled once the previous cycle has commanded (commands take effect a
// latency after their deadline). Nothing allocates after open().
//
// Faults can be injected for tests: a frame that never arrives, and a skew between the views'
// timestamps.

#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "lftrack/drivers/frame_source.hpp"
#include "lftrack/session/room_simulator.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/sim/simulated_room.hpp"
#include "lftrack/sim/synthetic_frames.hpp"
#include "lftrack/sim_devices/sim_detectors.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"

namespace lftrack::sim_devices {

class SimFrameSource final : public drivers::FrameSource {
 public:
  // `patient`: the scene's realistic patient (make_scene_patient), or null for ideal frames from
  // `renderer`.
  SimFrameSource(const session::PreparedScene& scene, std::shared_ptr<const tracking::DrrRenderer> renderer,
                 sim::SimulatedRoom* room, const session::SimFrameSourceOptions& options = {},
                 std::shared_ptr<const SimulatedPatient> patient = nullptr);
  ~SimFrameSource() override;

  Status open(drivers::FramePair* pair) override;
  void request_exposure(std::int64_t exposure_time_ns) override;
  void no_exposure(std::int64_t cycle_time_ns) override { room_->advance_to_ns(cycle_time_ns); }
  bool exposes_on_request() const override { return true; }
  drivers::DeviceStatus acquire(drivers::FramePair* pair, drivers::Deadline deadline) override;
  void close() override;

 private:
  struct Job {
    std::int64_t index = -1;
    std::int64_t exposure_ns = 0;
    tracking::Pose pose = tracking::Pose::Identity();
    // The couch is another process's (a room link) on the real clock: the pose is taken at the
    // exposure time by the render thread, when that couch is where it is then.
    bool pose_at_exposure = false;
  };
  void render_loop();

  const session::PreparedScene& scene_;
  std::shared_ptr<const tracking::DrrRenderer> renderer_;
  std::shared_ptr<const SimulatedPatient> patient_;
  sim::SimulatedRoom* room_;
  session::SimFrameSourceOptions options_;
  sim::DetectorModel model_;
  std::optional<SimDetectors> detectors_;
  std::vector<tracking::Image<std::uint16_t>> rendered_;  // per view, whole detector

  std::thread thread_;
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  Job pending_;       // requested, not yet started
  Job rendered_job_;  // what rendered_ holds
  bool has_pending_ = false;
  bool rendering_ = false;
  bool has_rendered_ = false;
  bool stopping_ = false;
  Status render_status_;
  std::int64_t next_index_ = 0;
};

}  // namespace lftrack::sim_devices

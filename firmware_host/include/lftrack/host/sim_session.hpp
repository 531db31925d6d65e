#pragma once
// The simulated closed loop assembled from a scene (`lftrack sim`, the closed-loop tests): the
// simulated room (set-up error, patient motion, virtual couch), the simulator's detectors, the
// scene's registration, the journal and the operator inputs, around one TrackingLoop.

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>

#include "lftrack/host/operator_input.hpp"
#include "lftrack/host/scene.hpp"
#include "lftrack/host/sim_frame_source.hpp"
#include "lftrack/host/tracking_loop.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::host {

struct SimSessionOptions {
  std::int64_t cycles = 300;
  bool simulated_clock = false;  // true: as fast as possible, deterministic (see tracking_loop.hpp)
  bool status_line = false;
  std::filesystem::path journal;          // empty: no journal
  std::filesystem::path control_socket;   // empty: none
  bool terminal_operator = false;         // keys on a terminal's standard input
  std::optional<double> auto_resume_s;    // an unattended operator resumes this long into each HOLD
  std::filesystem::path light_field_dir;  // empty: the scene's default folder
  SimFrameSourceOptions frames;           // fault injection; wait_for_frames follows simulated_clock
  std::uint64_t (*allocation_count)() = nullptr;
};

class SimSession {
 public:
  ~SimSession();
  // Builds (or loads) the renderers' light fields, the registration on `pool`, the room and its
  // devices, and the loop. `scene` and `pool` must outlive the session.
  static Result<std::unique_ptr<SimSession>> create(const PreparedScene& scene,
                                                    const SimSessionOptions& options,
                                                    tracking::ThreadPool* pool);
  Result<LoopSummary> run();
  void request_stop();
  const sim::SimulatedRoom& room() const;

 private:
  struct Parts;
  explicit SimSession(std::unique_ptr<Parts> parts);
  std::unique_ptr<Parts> parts_;
};

}  // namespace lftrack::host

#pragma once
// What the loop asks of a registration, and nothing more: readied plans for the alignment and
// for tracking, the cycle's frames, and a run from a start pose. The product's is
// PlannedRegistration (a tracking::Registration and its two prepared plans); a test gives the
// loop a scripted one, so that its states (ALIGN, TRACK, HOLD, FAULT), the commands it refuses,
// its overruns and its resumes are tested in milliseconds, without images worth registering.

#include <cstdint>
#include <vector>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/registration.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::loop {

// Which of the loop's two plans a run uses: the cold, wide one of ALIGN, or tracking's warm one.
enum class RegistrationStage : std::uint8_t { kAlign, kTrack };

class LoopRegistration {
 public:
  virtual ~LoopRegistration() = default;
  // Once, from TrackingLoop::create, before any cycle: readies both plans (an error refuses the
  // loop).
  virtual Status prepare(const tracking::RegistrationPlan& align, const tracking::RegistrationPlan& track) = 0;
  // Each cycle: the views' preprocessed line integrals and masks (empty: all valid), in the frame
  // source's order, copied or used before the next call.
  virtual Status set_frames(const std::vector<tracking::ImageView<const float>>& frames,
                            const std::vector<tracking::ImageView<const unsigned char>>& valid) = 0;
  // Registers the last frames from `start_T_room_from_ct` with the stage's plan, within `max_ms`
  // of wall time, into `result` (whose vectors keep their capacity). Must not allocate in the
  // steady state. An error, or a result that is not finite, is a failed registration.
  virtual Status run(const tracking::Pose& start_T_room_from_ct, RegistrationStage stage, double max_ms,
                     tracking::RegistrationResult* result) = 0;
};

// The product's registration as the loop sees it. `registration` must outlive this.
class PlannedRegistration final : public LoopRegistration {
 public:
  explicit PlannedRegistration(tracking::Registration* registration) : registration_(registration) {}
  Status prepare(const tracking::RegistrationPlan& align, const tracking::RegistrationPlan& track) override;
  Status set_frames(const std::vector<tracking::ImageView<const float>>& frames,
                    const std::vector<tracking::ImageView<const unsigned char>>& valid) override;
  Status run(const tracking::Pose& start_T_room_from_ct, RegistrationStage stage, double max_ms,
             tracking::RegistrationResult* result) override;

 private:
  tracking::Registration* registration_;
  tracking::PreparedPlan align_, track_;
};

}  // namespace lftrack::loop

#pragma once
// An actuator that passes every call to another it does not own: a device borrowed from someone
// else (the simulated room's couch as a session's actuator), or the base of a wrapper that
// changes some calls and passes the rest (the chaos soak's fault injector, tests' broken
// couches). `inner` must outlive it.

#include "lftrack/drivers/actuator.hpp"

namespace lftrack::drivers {

class ForwardingActuator : public Actuator {
 public:
  explicit ForwardingActuator(Actuator* inner) : inner_(inner) {}
  Status open() override { return inner_->open(); }
  DeviceStatus command(const tracking::Vector6d& correction, Deadline deadline) override {
    return inner_->command(correction, deadline);
  }
  DeviceStatus readback(ActuatorState* state, Deadline deadline) override { return inner_->readback(state, deadline); }
  void hold() override { inner_->hold(); }
  void set_beam_permit(bool permit) override { inner_->set_beam_permit(permit); }
  bool readback_follows_frames() const override { return inner_->readback_follows_frames(); }
  bool moves_patient() const override { return inner_->moves_patient(); }
  void close() override { inner_->close(); }

 protected:
  Actuator* inner_;
};

}  // namespace lftrack::drivers

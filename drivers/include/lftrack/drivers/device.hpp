#pragma once
// The device interfaces every backend implements: V4L2 detectors, replay and sim frame
// sources; Modbus couch, CAN robot and virtual actuators (DESIGN.md, "Interfaces").
//
// A device is a small lifecycle object: open() and close() run outside the cycle and may take
// time; cycle calls (acquire, command, readback, hold) return a DeviceStatus, never throw,
// never allocate and never block past their deadline.

#include <chrono>
#include <cstdint>

namespace lftrack::drivers {

enum class DeviceStatus {
  kOk,
  kTimeout,       // the deadline passed before the device answered
  kFault,         // the device reported an error; the cycle treats the result as invalid
  kDisconnected,  // the device is gone; reopening happens outside the cycle
  kRefused,       // refused before acting (a fault condition it knows of): nothing was sent or moved
};

// For people: "ok", "no answer in time", "the device reported a fault", "disconnected",
// "refused (a fault condition)".
inline const char* to_string(DeviceStatus s) {
  switch (s) {
    case DeviceStatus::kOk:
      return "ok";
    case DeviceStatus::kTimeout:
      return "no answer in time";
    case DeviceStatus::kFault:
      return "the device reported a fault";
    case DeviceStatus::kDisconnected:
      return "disconnected";
    case DeviceStatus::kRefused:
      return "refused (a fault condition)";
  }
  return "?";
}

// An absolute point on CLOCK_MONOTONIC by which a cycle call must return.
using Deadline = std::chrono::steady_clock::time_point;

}  // namespace lftrack::drivers

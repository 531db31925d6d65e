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

// An absolute point on CLOCK_MONOTONIC by which a cycle call must return.
using Deadline = std::chrono::steady_clock::time_point;

}  // namespace lftrack::drivers

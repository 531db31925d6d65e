#pragma once
// The couch's Modbus register map, shared by the driver (modbus_couch.hpp) and the virtual couch
// server (sim/modbus_couch_server.hpp). Documented for integrators in docs/couch_modbus.md.
//
// Units: travel is the couch's displacement from its zero, as the 6-vector of actuator.hpp:
// translations in micrometres, rotation-vector components in microradians, each a signed 32-bit
// integer over two registers, high word first. Targets are absolute, so a repeated write is
// harmless (a retried command cannot move the couch twice).

#include <array>
#include <cstdint>

#include "lftrack/tracking/pose.hpp"

namespace lftrack::drivers::couch_registers {

// Holding registers (function 16 writes them all in one request; function 6 the control word).
inline constexpr int kTarget = 0;            // 12 registers: target travel (um, urad)
inline constexpr int kCommandSequence = 12;  // the couch acts when this changes; echoed in kAcknowledged
inline constexpr int kControl = 13;          // kEnable or kHold
inline constexpr int kHoldingCount = 14;
inline constexpr std::uint16_t kEnable = 1;  // move to the target
inline constexpr std::uint16_t kHold = 2;    // stop where it is; refuse targets until kEnable again

// Input registers (function 4 reads them all in one request).
inline constexpr int kStatus = 0;           // bits below
inline constexpr int kAcknowledged = 1;     // the last command sequence accepted
inline constexpr int kFaultWord = 2;        // kNoFault or a code below
inline constexpr int kPosition = 3;         // 12 registers: read-back travel (um, urad)
inline constexpr int kAcceptedTarget = 15;  // 12 registers: the target in effect (um, urad)
inline constexpr int kInputCount = 27;
inline constexpr std::uint16_t kStatusMoving = 1u << 0;
inline constexpr std::uint16_t kStatusFault = 1u << 1;
inline constexpr std::uint16_t kStatusHolding = 1u << 2;
inline constexpr std::uint16_t kStatusEnabled = 1u << 3;
inline constexpr std::uint16_t kNoFault = 0;
inline constexpr std::uint16_t kFaultTargetOutOfRange = 1;  // also answered with exception 3
inline constexpr std::uint16_t kFaultDrive = 2;

// Exception codes the couch answers with (Modbus application protocol, section 7).
inline constexpr int kExceptionIllegalValue = 3;  // target outside the couch's range
inline constexpr int kExceptionDeviceFailure = 4;
inline constexpr int kExceptionBusy = 6;

using TravelRegisters = std::array<std::uint16_t, 12>;

// Travel to registers, rounded to the nearest unit. False (registers untouched) for a value that
// is not finite or does not fit in 32 bits (beyond +-2147 m or rad): nothing is clamped.
bool encode_travel(const tracking::Vector6d& travel, std::uint16_t* registers);
tracking::Vector6d decode_travel(const std::uint16_t* registers);

}  // namespace lftrack::drivers::couch_registers

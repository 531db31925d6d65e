#pragma once
// The beam robot's CAN frame layout (CAN 2.0A, 11-bit identifiers, little-endian payloads),
// shared by the driver (can_robot.hpp) and the virtual robot (sim/virtual_robot.hpp);
// documented for integrators in docs/robot_can.md. `n` is the robot's node id (1..15).
//
//  id         from   dlc  payload
//  0x200+n    host   8    correction, translation: int16 x, y, z [um]; u8 sequence; u8 0
//  0x210+n    host   8    correction, rotation:    int16 x, y, z [10 urad]; u8 sequence; u8 0
//                         (the robot moves when both halves of one sequence have arrived)
//  0x220+n    host   2    control: u8 kControlEnable or kControlHold; u8 0
//  0x230+n    host   1    read-back request: u8 token
//  0x240+n    host   2    beam permit: u8 0 or 1; u8 counter
//  0x180+n    robot  2    acknowledge: u8 sequence; u8 kAck* result
//  0x280+n    robot  4    status (answers a request): u8 token; u8 state; u8 fault; u8 flags
//  0x290+n..  robot  8    read-back, after the status: 0x290 (x, y), 0x291 (z, rx) and 0x292
//   0x295+n               (ry, rz) of the position, 0x293..0x295 the same of the target in effect;
//                         int32 each, um and urad
//  0x700+n    robot  2    heartbeat (CANopen NMT style): u8 state; u8 counter; every period
//
// Error frames (CAN_ERR_FLAG) are the CAN controller's, as SocketCAN delivers them.

#include <linux/can.h>

#include <cstdint>

#include "lftrack/tracking/pose.hpp"

namespace lftrack::drivers::robot_can {

inline constexpr canid_t kCorrectionTranslation = 0x200;
inline constexpr canid_t kCorrectionRotation = 0x210;
inline constexpr canid_t kControl = 0x220;
inline constexpr canid_t kReadbackRequest = 0x230;
inline constexpr canid_t kBeamPermit = 0x240;
inline constexpr canid_t kAcknowledge = 0x180;
inline constexpr canid_t kStatus = 0x280;
inline constexpr canid_t kPositionFirst = 0x290;  // three frames
inline constexpr canid_t kTargetFirst = 0x293;    // three frames
inline constexpr canid_t kHeartbeat = 0x700;

inline constexpr std::uint8_t kControlEnable = 1, kControlHold = 2;
inline constexpr std::uint8_t kAckAccepted = 0, kAckOutOfRange = 1, kAckNotEnabled = 2;
// Heartbeat and status states (CANopen NMT).
inline constexpr std::uint8_t kStateBootUp = 0x00, kStateOperational = 0x05, kStatePreOperational = 0x7F;
inline constexpr std::uint8_t kFlagMoving = 1, kFlagEnabled = 2, kFlagBeamPermit = 4;

inline constexpr double kTranslationUnitMm = 1e-3;  // correction frames
inline constexpr double kRotationUnitRad = 1e-5;
inline constexpr double kReadbackUnitMm = 1e-3;  // read-back frames
inline constexpr double kReadbackUnitRad = 1e-6;

can_frame make_frame(canid_t id, int node, std::uint8_t dlc);
// A correction as its two frames; false if a component is not finite or does not fit in int16
// (beyond 32.7 mm or 0.327 rad: far beyond any per-cycle limit).
bool encode_correction(const tracking::Vector6d& correction, int node, std::uint8_t sequence,
                       can_frame* translation, can_frame* rotation);
tracking::Vector6d decode_correction(const can_frame& translation, const can_frame& rotation);
// Travel as three frames from `first` (kPositionFirst or kTargetFirst), and back.
bool encode_travel(const tracking::Vector6d& travel, canid_t first, int node, can_frame* frames);
void decode_travel_frame(const can_frame& frame, int index, tracking::Vector6d* travel);

}  // namespace lftrack::drivers::robot_can

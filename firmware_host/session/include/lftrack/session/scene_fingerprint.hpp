#pragma once
// What identifies the room and the patient a run's records belong to, so that a record read back
// later (a journal exported as a DICOM registration) is never joined with another scene.

#include <array>
#include <cstdint>
#include <string>

#include "lftrack/session/scene.hpp"

namespace lftrack::session {

// The room's geometry as text: every detector's view (name, size, pitch, source, pixel (0,0),
// axes) at full precision, in the scene's order. Room frame, mm.
std::string room_geometry_text(const Scene& scene);

// The first 16 bytes of SHA-256 over the room's geometry and the planning CT (its path made
// absolute and canonical, or the built-in phantom and its seed). Two scenes with the same room and
// CT have the same fingerprint, whatever their motion, tracking or loop settings; never all zeros
// (zeros mean "not recorded" in a journal's header).
std::array<std::uint8_t, 16> scene_fingerprint(const Scene& scene);

// The room alone, whatever patient lies in it: its geometry, its actuator and detectors (kind,
// where each is reached, the calibration file each names and that file's contents, SHA-256) and
// the program's version (lftrack::kVersion). The daily QA is the room's: `lftrack run` on any
// patient's scene in the room looks for today's passed QA by this fingerprint, so a recalibrated
// detector or couch, or an upgraded program, needs a QA of its own. Reads the calibration files
// (a file that cannot be read gives another fingerprint, never an error). Never all zeros.
std::array<std::uint8_t, 16> room_fingerprint(const Scene& scene);

std::string to_hex(const std::array<std::uint8_t, 16>& fingerprint);

}  // namespace lftrack::session

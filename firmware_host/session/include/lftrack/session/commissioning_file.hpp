#pragma once
// A scene's commissioning file (issue 52): the registration verdict's floors that `lftrack
// commission` measured for one scene, and the fingerprints of everything those floors depend on.
// A scene names its file (safety.commissioning); the loop and `lftrack register` then judge with
// its floors, and refuse the scene when the file is missing or was measured on another CT, room,
// registration or imaging (commissioned_verdict_limits, scene_verdict.hpp). The file is written by
// the command, never by hand: what it measured is kept in it for the physicist who reads it.

#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::session {

// What the floors depend on, each part a 16-hex-digit digest (SHA-256), so a stale file says
// which part changed.
struct CommissioningFingerprint {
  std::string ct;            // the attenuation volume (every voxel) and the inserted fiducials
  std::string geometry;      // detectors, nominal pose, ROI, registration origin, envelope
  std::string registration;  // measure, plans, renderer and its light fields, fiducial weight
  std::string imaging;       // the frames: bits, dose, blur, imaging physics (sim section)
  bool operator==(const CommissioningFingerprint&) const = default;
};
CommissioningFingerprint commissioning_fingerprint(const PreparedScene& scene);

struct CommissioningRecord {
  CommissioningFingerprint fingerprint;
  std::string measure;        // the scene's tracking.similarity: min_similarity's units
  double min_similarity = 0;  // per view, the measure's value at the result must reach this
  double min_check_ncc = 0;   // per view, the NCC of frame and DRR at the result must reach this
  // The view check's limit measured for the scene (mm; 0: the scene has no view check): each view
  // registered alone may move the target at most this across it. At most the scene's
  // safety.max_view_shift_mm (which the fingerprint holds).
  double max_view_shift_mm = 0;
  std::string scene;     // the scene file it was measured on, as given
  std::string made_utc;  // ISO 8601
  std::string command;   // the command line that measured it
};

// Reads a commissioning file; a clear error naming the file for anything missing or malformed.
Result<CommissioningRecord> read_commissioning_file(const std::filesystem::path& file);

// Writes `record` and, below it as YAML comments and a `measured:` mapping, `measured_yaml` (what
// was measured; read by people, kept with the floors). Written beside the target and renamed over
// it; an existing file is replaced only with `replace`.
Status write_commissioning_file(const std::filesystem::path& file, const CommissioningRecord& record,
                                const std::string& measured_yaml, bool replace);

// OK when `record` was measured on what `scene` is; otherwise names every part that differs and
// the command that commissions the scene again.
Status check_commissioning_current(const PreparedScene& scene, const CommissioningRecord& record,
                                   const std::filesystem::path& file);

}  // namespace lftrack::session

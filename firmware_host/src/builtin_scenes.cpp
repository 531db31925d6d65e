// The built-in default scene: the procedural spine phantom seen by two orthogonal oblique views,
// like the papers' CyberKnife-style room (ceiling sources at +-45 degrees, floor detectors of
// 512 x 512 pixels at 0.4 mm, 12-bit). Room frame = patient LPS at the nominal pose; the
// isocentre (room origin) sits on the target vertebra's body centre.

#include "lftrack/host/scene.hpp"

namespace lftrack::host {

std::optional<std::string> builtin_scene_text(const std::string& name) {
  if (name != kBuiltinPhantom) return std::nullopt;
  return std::string(R"yaml(
version: 1
name: builtin spine phantom
ct:
  path: builtin:phantom
  seed: 1
roi:                      # centred on the target vertebra (L3), posterior elements included
  size_mm: [64, 64, 40]
detectors:
  - name: A               # source up and to the patient's left, detector down and right
    frames: sim
    bits: 12
    rows: 512
    cols: 512
    pitch_mm: 0.4
    isocentric:
      source_direction: [0.70710678, -0.70710678, 0]
      up: [0, 0, 1]       # top row towards the head
      source_to_isocentre_mm: 1500
      source_to_detector_mm: 2100
  - name: B               # source up and to the patient's right
    frames: sim
    bits: 12
    rows: 512
    cols: 512
    pitch_mm: 0.4
    isocentric:
      source_direction: [-0.70710678, -0.70710678, 0]
      up: [0, 0, 1]
      source_to_isocentre_mm: 1500
      source_to_detector_mm: 2100
envelope:
  translation_mm: 10
  rotation_deg: 5
tracking:
  renderer: siddon
)yaml");
}

}  // namespace lftrack::host

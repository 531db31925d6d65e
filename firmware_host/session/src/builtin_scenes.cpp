// The built-in default scene: the procedural spine phantom seen by two orthogonal oblique views,
// like the papers' CyberKnife-style room (ceiling sources at +-45 degrees, floor detectors of
// 512 x 512 pixels at 0.4 mm, 12-bit). Room frame = patient LPS at the nominal pose; the
// isocentre (room origin) sits on the target vertebra's body centre.
//
// It is also the default closed loop (`lftrack sim`, `make demo`): a patient set up a few mm
// and a degree off, drifting slowly and moving with a breathing-like 4 s cycle of up to 5 mm, on
// a virtual couch with 100 ms latency, tracked at 10 Hz. Its light fields are small enough to
// build in about a minute on two cores the first time (cached in out/lightfields/builtin-phantom).

#include "lftrack/session/scene.hpp"

namespace lftrack::session {

namespace {
std::string phantom_scene_text();
}  // namespace

// builtin:phantom-clinical: the same room with X-rays that differ from the planning CT the way real
// ones do (sim.physics: clinical, issue 21), rendered by Siddon (exact, and no fields to build
// for the tests and studies that use it), registered by the robust plans.
std::optional<std::string> builtin_scene_text(const std::string& name) {
  if (name == kBuiltinPhantom) return phantom_scene_text();
  if (name != kBuiltinPhantomClinical) return std::nullopt;
  std::string text = phantom_scene_text();
  auto swap = [&](const std::string& from, const std::string& to) {
    const auto at = text.find(from);
    if (at != std::string::npos) text.replace(at, from.size(), to);
  };
  swap("name: builtin spine phantom\n", "name: builtin spine phantom, clinical X-rays\n");
  swap("  renderer: lightfield    # frames from a separate, finer field of the anatomy\n  light_field:\n"
       "    resolution: [24, 24, 192, 192]\n",
       "  renderer: siddon        # exact frames; lightfield renders them faster, from fields of water and bone\n"
       "  physics: clinical\n");
  // The plans that hold up on such frames (registration.hpp: robust, warm-robust).
  swap("  plan: quadratic\n", "  plan: robust\n");
  swap("  align_plan: quadratic\n", "  align_plan: robust\n");
  swap("  track_plan: warm\n", "  track_plan: warm-robust\n");
  return text;
}

namespace {
std::string phantom_scene_text() {
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
  renderer: lightfield    # the loop registers with light-field DRRs
  light_field:
    resolution: [16, 16, 128, 128]
  similarity: mi
  plan: quadratic
sim:
  renderer: lightfield    # frames from a separate, finer field of the anatomy
  light_field:
    resolution: [24, 24, 192, 192]
  photons_per_pixel: 10000
  detector_blur_px: 0.5
loop:
  period_ms: 100
  registration_budget_ms: 50
  acquire_timeout_ms: 40
  align_plan: quadratic
  track_plan: warm
  realtime:
    mode: ignore          # a treatment-room host sets enforce and cpus
actuator:
  type: virtual
  latency_s: 0.1
  max_speed_mm_s: 40
  max_speed_deg_s: 10
safety:
  max_step_mm: 2
  max_step_deg: 2
  max_total_mm: 10
  max_total_deg: 5
motion:
  setup_error: {translation_mm: [3, -2, 2], rotation_deg: [1, -0.5, 1]}
  drift: {translation_mm_per_s: [0.02, 0.01, -0.02]}
  breathing: {amplitude_mm: [0.5, 1.5, 4.5], amplitude_deg: [0.2, 0, 0], period_s: 4}
)yaml");
}
}  // namespace

}  // namespace lftrack::session

#pragma once
// Synthetic detector frames for tests and studies (PAPERS.md; DESIGN.md "Attenuation"): the exact
// (Siddon) line integrals at a known gold pose, Beer's law, Poisson photon noise at a stated dose,
// detector blur and quantisation to the detector's bit depth. Frames are made from a ray caster,
// never from the light field that will register them.
//
// With imaging physics (sim_spec/xray_physics_spec.hpp) a frame is, per pixel of the window:
//   primary    exp(-p) for the attenuation line integral p, or with a spectrum the
//              polyenergetic transmission behind the ray's water and bone mass thicknesses;
//   + scatter  scatter_model.hpp, from the primary and the ray's water-equivalent thickness;
//   x heel     the beam's intensity across the detector;
//   photons    Poisson, at photons_per_pixel (x the grid's primary transmission);
//   blur       the Gaussian point spread, plus the glare's share spread wider;
//   lag        the previous frame's share of the signal (the synthesizer keeps it);
//   counts     scaled to the (gridded) open field's level, x the residual gain; stuck pixels
//              read their stuck level; quantised to the bit depth.
// The anatomy part is not applied here: it changes the volumes the renderers cast through
// (anatomy_deformation.hpp).

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "lftrack/sim/detector_effects.hpp"
#include "lftrack/sim/scatter_model.hpp"
#include "lftrack/sim/xray_spectrum.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::sim {

struct DetectorModel {
  double photons_per_pixel = 10000;  // open field, per pixel and frame (the dose)
  double blur_sigma_px = 0.5;        // detector point-spread (scintillator), Gaussian
  int bits = 12;
  // Open-field counts as a fraction of full scale; above 1 the open field saturates (a dose an
  // automatic exposure control set for thick anatomy).
  double open_field_fraction = 0.85;
  bool noise = true;                  // false: expected values (no Poisson draw)
};

// What preprocess_frame() needs to undo the model: I0 in counts and the saturation level.
tracking::DetectorCorrection detector_correction(const DetectorModel& model);

// Photons in (0, 1e9], an open-field fraction in (0, 1e6], 8 to 16 bits.
Status check_detector_model(const DetectorModel& model);

// The effects of detector number `detector_seed` (each its own fixed pattern) from the scene's.
sim_spec::DetectorEffectsSpec effects_of_detector(const sim_spec::DetectorEffectsSpec& effects,
                                                  std::uint64_t detector_seed);

// The attenuation table of `beam`'s spectrum (make_spectrum, PolyenergeticTable::create).
Result<PolyenergeticTable> beam_attenuation_table(const sim_spec::BeamSpec& beam);

struct PatientRenderers;
class ScatterModel;
// Images of one window's size for transmitted_signal().
struct SignalBuffers {
  tracking::ImageView<float> line, bone, primary, thickness_cm, total;
};
// The signal relative to the open field (1 = open) at each pixel of `window` of `view`: the line
// integrals by `patient`'s renderers (with a spectrum, `table`, the water and bone mass
// thicknesses into line and bone; else the attenuation into line), the primary's transmission
// and the ray's water-equivalent thickness (cm), then `scatter` on top where set, into total.
// The frame synthesizer's window and the surround's coarse grid both use it, so that the two
// meet at the same levels. Allocates nothing.
Status transmitted_signal(const PatientRenderers& patient, const PolyenergeticTable* table, ScatterModel* scatter,
                          const tracking::Pose& gold_T_room_from_ct, const tracking::XrayView& view,
                          const tracking::PixelWindow& window, const SignalBuffers& buffers);

// Renders `window` of `view` with `exact` at `gold` and returns a whole-detector frame of raw
// counts; pixels outside the window are left at 0 (unexposed, which preprocessing masks).
// Same seed, same frame.
Result<tracking::Image<std::uint16_t>> synthesize_frame(const tracking::DrrRenderer& exact,
                                                        const tracking::Pose& gold_T_room_from_ct,
                                                        const tracking::XrayView& view,
                                                        const tracking::PixelWindow& window,
                                                        const DetectorModel& model, std::uint64_t seed);

// What a frame is rendered from: the attenuation line integral (ideal and mono-energetic
// frames), or with a spectrum the water and bone mass thicknesses (g/cm^2) of
// material_decomposition.hpp. Not owned.
struct PatientRenderers {
  const tracking::DrrRenderer* attenuation = nullptr;
  const tracking::DrrRenderer* water = nullptr;
  const tracking::DrrRenderer* bone = nullptr;
};

// The same model, sized once for one window and allocation-free per frame, for the simulator's
// frame source in the real-time loop. synthesize() renders `window` of `view` at `gold`, and
// writes the window's raw counts into `frame` (a whole detector); pixels outside it are left as
// they are. Same seed and same previous frame, same counts.
class FrameSynthesizer {
 public:
  // Ideal frames.
  FrameSynthesizer(const tracking::PixelWindow& window, const DetectorModel& model);
  // Frames with `physics` (its spectrum, scatter and detector parts) on a detector of
  // `detector_rows` x `detector_cols` pixels `pitch_mm` wide, whose fixed pattern is drawn from
  // `pattern_seed` (each detector its own).
  static Result<std::unique_ptr<FrameSynthesizer>> create(const tracking::PixelWindow& window,
                                                          const DetectorModel& model,
                                                          const sim_spec::XrayPhysicsSpec& physics,
                                                          int detector_rows, int detector_cols,
                                                          double pitch_mm, std::uint64_t pattern_seed);
  const tracking::PixelWindow& window() const { return window_; }
  // Whether frames need the water and bone renderers (a spectrum) or the attenuation one.
  bool needs_materials() const { return table_.has_value(); }
  Status synthesize(const tracking::DrrRenderer& renderer, const tracking::Pose& gold_T_room_from_ct,
                    const tracking::XrayView& view, std::uint64_t seed,
                    tracking::ImageView<std::uint16_t> frame);
  Status synthesize(const PatientRenderers& patient, const tracking::Pose& gold_T_room_from_ct,
                    const tracking::XrayView& view, std::uint64_t seed,
                    tracking::ImageView<std::uint16_t> frame);
  // The next frame carries no lag (a detector that was idle).
  void forget_previous_frame() { has_previous_ = false; }

 private:
  tracking::PixelWindow window_;
  DetectorModel model_;
  tracking::Image<float> line_integral_, photons_, blurred_;
  tracking::GaussianBlur blur_;
  // Physics (absent: ideal).
  std::optional<PolyenergeticTable> table_;
  std::unique_ptr<ScatterModel> scatter_;
  std::optional<sim_spec::DetectorEffectsSpec> effects_;
  std::unique_ptr<tracking::GaussianBlur> glare_;
  tracking::Image<float> bone_integral_, primary_, thickness_cm_, total_, glared_, previous_;
  tracking::Image<float> gain_, stuck_, heel_;  // the fixed pattern over the window
  bool has_previous_ = false;
};

}  // namespace lftrack::sim

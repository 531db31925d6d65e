#pragma once
// Synthetic detector frames for tests and studies (PAPERS.md; DESIGN.md "Attenuation"): the exact
// (Siddon) line integrals at a known gold pose, Beer's law, Poisson photon noise at a stated dose,
// detector blur and quantisation to the detector's bit depth. Frames are made from a ray caster,
// never from the light field that will register them.

#include <Eigen/Core>
#include <cstdint>
#include <vector>

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
  double open_field_fraction = 0.85;  // open-field counts as a fraction of full scale
  bool noise = true;                  // false: expected values (no Poisson draw)
};

// What preprocess_frame() needs to undo the model: I0 in counts and the saturation level.
tracking::DetectorCorrection detector_correction(const DetectorModel& model);

// Renders `window` of `view` with `exact` at `gold` and returns a whole-detector frame of raw
// counts; pixels outside the window are left at 0 (unexposed, which preprocessing masks).
// Same seed, same frame.
Result<tracking::Image<std::uint16_t>> synthesize_frame(const tracking::DrrRenderer& exact,
                                                        const tracking::Pose& gold_T_room_from_ct,
                                                        const tracking::XrayView& view,
                                                        const tracking::PixelWindow& window,
                                                        const DetectorModel& model, std::uint64_t seed);

// The same model, sized once for one window and allocation-free per frame, for the simulator's
// frame source in the real-time loop. synthesize() renders `window` of `view` at `gold`, and
// writes the window's raw counts into `frame` (a whole detector); pixels outside it are left as
// they are. Same seed, same counts.
class FrameSynthesizer {
 public:
  FrameSynthesizer(const tracking::PixelWindow& window, const DetectorModel& model);
  const tracking::PixelWindow& window() const { return window_; }
  Status synthesize(const tracking::DrrRenderer& renderer, const tracking::Pose& gold_T_room_from_ct,
                    const tracking::XrayView& view, std::uint64_t seed,
                    tracking::ImageView<std::uint16_t> frame);

 private:
  tracking::PixelWindow window_;
  DetectorModel model_;
  tracking::Image<float> line_integral_, photons_, blurred_;
  tracking::GaussianBlur blur_;
};

// Steel markers (spheres, partial volume from 4^3 sub-samples per voxel) written into a volume:
// value_at_centre replaces the voxel's value in proportion to the sphere's share of it.
template <class Unit>
void insert_markers(tracking::ScalarVolume<Unit>* volume, const std::vector<Eigen::Vector3d>& centres_ct_mm,
                    double radius_mm, float marker_value);

// Attenuation of stainless steel at about 70 keV (1/mm); a CT shows the same marker clipped at
// its top HU value (kMarkerHu).
inline constexpr float kSteelMuPerMm = 0.7f;
inline constexpr float kMarkerHu = 3071.f;

}  // namespace lftrack::sim

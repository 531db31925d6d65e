#pragma once
// The rest of a simulated detector (issue 51): a real flat panel reads out every pixel, not only
// the ROI the registration uses, and the operator's page, the frame archive and a replay show
// what it read. The frame synthesizer (synthetic_frames.hpp) renders the ROI window finely; this
// fills every pixel outside it, coarser:
//   line integrals   rendered on a coarse copy of the detector (at most `cells` pixels along its
//                    longer side, the same source and plane), by an exact renderer;
//   primary/scatter  as in the window (spectrum, scatter model), on the coarse grid;
//   interpolation    bilinear from the coarse pixels' centres to each detector pixel;
//   per pixel        the heel, photon noise, the fixed pattern's gain and stuck pixels, counts at
//                    the open field's level, quantised: the same levels as the window, so the two
//                    meet without a step where the anatomy is smooth. The noise is Poisson below
//                    30 photons and above it a normal deviate of the Poisson's variance (four
//                    uniforms summed, tails cut at 3.5 sigma): a fifth of an exact draw's time.
// Left out (the coarse grid is smoother than any of them): the detector blur, the glare and the
// lag. Pixels inside the window are never written.

#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "lftrack/sim/detector_effects.hpp"
#include "lftrack/sim/scatter_model.hpp"
#include "lftrack/sim/synthetic_frames.hpp"
#include "lftrack/sim/xray_spectrum.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::sim {

// Coarse pixels along the detector's longer side: 24 is 8.5 mm pixels on a 512 x 0.4 mm panel,
// 1,152 rays for a pair of views (about a hundredth of a 256 x 256 ROI pair).
inline constexpr int kSurroundCells = 24;

// The volume the surround's ray caster walks: `mu` block-averaged to voxels of about
// kSurroundVoxelMm (tracking::block_averaged; the nearest whole factor per axis), a sixtieth of
// the voxels of a 1 mm CT and a quarter of the steps along each ray. A coarse pixel (8.5 mm at
// the detector, about 5 mm at the isocentre) averages over more than such a voxel.
inline constexpr double kSurroundVoxelMm = 4.0;
tracking::MuVolume surround_volume(const tracking::MuVolume& mu);

class SurroundSynthesizer {
 public:
  // For a detector of `detector_rows` x `detector_cols` pixels (2..16384) `pitch_mm` wide whose
  // `window` the frame synthesizer renders, with the same model, physics and `pattern_seed` as
  // it; `cells` (2..1024) coarse pixels along the longer side, each at most 100 mm.
  static Result<std::unique_ptr<SurroundSynthesizer>> create(const tracking::PixelWindow& window,
                                                             const DetectorModel& model,
                                                             const sim_spec::XrayPhysicsSpec& physics,
                                                             int detector_rows, int detector_cols,
                                                             double pitch_mm, std::uint64_t pattern_seed,
                                                             int cells = kSurroundCells);
  // Writes every pixel of `frame` (the whole detector of `view`) outside the window. `exact`
  // renders what the window's renderers render (attenuation, or water and bone with a spectrum)
  // over the whole detector: a ray caster, not a light field made for the window. No allocation;
  // the same seed gives the same pixels.
  Status synthesize(const PatientRenderers& exact, const tracking::Pose& gold_T_room_from_ct,
                    const tracking::XrayView& view, std::uint64_t seed, tracking::ImageView<std::uint16_t> frame);
  int coarse_rows() const { return coarse_rows_; }
  int coarse_cols() const { return coarse_cols_; }

 private:
  SurroundSynthesizer() = default;
  // Bilinear weights from detector rows (cols) to coarse ones: lower index and upper's weight.
  struct Axis {
    std::vector<int> lower;
    std::vector<float> weight;
  };
  static Axis make_axis(int pixels, int coarse);

  tracking::PixelWindow window_;
  DetectorModel model_;
  int rows_ = 0, cols_ = 0, coarse_rows_ = 0, coarse_cols_ = 0;
  Axis row_axis_, col_axis_;
  tracking::Image<float> line_integral_, bone_integral_, primary_, thickness_cm_, total_;
  std::optional<PolyenergeticTable> table_;
  std::unique_ptr<ScatterModel> scatter_;
  bool effects_ = false;
  std::vector<float> heel_;            // per detector row
  tracking::Image<float> gain_, stuck_;  // per detector pixel, with detector effects
  tracking::XrayView geometry_;          // the last view's geometry, unnamed
};

}  // namespace lftrack::sim

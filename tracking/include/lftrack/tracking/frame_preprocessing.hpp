#pragma once
// From a raw detector frame to the line-integral image registration compares DRRs with
// (DESIGN.md, "Attenuation"): dark and gain correction, p = ln(I0 / I), crop to a window, masks,
// and a Gaussian blur whose sigma is given in millimetres on the detector.

#include <cstdint>
#include <vector>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {

// The detector's correction images and levels (counts). Empty images mean "none": no dark
// offset, unit gain.
struct DetectorCorrection {
  Image<float> dark_counts;   // offset per pixel, subtracted first
  Image<float> gain;          // flat-field gain per pixel (1 = nominal); <= 0 marks a dead pixel
  double open_field_counts = 4000;  // I0: dark-corrected counts with nothing in the beam
  int saturation_counts = 4095;     // raw values at or above this are saturated
};

// The open-field levels preprocess_frame accepts (counts): within them I0 / I, in float, is
// positive and finite for every raw value with no dark or gain image.
inline constexpr double kMinOpenFieldCounts = 1e-20;
inline constexpr double kMaxOpenFieldCounts = 1e30;

// The levels of a detector read out with `bits` (clamped to 8 to 16) whose open field reads
// `open_field_fraction` of full scale, with no dark or gain image: how frames of a detector with
// no calibration of its own are corrected (the simulator's detectors, and its served twins).
DetectorCorrection nominal_detector_correction(int bits, double open_field_fraction);

// Fills `line_integral` (window-sized) with p = ln(I0 / I), I = (raw - dark) / gain, for the
// pixels of `window`, and `valid` with 1 where p is usable: 0 for saturated raw values, dead
// pixels (gain <= 0) and photon-starved ones (I <= 0); masked pixels get p = 0. Fails, leaving
// the outputs untouched, if the window is outside the frame, the outputs or the correction
// images have the wrong size, or I0 is outside [1e-20, 1e30] counts (or not a number). A pixel
// whose I0 / I falls outside float's range (an absurd dark or gain value) is masked: every p is
// finite.
Status preprocess_frame(const ImageView<const std::uint16_t>& raw, const DetectorCorrection& correction,
                        const PixelWindow& window, ImageView<float> line_integral,
                        ImageView<unsigned char> valid);

// Separable Gaussian blur that respects a mask (normalised convolution: masked pixels neither
// contribute nor receive a guessed value; they keep their input value and stay masked). Sized once
// for an image shape; blur() allocates nothing.
class GaussianBlur {
 public:
  // sigma in pixels (0: copy). The kernel reaches 3 sigma.
  GaussianBlur(int rows, int cols, double sigma_px);
  double sigma_px() const { return sigma_px_; }
  // in and out have the shape given at construction (they may not alias); `valid` may be empty.
  Status blur(const ImageView<const float>& in, const ImageView<const unsigned char>& valid,
              ImageView<float> out);

 private:
  int rows_, cols_;
  double sigma_px_;
  std::vector<double> kernel_;
  std::vector<double> value_tmp_, weight_tmp_;
};

// High-pass filter that removes what varies slowly across the image (scatter, soft tissue that is
// not the planning CT's, a flat-field residue): out = in - low, where low is kPasses box means
// of the usable pixels in a (2r+1) x (2r+1) box (close to a Gaussian of the stated sigma, without
// a single box's ringing), each from running sums along rows and down columns, so the cost does
// not grow with the box. Masked pixels (valid == 0, or not finite) neither contribute nor receive
// a value: they get 0 and stay masked. Sized once for an image shape; apply() allocates nothing.
// It keeps the last call's usable pixels and their box counts: calls over the same pixels (every
// DRR of a registration level) skip the counting. Not for concurrent use.
class BoxHighPass {
 public:
  static constexpr int kPasses = 3;
  // radius_px is clamped to [1, max(rows, cols)] (a larger box sees no more of the image).
  BoxHighPass(int rows, int cols, int radius_px);
  // The radius whose kPasses boxes have standard deviation sigma_px (at least 1).
  static int radius_for_sigma(double sigma_px);
  int radius_px() const { return radius_; }
  // in and out have the shape given at construction (they may alias); `valid` may be empty.
  Status apply(const ImageView<const float>& in, const ImageView<const unsigned char>& valid,
               ImageView<float> out);

 private:
  int rows_, cols_, radius_;
  bool counts_ready_ = false;           // usable_ and inverse_count_ hold the last call's
  std::vector<unsigned char> usable_;   // rows x cols, 1 where usable
  std::vector<double> inverse_count_;   // rows x cols: 1 / usable pixels in the box; 0 unusable
  std::vector<double> row_sums_;        // rows x cols: sums along the rows (of counts, then values)
  std::vector<double> column_sums_;     // cols: box sums, sliding down
  std::vector<float> low_;              // rows x cols: the low-pass image; 0 at unusable pixels
};

}  // namespace lftrack::tracking

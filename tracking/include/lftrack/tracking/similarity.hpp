#pragma once
// Similarity measures between a fixed image (a preprocessed detector frame, line integrals) and a
// moving image (a DRR of the same pixels). Larger is better. Chosen by name through
// make_similarity(); one parameterised test runs them all on the same fixtures.
//
// Contract:
// - prepare() takes the fixed image once per frame (and its validity mask, 1 = use the pixel)
//   and sizes every scratch buffer; score() then allocates nothing.
// - score() takes a moving image of the same size and an optional validity mask (a light-field
//   DRR's). A pixel counts only where both masks are 1 and both values are finite.
// - score() always returns a finite value. With fewer than kMinPixels usable pixels, or images
//   that carry no information (constant), it returns the measure's worst_score() or the value its
//   definition gives for that case (stated per measure below); never NaN.
// - A Similarity holds scratch, so one object serves one thread; clone() makes another.

#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::tracking {

struct SimilarityOptions {
  int histogram_bins = 64;     // mi, nmi: bins per axis of the joint histogram, 2..1024
  int pattern_radius_px = 3;   // pi: neighbourhood radius
  double pattern_sigma = 0.1;  // pi: in units of the difference image's standard deviation
  double tukey_c = 2.5;        // rncc: the biweight's cut-off, times the residual's RMS, 1..100
  // mi, nmi: per-pixel passes in AVX2 lanes where the CPU has them (the same scores bit for bit);
  // false: the portable loops.
  bool vector_lanes = true;
};

class Similarity {
 public:
  static constexpr int kMinPixels = 16;

  virtual ~Similarity() = default;
  virtual std::string_view name() const = 0;
  // The value returned when nothing can be compared (too few pixels).
  virtual double worst_score() const = 0;

  // Fixed image and its mask (an empty mask view means every pixel is valid). Fails for an empty
  // image or a mask of another size.
  virtual Status prepare(const ImageView<const float>& fixed,
                         const ImageView<const unsigned char>& fixed_valid) = 0;
  // Moving image of the prepared size (a wrong size gives worst_score()).
  virtual double score(const ImageView<const float>& moving,
                       const ImageView<const unsigned char>& moving_valid = {}) = 0;
  virtual std::unique_ptr<Similarity> clone() const = 0;
};

// Names accepted by make_similarity, in a stable order:
//   mi   mutual information (nats), joint histogram with linear (partial-volume) binning of the
//        moving image; constant images give 0.
//   nmi  normalised mutual information (H(F) + H(M)) / H(F, M), in [1, 2]; constant images give 1.
//   ncc  normalised cross-correlation in [-1, 1]; a constant image gives 0.
//   rncc ncc with Tukey's biweight on the standardised residual (one reweighting step, cut-off
//        tukey_c times the residual's RMS): pixels the DRR cannot explain stop pulling the pose;
//        in [-1, 1], a constant image gives 0.
//   gc   gradient correlation: mean of the NCCs of the row and column gradients, in [-1, 1].
//   pi   pattern intensity (Weese) of the difference of the two standardised images, in [0, 1]
//        (1: identical up to a linear intensity map).
//   gd   gradient difference (Penney) with the least-squares intensity scale, in [0, 2].
std::vector<std::string> similarity_names();
Result<std::unique_ptr<Similarity>> make_similarity(std::string_view name,
                                                    const SimilarityOptions& options = {});

}  // namespace lftrack::tracking

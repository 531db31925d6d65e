#pragma once
// DRR renderers: every implementation computes, for each detector pixel in a window, the line
// integral of mu from the X-ray source to the pixel centre, through the CT placed in the room by
// T_room_from_ct. Renderers are chosen by name through make_renderer(); one parameterised test
// runs them all against the exact (Siddon) renderer.
//
// Contract of render():
// - `out` has exactly window.rows x window.cols pixels; out(r, c) is detector pixel
//   (window.row0 + r, window.col0 + c).
// - Values are mu * mm (unitless line integrals), >= 0; rays that miss the volume give 0.
// - It allocates nothing, does not throw, and is safe to call from several threads at once.
// - A non-finite pose, an invalid view, a window outside the detector or a wrongly sized `out`
//   (or mask) return an error Status and leave `out` untouched.
// - Pixels a renderer cannot compute (a ray outside a light field) are never guessed: they are
//   set to 0, marked 0 in the optional validity mask and counted in RenderExtras.

#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::tracking {

class ThreadPool;
class LightField;
class OctreeVolume;

// Optional inputs and outputs of render().
struct RenderExtras {
  // If set (same size as `out`): written 1 where the pixel is a computed line integral, 0 where
  // it is masked.
  ImageView<unsigned char> valid;
  // Written: how many pixels are masked.
  int masked_pixels = 0;
  // Written: true if the pose lies outside the envelope the renderer was built for.
  bool pose_outside_envelope = false;
};

class DrrRenderer {
 public:
  virtual ~DrrRenderer() = default;
  virtual std::string_view name() const = 0;
  // Bytes of precomputed data the renderer holds beyond the volume it was given (0 for ray casters).
  virtual std::size_t bytes() const { return 0; }

  Status render(const Pose& T_room_from_ct, const XrayView& view, const PixelWindow& window,
                ImageView<float> out, RenderExtras* extras = nullptr) const;

 protected:
  // Called by render() after its arguments were checked; `extras` is never null.
  virtual Status do_render(const Pose& T_room_from_ct, const XrayView& view, const PixelWindow& window,
                           ImageView<float> out, RenderExtras* extras) const = 0;
};

// kAvx2Gathers: the AVX2 kernel with every sample gathered (no runs), as before issue 24, for
// side-by-side benchmarks and tests of both paths.
enum class SimdLevel { kBest, kAvx2, kScalar, kAvx2Gathers };

struct RendererOptions {
  // Rows are spread over this pool; null renders on the calling thread.
  ThreadPool* pool = nullptr;
  // Trilinear renderer: sampling step as a fraction of the smallest voxel spacing.
  double trilinear_step_fraction = 0.5;
  // Light-field renderer: one precomputed field per view it will be asked to render (matched by
  // view name), all of one storage mode.
  std::vector<std::shared_ptr<const LightField>> light_fields;
  // Octree renderer: the compressed volume to render (shared; the volume given to make_renderer
  // may then be null), or, if null, one compressed from that volume at `octree_pivot` in [0, 1].
  std::shared_ptr<const OctreeVolume> octree;
  double octree_pivot = 0.0;
  // Which vectorised kernels the light-field renderer may use: the best the CPU has, at most
  // AVX2 (with or without runs), or none (the portable scalar kernels). Tests compare them.
  SimdLevel simd = SimdLevel::kBest;
  // Light-field renderer: render coarse pixels from (s, t)-averaged copies of the fields
  // (LightField::downsampled_st, by 2 and 4, made when the renderer is made, in float: 5/16 of a
  // float field's memory again, 5/8 of a 16-bit one's; VQ fields get none): a view and window
  // whose pixels span k >= 2 (s, t) samples on both axes at the nominal pose render from the copy
  // averaged over the largest such power of two k (at most 4), so a pixel averages rays over
  // about its footprint instead of taking the ray through its centre, and reads 1 / k^2 of the
  // samples (the 4 x 4 binned registration levels). False: every pixel samples the ray through
  // its centre.
  bool light_field_mips = true;
  // Light-field renderer, float and 16-bit fields: blend (u, v) once per (s, t) sample of the
  // window's footprint at that sample's ray from the moved source (a "source image"), then each
  // pixel bilinearly in (s, t) from it, instead of each pixel's 16 samples quadrilinearly at its
  // own ray. The two differ only by how much (u, v) moves between a pixel's ray and its (s, t)
  // neighbours' (nothing at the nominal pose); the image path reads a quarter of the samples a
  // pixel (BENCHMARKS.md, issue 24). False: the papers' per-ray blend (and, on AVX-512 CPUs,
  // its AVX-512 kernels).
  bool light_field_source_image = true;
};

// Names accepted by make_renderer, in a stable order.
std::vector<std::string> renderer_names();

// Builds the renderer called `name` over `volume` (shared, so the caller may drop its copy).
// "lightfield" renders from options.light_fields and needs no volume (`volume` may be null).
Result<std::unique_ptr<DrrRenderer>> make_renderer(std::string_view name,
                                                   std::shared_ptr<const MuVolume> volume,
                                                   const RendererOptions& options = {});

// Checks render()'s preconditions.
Status check_render_arguments(const Pose& T_room_from_ct, const XrayView& view, const PixelWindow& window,
                              const ImageView<float>& out, const RenderExtras* extras = nullptr);

}  // namespace lftrack::tracking

// The two ray-casting renderers: exact Siddon-Jacobs and fixed-step trilinear. Both walk one ray
// per pixel from the source to the pixel centre through GridRayCaster; they differ only in the
// line-integral rule (and Siddon hands its rays over a row at a time, for the vector lanes).

#include <algorithm>
#include <array>

#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/ray_integrals.hpp"
#include "pixel_rays.hpp"

namespace lftrack::tracking {
namespace {

enum class RayRule { kSiddon, kTrilinear };

class RayCastRenderer final : public DrrRenderer {
 public:
  RayCastRenderer(RayRule rule, std::shared_ptr<const MuVolume> volume, const RendererOptions& options)
      : rule_(rule), volume_(std::move(volume)), caster_(*volume_), pool_(options.pool) {
    step_mm_ = options.trilinear_step_fraction * volume_->geometry.spacing_mm.minCoeff();
  }

  std::string_view name() const override { return rule_ == RayRule::kSiddon ? "siddon" : "trilinear"; }

  Status do_render(const Pose& T_room_from_ct, const XrayView& view, const PixelWindow& window,
                   ImageView<float> out, RenderExtras* extras) const override {
    if (rule_ == RayRule::kTrilinear) {
      render_pixel_rays(volume_->geometry, T_room_from_ct, view, window, out, extras, pool_,
                        [&](const Eigen::Vector3d& source, const Eigen::Vector3d& pixel) {
                          return caster_.trilinear(source, pixel, step_mm_);
                        });
      return {};
    }
    // Siddon: a row's rays go to siddon_batch in groups (vector lanes where the CPU has them; the
    // same bits as one ray at a time), with buffers on the stack: nothing is allocated.
    render_pixel_ray_rows(volume_->geometry, T_room_from_ct, view, window, out, extras, pool_,
                          [&](const Eigen::Vector3d& source, const Eigen::Vector3d& first_pixel,
                              const Eigen::Vector3d& per_col, int cols, float* dst) {
                            constexpr int kGroup = 64;
                            std::array<Eigen::Vector3d, kGroup> from, to;
                            std::array<double, kGroup> integrals;
                            from.fill(source);
                            for (int c0 = 0; c0 < cols; c0 += kGroup) {
                              const auto n = static_cast<std::size_t>(std::min(kGroup, cols - c0));
                              for (std::size_t k = 0; k < n; ++k)
                                to[k] = first_pixel + per_col * (c0 + static_cast<int>(k));
                              caster_.siddon_batch({from.data(), n}, {to.data(), n}, {integrals.data(), n});
                              for (std::size_t k = 0; k < n; ++k)
                                dst[c0 + static_cast<int>(k)] = static_cast<float>(integrals[k]);
                            }
                          });
    return {};
  }

 private:
  RayRule rule_;
  std::shared_ptr<const MuVolume> volume_;
  GridRayCaster caster_;
  ThreadPool* pool_;
  double step_mm_ = 0.5;
};

}  // namespace

Status DrrRenderer::render(const Pose& T_room_from_ct, const XrayView& view, const PixelWindow& window,
                           ImageView<float> out, RenderExtras* extras) const {
  LFTRACK_RETURN_IF_ERROR(check_render_arguments(T_room_from_ct, view, window, out, extras));
  RenderExtras ignored;
  RenderExtras* e = extras ? extras : &ignored;
  e->masked_pixels = 0;
  e->pose_outside_envelope = false;
  return do_render(T_room_from_ct, view, window, out, e);
}

Status check_render_arguments(const Pose& T_room_from_ct, const XrayView& view, const PixelWindow& window,
                              const ImageView<float>& out, const RenderExtras* extras) {
  if (!T_room_from_ct.matrix().allFinite()) return invalid_argument("pose is not finite");
  LFTRACK_RETURN_IF_ERROR(view.validate());
  if (!window.inside(view.rows, view.cols)) {
    return out_of_range("pixel window rows " + std::to_string(window.row0) + "+" +
                        std::to_string(window.rows) + ", cols " + std::to_string(window.col0) + "+" +
                        std::to_string(window.cols) + " is not inside the " + std::to_string(view.rows) +
                        " x " + std::to_string(view.cols) + " detector of view '" + view.name + "'");
  }
  if (out.data == nullptr || out.rows != window.rows || out.cols != window.cols || out.stride < out.cols) {
    return invalid_argument("output image is " + std::to_string(out.rows) + " x " + std::to_string(out.cols) +
                            ", the window is " + std::to_string(window.rows) + " x " +
                            std::to_string(window.cols));
  }
  if (extras && extras->valid.data &&
      (extras->valid.rows != window.rows || extras->valid.cols != window.cols ||
       extras->valid.stride < extras->valid.cols)) {
    return invalid_argument("validity mask is " + std::to_string(extras->valid.rows) + " x " +
                            std::to_string(extras->valid.cols) + ", the window is " +
                            std::to_string(window.rows) + " x " + std::to_string(window.cols));
  }
  return {};
}

std::vector<std::string> renderer_names() {
  return {"siddon", "trilinear", "lightfield", "octree"};
}

// In light_field_renderer.cpp.
Result<std::unique_ptr<DrrRenderer>> make_light_field_renderer(
    std::vector<std::shared_ptr<const LightField>> fields, ThreadPool* pool, SimdLevel simd, bool mips,
    bool source_image);
// In octree_renderer.cpp.
Result<std::unique_ptr<DrrRenderer>> make_octree_renderer(std::shared_ptr<const MuVolume> volume,
                                                          const RendererOptions& options);

Result<std::unique_ptr<DrrRenderer>> make_renderer(std::string_view name,
                                                   std::shared_ptr<const MuVolume> volume,
                                                   const RendererOptions& options) {
  if (name == "lightfield")
    return make_light_field_renderer(options.light_fields, options.pool, options.simd, options.light_field_mips,
                                     options.light_field_source_image);
  if (name == "octree") return make_octree_renderer(std::move(volume), options);
  if (!volume) return invalid_argument("make_renderer: no volume");
  if (auto s = check_attenuation_volume(*volume); !s.ok()) return s.with_context("make_renderer");
  if (name == "siddon") {
    return std::unique_ptr<DrrRenderer>(
        std::make_unique<RayCastRenderer>(RayRule::kSiddon, std::move(volume), options));
  }
  if (name == "trilinear") {
    if (!(options.trilinear_step_fraction > 0.01) || !(options.trilinear_step_fraction <= 4.0)) {
      return out_of_range("trilinear step fraction must be in (0.01, 4]");
    }
    return std::unique_ptr<DrrRenderer>(
        std::make_unique<RayCastRenderer>(RayRule::kTrilinear, std::move(volume), options));
  }
  std::string known;
  for (const auto& n : renderer_names()) known += (known.empty() ? "" : ", ") + n;
  return not_found("unknown renderer '" + std::string(name) + "' (known: " + known + ")");
}

}  // namespace lftrack::tracking

// The octree renderer (PAPERS.md, paper 3): each pixel's ray walks the compressed volume leaf by
// leaf, a homogeneous leaf taken in one step however many voxels it spans. At pivot 0 it equals
// the Siddon renderer up to rounding.

#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/octree_volume.hpp"
#include "pixel_rays.hpp"

namespace lftrack::tracking {
namespace {

class OctreeRenderer final : public DrrRenderer {
 public:
  OctreeRenderer(std::shared_ptr<const OctreeVolume> octree, ThreadPool* pool)
      : octree_(std::move(octree)), nodes_(*octree_), pool_(pool) {}

  std::string_view name() const override { return "octree"; }
  // The traversal layout (the ordered list is dropped once it is laid out).
  std::size_t bytes() const override { return nodes_.bytes(); }

  Status do_render(const Pose& T_room_from_ct, const XrayView& view, const PixelWindow& window,
                   ImageView<float> out, RenderExtras* extras) const override {
    const VolumeGeometry& g = octree_->geometry();
    render_pixel_rays(g, T_room_from_ct, view, window, out, extras, pool_,
                      [&](const Eigen::Vector3d& source, const Eigen::Vector3d& pixel) {
                        return octree_line_integral(nodes_, g, source, pixel);
                      });
    return {};
  }

 private:
  std::shared_ptr<const OctreeVolume> octree_;
  OctreeNodes nodes_;
  ThreadPool* pool_;
};

}  // namespace

Result<std::unique_ptr<DrrRenderer>> make_octree_renderer(std::shared_ptr<const MuVolume> volume,
                                                          const RendererOptions& options) {
  std::shared_ptr<const OctreeVolume> octree = options.octree;
  if (!octree) {
    if (!volume) return invalid_argument("make_renderer: octree needs a volume or a compressed one");
    auto built = OctreeVolume::build(*volume, options.octree_pivot);
    if (!built.ok()) return built.status();
    octree = std::make_shared<const OctreeVolume>(std::move(built).value());
  }
  return std::unique_ptr<DrrRenderer>(std::make_unique<OctreeRenderer>(std::move(octree), options.pool));
}

}  // namespace lftrack::tracking

// The octree renderer (PAPERS.md, paper 3): each pixel's ray walks the compressed volume leaf by
// leaf, a homogeneous leaf taken in one step however many voxels it spans. At pivot 0 it equals
// the Siddon renderer up to rounding.

#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/octree_volume.hpp"
#include "lftrack/tracking/thread_pool.hpp"

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
    const Eigen::Isometry3d T_grid_from_room = g.grid_from_ct() * T_room_from_ct.inverse();
    const Eigen::Vector3d source = T_grid_from_room * view.source_mm;
    const Eigen::Vector3d pixel00 = T_grid_from_room * view.pixel00_mm;
    const Eigen::Vector3d per_col = T_grid_from_room.linear() * view.col_axis * view.pitch_col_mm;
    const Eigen::Vector3d per_row = T_grid_from_room.linear() * view.row_axis * view.pitch_row_mm;
    auto rows_body = [&](int r_begin, int r_end) {
      for (int r = r_begin; r < r_end; ++r) {
        if (extras->valid.data)
          std::fill_n(extras->valid.row_ptr(r), window.cols, static_cast<unsigned char>(1));
        float* dst = out.row_ptr(r);
        const Eigen::Vector3d row_start = pixel00 + per_row * (window.row0 + r) + per_col * window.col0;
        for (int c = 0; c < window.cols; ++c)
          dst[c] = static_cast<float>(octree_line_integral(nodes_, g, source, row_start + per_col * c));
      }
    };
    if (pool_) {
      pool_->parallel_for(window.rows, 4, rows_body);
    } else {
      rows_body(0, window.rows);
    }
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

#include "fixtures.hpp"

#include <cmath>
#include <map>
#include <mutex>

namespace lftrack::test {

using Eigen::Vector3d;

std::shared_ptr<const tracking::MuVolume> fixture_volume() {
  static const std::shared_ptr<const tracking::MuVolume> volume = [] {
    auto v = std::make_shared<tracking::MuVolume>();
    v->geometry.size = {48, 40, 36};
    v->geometry.spacing_mm = {1.0, 1.2, 1.5};
    v->geometry.origin_mm = {-23.5, -23.4, -26.25};
    v->values.resize(static_cast<std::size_t>(v->geometry.voxel_count()));
    for (int k = 0; k < 36; ++k)
      for (int j = 0; j < 40; ++j)
        for (int i = 0; i < 48; ++i) {
          const Vector3d p = v->geometry.ct_from_index() * Vector3d(i, j, k);
          float mu = p.head<2>().norm() < 20 ? 0.02f : 0.0f;
          if (std::abs(p.x() - 5) < 6 && std::abs(p.y() + 3) < 4 && std::abs(p.z()) < 9) mu = 0.05f;
          mu += 0.004f * static_cast<float>(std::sin(0.7 * i) * std::cos(0.5 * j + 0.3 * k));
          v->at(i, j, k) = std::max(mu, 0.0f);
        }
    return std::shared_ptr<const tracking::MuVolume>(v);
  }();
  return volume;
}

tracking::MuVolume uniform_box(Eigen::Vector3i size, Eigen::Vector3d spacing_mm, float mu) {
  tracking::MuVolume v;
  v.geometry.size = size;
  v.geometry.spacing_mm = spacing_mm;
  v.values.assign(static_cast<std::size_t>(v.geometry.voxel_count()), mu);
  return v;
}

tracking::XrayView fixture_view() {
  return *tracking::XrayView::isocentric("A", Vector3d::Zero(), Vector3d(0.6, -0.8, 0.0), Vector3d(0, 0, 1),
                                         400, 600, 48, 40, 1.0);
}

tracking::LightFieldPlanInput fixture_plan() {
  tracking::LightFieldPlanInput in;
  in.view_room = fixture_view();
  in.roi_window = tracking::PixelWindow::full(in.view_room.rows, in.view_room.cols);
  in.envelope.translation_mm = 3;
  in.envelope.rotation_deg = 12;
  return in;
}

std::shared_ptr<const tracking::LightField> fixture_light_field(tracking::LightFieldStorage storage) {
  static std::mutex mutex;
  static std::map<tracking::LightFieldStorage, std::shared_ptr<const tracking::LightField>> cache;
  std::lock_guard lock(mutex);
  auto& slot = cache[storage];
  if (!slot) {
    tracking::LightFieldSpec spec;
    spec.resolution = {12, 12, 64, 64};
    spec.storage = storage;
    spec.vq_codebook_size = 256;
    auto field = tracking::LightField::build(*fixture_volume(), fixture_plan(), spec, nullptr);
    if (field.ok()) slot = *field;
  }
  return slot;
}

}  // namespace lftrack::test

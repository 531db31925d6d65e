// Markers rendered as spheres: the added line integral is mu times the chord, and the blob's
// centroid lies on the sphere centre's projection wherever the centre sits in a voxel (a voxel
// marker would sit at its slice's centre).

#include "lftrack/sim/sphere_markers.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "lftrack/tracking/volume.hpp"

namespace lftrack::sim {
namespace {

using Eigen::Vector3d;

// An empty (air) volume, so only the marker adds.
std::shared_ptr<const tracking::DrrRenderer> empty_siddon() {
  tracking::MuVolume air;
  air.geometry.size = {8, 8, 8};
  air.geometry.spacing_mm = {3, 3, 3};
  air.geometry.origin_mm = {-12, -12, -12};
  air.values.assign(8 * 8 * 8, 0.f);
  auto mu = std::make_shared<const tracking::MuVolume>(std::move(air));
  return std::shared_ptr<const tracking::DrrRenderer>(std::move(tracking::make_renderer("siddon", mu)).value());
}

tracking::XrayView side_view() {
  return *tracking::XrayView::isocentric("A", Vector3d::Zero(), Vector3d(1, 0, 0), Vector3d(0, 0, 1), 1000, 1500,
                                         64, 64, 0.2);
}

TEST(SphereMarkers, AddTheChordAndCentreOnTheProjection) {
  const tracking::XrayView view = side_view();
  for (const Vector3d& centre : {Vector3d(0, 0, 0), Vector3d(0, 0.4, 0.9), Vector3d(3, -0.7, 1.4)}) {
    auto renderer = with_sphere_markers(empty_siddon(), {{centre, 1.0, 0.7}}, 8);
    ASSERT_TRUE(renderer.ok()) << renderer.status().message();
    tracking::Image<float> out(64, 64, 0.f);
    ASSERT_TRUE((*renderer)->render(tracking::Pose::Identity(), view, tracking::PixelWindow::full(64, 64), out.view()).ok());
    double sum = 0, sc = 0, sr = 0, peak = 0;
    for (int r = 0; r < 64; ++r)
      for (int c = 0; c < 64; ++c) {
        const double v = out.at(r, c);
        sum += v;
        sc += v * c;
        sr += v * r;
        peak = std::max(peak, v);
      }
    const Eigen::Vector2d expected = *view.project(centre);
    // Centroid of a sphere's shadow: the projection of its centre (to within the cone's skew).
    EXPECT_NEAR(sc / sum, expected.x(), 0.03) << centre.transpose();
    EXPECT_NEAR(sr / sum, expected.y(), 0.03) << centre.transpose();
    EXPECT_NEAR(peak, 0.7 * 2.0, 0.05);  // mu x diameter through the centre
    // Total: mu x the sphere's volume, spread over magnified pixels.
    const double magnification = 1500.0 / (1000.0 - centre.x());  // the source is at +x
    const double pixel_area_at_sphere = std::pow(0.2 / magnification, 2);
    EXPECT_NEAR(sum * pixel_area_at_sphere, 0.7 * 4.0 / 3.0 * 3.14159265358979, 0.02);
  }
}

TEST(SphereMarkers, RefuseBadMarkers) {
  const Vector3d c = Vector3d::Zero();
  EXPECT_FALSE(with_sphere_markers(nullptr, {{c, 1, 0.7}}).ok());
  EXPECT_FALSE(with_sphere_markers(empty_siddon(), {{c, 1, 0.7}}, 0).ok());
  EXPECT_FALSE(with_sphere_markers(empty_siddon(), {{c, 1, 0.7}}, 9).ok());
  for (double bad : {0.0, -1.0, std::nan(""), HUGE_VAL, 1e12}) {
    EXPECT_FALSE(with_sphere_markers(empty_siddon(), {{c, bad, 0.7}}).ok()) << bad;
  }
  for (double bad : {-1.0, std::nan(""), HUGE_VAL, 1e12}) {
    EXPECT_FALSE(with_sphere_markers(empty_siddon(), {{c, 1, bad}}).ok()) << bad;
    if (!std::isfinite(bad)) {
      EXPECT_FALSE(with_sphere_markers(empty_siddon(), {{Vector3d(bad, 0, 0), 1, 0.7}}).ok());
    }
  }
  EXPECT_TRUE(with_sphere_markers(empty_siddon(), {}).ok());  // no markers: the inner renderer's images
}

}  // namespace
}  // namespace lftrack::sim

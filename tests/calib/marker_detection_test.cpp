#include "lftrack/calib/marker_detection.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace lftrack::calib {
namespace {

using tracking::Image;

// A textured background with a bright disc-like blob (a projected sphere, blurred) at (col, row).
Image<float> frame_with_marker(double col, double row, double radius_px, double peak, std::uint64_t seed) {
  Image<float> im(120, 140);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, 0.01);
  for (int r = 0; r < im.rows(); ++r)
    for (int c = 0; c < im.cols(); ++c) {
      const double bone = 1.5 + 0.5 * std::sin(0.05 * c) * std::cos(0.07 * r) + (c > 70 ? 0.4 : 0.0);
      const double d2 = (c - col) * (c - col) + (r - row) * (r - row);
      const double chord = d2 < radius_px * radius_px ? std::sqrt(radius_px * radius_px - d2) / radius_px : 0.0;
      im.at(r, c) = float(bone + peak * chord + noise(rng));
    }
  return im;
}

TEST(FindMarker, SubPixelPositionOfABlobOnABusyBackground) {
  for (const auto& [col, row] : std::vector<std::pair<double, double>>{{60.3, 50.7}, {82.55, 71.25}, {40.0, 30.5}}) {
    const Image<float> im = frame_with_marker(col, row, 3.5, 1.2, 7);
    MarkerSearch s;
    s.expected_px = {col + 12, row - 9};
    s.search_radius_px = 30;
    s.marker_radius_px = 3.5;
    auto found = find_marker(im.view(), {}, s);
    ASSERT_TRUE(found.ok()) << found.status().message();
    EXPECT_NEAR(found->pixel.x(), col, 0.15);
    EXPECT_NEAR(found->pixel.y(), row, 0.15);
    EXPECT_GT(found->contrast, 0.5);
  }
}

TEST(FindMarker, SaysSoWhenThereIsNone) {
  const Image<float> im = frame_with_marker(60, 50, 3.5, 0.0, 3);
  MarkerSearch s;
  s.expected_px = {60, 50};
  s.min_contrast = 0.2;
  auto found = find_marker(im.view(), {}, s);
  ASSERT_FALSE(found.ok());
  EXPECT_NE(found.status().message().find("no marker"), std::string::npos);
  // Entirely masked, or searched off the image.
  const Image<unsigned char> none(im.rows(), im.cols(), 0);
  EXPECT_FALSE(find_marker(im.view(), none.view(), s).ok());
  s.expected_px = {-500, -500};
  EXPECT_FALSE(find_marker(im.view(), {}, s).ok());
  s.expected_px = {NAN, 3};
  EXPECT_FALSE(find_marker(im.view(), {}, s).ok());
}

TEST(FindMarker, IgnoresAMaskedBrighterBlob) {
  Image<float> im = frame_with_marker(60, 50, 3.5, 1.0, 5);
  const Image<float> other = frame_with_marker(90, 50, 3.5, 5.0, 5);
  Image<unsigned char> mask(im.rows(), im.cols(), 1);
  for (int r = 0; r < im.rows(); ++r)
    for (int c = 80; c < im.cols(); ++c) {
      im.at(r, c) = other.at(r, c);
      mask.at(r, c) = 0;
    }
  MarkerSearch s;
  s.expected_px = {75, 50};
  s.search_radius_px = 30;
  auto found = find_marker(im.view(), mask.view(), s);
  ASSERT_TRUE(found.ok());
  EXPECT_NEAR(found->pixel.x(), 60, 0.3);
}

// What a clinical detector and anatomy put beside a marker: stuck pixels brighter than the marker,
// a bad column, and a bright ridge (a cortex seen edge-on) with more disc-minus-ring contrast than
// the marker's. None of them is taken for it.
TEST(FindMarker, IgnoresStuckPixelsBadLinesAndRidges) {
  Image<float> im = frame_with_marker(60.3, 50.7, 3.5, 0.8, 11);
  for (const auto& [r, c] : std::vector<std::pair<int, int>>{{40, 45}, {62, 70}, {30, 80}}) im.at(r, c) = 40.f;
  for (int r = 0; r < im.rows(); ++r) im.at(r, 75) += 3.f;  // a bad column
  for (int r = 0; r < im.rows(); ++r)                        // a ridge 3 pixels wide, brighter than the marker
    for (int c = 30; c <= 32; ++c) im.at(r, c) += 1.5f;
  MarkerSearch s;
  s.expected_px = {62, 48};
  s.search_radius_px = 35;
  s.marker_radius_px = 3.5;
  auto found = find_marker(im.view(), {}, s);
  ASSERT_TRUE(found.ok()) << found.status().message();
  EXPECT_NEAR(found->pixel.x(), 60.3, 0.3);
  EXPECT_NEAR(found->pixel.y(), 50.7, 0.3);
  // With the marker gone, the ridge and the defects are still not a marker.
  Image<float> no_marker = frame_with_marker(60.3, 50.7, 3.5, 0.0, 11);
  for (int r = 0; r < im.rows(); ++r) {
    no_marker.at(r, 75) += 3.f;
    for (int c = 30; c <= 32; ++c) no_marker.at(r, c) += 1.5f;
  }
  no_marker.at(40, 45) = 40.f;
  s.min_contrast = 0.2;
  auto none = find_marker(no_marker.view(), {}, s);
  ASSERT_FALSE(none.ok());
  const std::string why = none.status().message();  // the ridges are not blobs; what is left is faint
  EXPECT_TRUE(why.find("nothing blob-like") != std::string::npos || why.find("no marker") != std::string::npos)
      << why;
}

// A marker beside a bone edge (a step in its ring, two thirds of the marker's own contrast) and on
// a steep gradient is still a blob once the ring's plane is taken out, and a stuck pixel inside
// it does not move its centroid.
TEST(FindMarker, KeepsMarkersOnEdgesAndGradientsAndIgnoresAStuckPixelInside) {
  Image<float> im = frame_with_marker(64.4, 60.2, 3.5, 0.6, 13);  // the frame's 0.4 step is at column 70
  for (int r = 0; r < im.rows(); ++r)
    for (int c = 0; c < im.cols(); ++c) im.at(r, c) += 0.04f * float(r);  // 0.28 across the ring
  im.at(61, 65) = 50.f;
  MarkerSearch s;
  s.expected_px = {66, 58};
  s.search_radius_px = 12;
  s.marker_radius_px = 3.5;
  auto found = find_marker(im.view(), {}, s);
  ASSERT_TRUE(found.ok()) << found.status().message();
  EXPECT_NEAR(found->pixel.x(), 64.4, 0.3);
  EXPECT_NEAR(found->pixel.y(), 60.2, 0.3);
}

TEST(FindMarker, RefusesAbsurdSearches) {
  const Image<float> im = frame_with_marker(60, 50, 3.5, 1.0, 3);
  for (double bad : {std::nan(""), HUGE_VAL, -1.0}) {
    MarkerSearch s;
    s.expected_px = {60, 50};
    s.search_radius_px = bad;
    EXPECT_FALSE(find_marker(im.view(), {}, s).ok()) << bad;
    s.search_radius_px = 20;
    s.marker_radius_px = bad;
    EXPECT_FALSE(find_marker(im.view(), {}, s).ok()) << bad;
  }
  MarkerSearch huge;
  huge.expected_px = {60, 50};
  huge.marker_radius_px = 1e12;
  EXPECT_FALSE(find_marker(im.view(), {}, huge).ok());
  huge.marker_radius_px = 3.5;
  huge.search_radius_px = 1e12;  // searched over the whole image: still the marker
  auto found = find_marker(im.view(), {}, huge);
  ASSERT_TRUE(found.ok()) << found.status().message();
  EXPECT_NEAR(found->pixel.x(), 60, 0.3);
  huge.expected_px = {1e12, -1e12};
  EXPECT_FALSE(find_marker(im.view(), {}, huge).ok());
}

}  // namespace
}  // namespace lftrack::calib

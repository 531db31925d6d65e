// The source-image render's two AVX2 ways of reading the image (tracking/src/light_field_source_image_avx2.cpp,
// private to the renderer): runs of its rows, and its copy in row pairs. Both must give the
// portable render's image, and the same image as each other to the bit, at every tilt of the
// pixel rows across the image's rows; the share that chooses between them
// (chunks_across_image_rows) must follow the tilt.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "../../tracking/src/light_field_kernels.hpp"
#include "lftrack/tracking/image.hpp"

namespace lftrack::tracking {
namespace {

// A field of 16 x 16 x 256 x 256 samples, axis z, and the map of a rows x cols window whose rays
// from a source 1,000 mm before the (s, t) plane spread over `spread` samples of it, turned by
// `tilt` radians about the axis.
struct Case {
  LightFieldGeometry g;
  RayMap m;
};

Case make_case(double spread, double tilt, int rows, int cols) {
  Case k;
  k.g.size = {16, 16, 256, 256};
  for (int a = 0; a < 4; ++a) {
    k.m.base[a] = a < 2 ? 7.5f : 127.5f;
    k.m.gain[a] = a < 2 ? 0.5f : 1000.0f;
    k.m.limit[a] = float(k.g.size[a] - 1);
  }
  const double per_pixel = spread / (1000.0 * std::max(rows, cols));
  const Eigen::Vector3d row_dir(std::cos(tilt), std::sin(tilt), 0);
  const Eigen::Vector3d col_dir(-std::sin(tilt), std::cos(tilt), 0);
  k.m.d_row = row_dir * per_pixel;
  k.m.d_col = col_dir * per_pixel;
  k.m.d00 = Eigen::Vector3d(0, 0, 1) - k.m.d_row * (0.5 * (rows - 1)) - k.m.d_col * (0.5 * (cols - 1));
  return k;
}

// The image's values: smooth and different in every sample, so that a neighbour read from the
// wrong row or column shows.
void fill(SourceImage* image) {
  for (int i = 0; i < image->rows; ++i)
    for (int j = 0; j < image->cols; ++j)
      image->values[std::size_t(i) * std::size_t(image->cols) + std::size_t(j)] =
          float(1 + 0.37 * i + 0.011 * j + 0.2 * std::sin(0.3 * i) * std::cos(0.17 * j));
}

TEST(SourceImageRowsAcross, FollowsTheTiltOfThePixelRows) {
  // 180 samples over 256 pixels: 0.7 image rows a pixel at a right angle.
  const Case straight = make_case(180, 0, 256, 256);
  EXPECT_NEAR(chunks_across_image_rows(straight.g, straight.m, 256, 256), 0, 1e-9);
  double before = -1;
  for (double deg : {0.5, 1.0, 2.0, 4.0, 8.0}) {
    const Case k = make_case(180, deg * M_PI / 180, 256, 256);
    const double share = chunks_across_image_rows(k.g, k.m, 256, 256);
    // Seven steps of 180 / 256 samples, tilted: 7 x 180 / 256 x sin(tilt) rows.
    EXPECT_NEAR(share, std::min(1.0, 7 * 180.0 / 256 * std::sin(deg * M_PI / 180)), 1e-6) << deg;
    EXPECT_GT(share, before) << deg;
    before = share;
  }
  const Case steep = make_case(180, 1.2, 256, 256);
  EXPECT_EQ(chunks_across_image_rows(steep.g, steep.m, 256, 256), 1.0);
  Case broken = make_case(180, 0.1, 256, 256);
  broken.m.d00 = Eigen::Vector3d(NAN, 0, 1);
  EXPECT_EQ(chunks_across_image_rows(broken.g, broken.m, 256, 256), 1.0) << "a map without numbers reads pairs";
  EXPECT_EQ(chunks_across_image_rows(broken.g, broken.m, 256, 1), 0.0) << "a single column has no chunk across";
}

TEST(SourceImagePairs, HoldEachSampleAndTheOneBelowIt) {
  if (!light_field_avx2_available()) GTEST_SKIP() << "this CPU has no AVX2 + FMA";
  for (int cols : {2, 7, 8, 11, 24}) {
    SourceImage image;
    image.rows = 5;
    image.cols = cols;
    std::vector<float> values(std::size_t(image.rows * cols) + SourceImage::kTailFloats);
    std::vector<float> pairs(std::size_t(2 * (image.rows - 1) * cols), -1.0f);
    image.values = values.data();
    image.pairs = pairs.data();
    fill(&image);
    pair_source_image_avx2(image, 0, image.rows - 1);
    for (int i = 0; i + 1 < image.rows; ++i)
      for (int j = 0; j < cols; ++j) {
        const std::size_t at = 2 * (std::size_t(i) * std::size_t(cols) + std::size_t(j));
        ASSERT_EQ(pairs[at], values[std::size_t(i * cols + j)]) << cols << " " << i << " " << j;
        ASSERT_EQ(pairs[at + 1], values[std::size_t((i + 1) * cols + j)]) << cols << " " << i << " " << j;
      }
  }
}

TEST(SourceImagePairs, RunsAndPairsRenderThePortableImageAtEveryTilt) {
  if (!light_field_avx2_available()) GTEST_SKIP() << "this CPU has no AVX2 + FMA";
  const int rows = 61, cols = 77;  // a last partial chunk in every row
  int read_as_pairs = 0, read_as_runs = 0;
  for (int step = -40; step <= 40; ++step) {
    const double tilt = 0.5 * step * M_PI / 180;
    const Case k = make_case(60, tilt, rows, cols);
    SourceImage image;
    ASSERT_TRUE(source_image_box(k.g, k.m, rows, cols, 1L << 20, &image)) << step;
    const std::size_t samples = std::size_t(image.rows) * std::size_t(image.cols);
    std::vector<float> values(samples + SourceImage::kTailFloats), pairs(2 * samples);
    image.values = values.data();
    fill(&image);
    (chunks_across_image_rows(k.g, k.m, rows, cols) >= kPairsFromShareAcrossRows ? read_as_pairs : read_as_runs)++;

    Image<float> portable(rows, cols), runs(rows, cols), paired(rows, cols);
    Image<unsigned char> valid(rows, cols);
    ASSERT_EQ(render_source_image(image, k.g, k.m, portable.view(), valid.view(), cols, 0, rows), 0) << step;
    ASSERT_EQ(render_source_image_avx2(image, k.g, k.m, runs.view(), valid.view(), cols, 0, rows), 0) << step;
    image.pairs = pairs.data();
    pair_source_image_avx2(image, 0, image.rows - 1);
    ASSERT_EQ(render_source_image_avx2(image, k.g, k.m, paired.view(), valid.view(), cols, 0, rows), 0) << step;
    for (std::size_t p = 0; p < portable.pixels().size(); ++p) {
      const float want = portable.pixels()[p];
      ASSERT_NEAR(runs.pixels()[p], want, 1e-5f * (1 + std::abs(want))) << "runs, tilt step " << step << " pixel " << p;
      // The same blend of the same four samples: the same float.
      ASSERT_EQ(paired.pixels()[p], runs.pixels()[p]) << "pairs against runs, tilt step " << step << " pixel " << p;
    }
  }
  // The sweep spans both of the renderer's choices.
  EXPECT_GT(read_as_runs, 0);
  EXPECT_GT(read_as_pairs, 0);
}

}  // namespace
}  // namespace lftrack::tracking

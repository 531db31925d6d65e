// The source image's row pairs (tracking/src/light_field_source_image*.cpp, private to the
// renderer): blended straight from the field, they must hold the same floats as the image the
// portable render reads, each sample beside the one below it; and the AVX2 render from them must
// give the portable render's image at every tilt of the pixel rows across the image's rows, with
// rays inside and outside the field, rows of every length.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "../../tracking/src/light_field_kernels.hpp"
#include "lftrack/tracking/image.hpp"

namespace lftrack::tracking {
namespace {

// A field of 16 x 16 x 256 x 256 samples, axis z, and the map of a rows x cols window whose rays
// from a source 1,000 mm before the (s, t) plane spread over `spread` samples of it, turned by
// `tilt` radians about the axis.
struct SourceImageCase {
  LightFieldGeometry g;
  RayMap m;
};

SourceImageCase make_case(double spread, double tilt, int rows, int cols) {
  SourceImageCase k;
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
// wrong row or column shows; and its row pairs, made here from them.
void fill(SourceImage* image, std::vector<float>* values, std::vector<float>* pairs) {
  const std::size_t cols = std::size_t(image->cols);
  values->assign(std::size_t(image->rows) * cols, 0.0f);
  pairs->assign(2 * std::size_t(image->rows - 1) * cols, 0.0f);
  for (int i = 0; i < image->rows; ++i)
    for (int j = 0; j < image->cols; ++j)
      (*values)[std::size_t(i) * cols + std::size_t(j)] =
          float(1 + 0.37 * i + 0.011 * j + 0.2 * std::sin(0.3 * i) * std::cos(0.17 * j));
  for (std::size_t p = 0; p + cols < values->size(); ++p) {
    (*pairs)[2 * p] = (*values)[p];
    (*pairs)[2 * p + 1] = (*values)[p + cols];
  }
  image->values = values->data();
  image->pairs = pairs->data();
}

// Renders the window both ways and compares them pixel by pixel: values to float rounding, the
// mask and the masked count exactly. `label` names the case in failures.
void expect_same_render(const SourceImage& image, const SourceImageCase& k, int rows, int cols, bool with_mask,
                        const std::string& label) {
  Image<float> portable(rows, cols), vectorised(rows, cols);
  Image<unsigned char> portable_ok(rows, cols), vectorised_ok(rows, cols);
  ImageView<unsigned char> none;
  const int masked = render_source_image(image, k.g, k.m, portable.view(), portable_ok.view(), cols, 0, rows);
  // In two bands, as the renderer's threads render them.
  const int split = rows / 3;
  const int masked_avx2 =
      render_source_image_avx2(image, k.g, k.m, vectorised.view(), with_mask ? vectorised_ok.view() : none, cols, 0,
                               split) +
      render_source_image_avx2(image, k.g, k.m, vectorised.view(), with_mask ? vectorised_ok.view() : none, cols,
                               split, rows);
  ASSERT_EQ(masked_avx2, masked) << label;
  for (std::size_t p = 0; p < portable.pixels().size(); ++p) {
    const float want = portable.pixels()[p];
    ASSERT_NEAR(vectorised.pixels()[p], want, 1e-5f * (1 + std::abs(want))) << label << ", pixel " << p;
    if (with_mask) {
      ASSERT_EQ(vectorised_ok.pixels()[p], portable_ok.pixels()[p]) << label << ", pixel " << p;
    }
  }
}

TEST(SourceImagePairs, RenderThePortableImageAtEveryTilt) {
  if (!light_field_avx2_available()) GTEST_SKIP() << "this CPU has no AVX2 + FMA";
  // Rows of 77 (four steps of sixteen, then a whole chunk of eight and a partial one of five
  // through the chunk-at-a-time path), 16 (one step and nothing left) and 8 (no step: the
  // chunk-at-a-time path alone).
  const int shapes[][2] = {{61, 77}, {23, 16}, {9, 8}};
  for (const auto& shape : shapes) {
    const int rows = shape[0], cols = shape[1];
    for (int step = -40; step <= 40; ++step) {
      const double tilt = 0.5 * step * M_PI / 180;
      const SourceImageCase k = make_case(60, tilt, rows, cols);
      SourceImage image;
      ASSERT_TRUE(source_image_box(k.g, k.m, rows, cols, 1L << 20, &image)) << step;
      std::vector<float> values, pairs;
      fill(&image, &values, &pairs);
      const std::string label = std::to_string(rows) + " x " + std::to_string(cols) + ", tilt step " +
                                std::to_string(step);
      expect_same_render(image, k, rows, cols, step % 2 == 0, label);
      if (::testing::Test::HasFatalFailure()) return;
    }
  }
}

TEST(SourceImagePairs, RenderThePortableImageWhereRaysLeaveTheField) {
  if (!light_field_avx2_available()) GTEST_SKIP() << "this CPU has no AVX2 + FMA";
  // 400 samples over a field of 256: the window's outer pixels miss it and are masked, rows
  // partly inside take the per-ray path, and the box is clamped to the field.
  const int rows = 70, cols = 90;
  for (double deg : {0.0, 3.0, 17.0}) {
    const SourceImageCase k = make_case(400, deg * M_PI / 180, rows, cols);
    SourceImage image;
    ASSERT_TRUE(source_image_box(k.g, k.m, rows, cols, 1L << 20, &image)) << deg;
    ASSERT_EQ(image.rows, 256) << "the box is clamped to the field";
    std::vector<float> values, pairs;
    fill(&image, &values, &pairs);
    Image<float> out(rows, cols);
    Image<unsigned char> ok(rows, cols);
    const int masked = render_source_image(image, k.g, k.m, out.view(), ok.view(), cols, 0, rows);
    EXPECT_GT(masked, 0) << deg;
    EXPECT_LT(masked, rows * cols / 2) << deg;
    expect_same_render(image, k, rows, cols, true, "turn " + std::to_string(deg));
  }
}

// A small field whose samples differ everywhere, and a map whose v along the image crosses two v
// cells and the field's v = 0 edge along a row of more than two blocks of columns; u stays inside
// one u cell (u_per_s 0.01) or crosses the field's both u edges down the image's rows (1.0).
struct BlendCase {
  LightFieldGeometry g;
  RayMap m;
  std::vector<float> samples;
  std::vector<std::uint16_t> codes;
};

BlendCase make_blend_case(float u_per_s = 0.01f) {
  BlendCase k;
  k.g.size = {4, 5, 14, 600};
  const float base[4] = {1.3f, 0.9f, 7.0f, 300.0f}, gain[4] = {u_per_s, 0.005f, 1.0f, 1.0f};
  for (int a = 0; a < 4; ++a) {
    k.m.base[a] = base[a];
    k.m.gain[a] = gain[a];
    k.m.limit[a] = float(k.g.size[a] - 1);
  }
  const std::size_t n = std::size_t(k.g.size[0]) * k.g.size[1] * k.g.size[2] * k.g.size[3];
  k.samples.resize(n);
  k.codes.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    k.codes[i] = std::uint16_t((i * 2654435761u) >> 17);
    k.samples[i] = float(k.codes[i]) * 1e-3f;
  }
  return k;
}

TEST(SourceImagePairs, BlendedFromTheFieldHoldEachSampleAndTheOneBelowIt) {
  for (int cols : {2, 7, 255, 256, 257, 520}) {
    for (int variant = 0; variant < 4; ++variant) {
      const bool fixed16 = variant % 2 == 1;
      const BlendCase k = make_blend_case(variant < 2 ? 0.01f : 1.0f);
      SourceImage image;
      image.s0 = 2;
      image.t0 = 3;
      image.rows = 9;
      image.cols = cols;
      std::vector<float> values(std::size_t(image.rows * cols), -1.0f);
      std::vector<float> pairs(std::size_t(2 * (image.rows - 1) * cols), -1.0f);
      image.values = values.data();
      image.pairs = pairs.data();
      // The image in one piece; its pairs in two, as two threads blend them.
      if (fixed16) {
        blend_source_image_fixed16(k.codes.data(), 1e-3f, k.g, k.m, image, 0, image.rows);
        blend_source_image_pairs_fixed16(k.codes.data(), 1e-3f, k.g, k.m, image, 0, 3);
        blend_source_image_pairs_fixed16(k.codes.data(), 1e-3f, k.g, k.m, image, 3, image.rows - 1);
      } else {
        blend_source_image_float(k.samples.data(), k.g, k.m, image, 0, image.rows);
        blend_source_image_pairs_float(k.samples.data(), k.g, k.m, image, 0, 3);
        blend_source_image_pairs_float(k.samples.data(), k.g, k.m, image, 3, image.rows - 1);
      }
      for (int i = 0; i + 1 < image.rows; ++i)
        for (int j = 0; j < cols; ++j) {
          const std::size_t at = 2 * (std::size_t(i) * std::size_t(cols) + std::size_t(j));
          const float top = values[std::size_t(i * cols + j)], bottom = values[std::size_t((i + 1) * cols + j)];
          ASSERT_GE(top, 0.0f) << "every sample blended: " << cols << " " << i << " " << j;
          ASSERT_EQ(pairs[at], top) << cols << " " << fixed16 << " " << i << " " << j;
          ASSERT_EQ(pairs[at + 1], bottom) << cols << " " << fixed16 << " " << i << " " << j;
        }
    }
  }
}

TEST(SourceImagePairs, BlendTheFieldAtEachSamplesOwnUv) {
  // The image against the bilinear (u, v) blend written out here: u = base_u + (s - base_s)
  // gain_u / gain_s, likewise v with t, clamped to the field.
  for (double u_per_s : {0.01, 1.0}) {
    const BlendCase k = make_blend_case(float(u_per_s));
    SourceImage image;
    image.s0 = 2;
    image.t0 = 3;
    image.rows = 9;  // u from -3.7 to 4.3 at 1.0 a row: both of the field's u edges
    image.cols = 520;
    std::vector<float> values(std::size_t(image.rows * image.cols));
    image.values = values.data();
    blend_source_image_float(k.samples.data(), k.g, k.m, image, 0, image.rows);
    const auto& size = k.g.size;
    const auto sample = [&](int iu, int iv, int s, int t) {
      return double(k.samples[((std::size_t(iu) * size[1] + std::size_t(iv)) * size[2] + std::size_t(s)) * size[3] +
                              std::size_t(t)]);
    };
    for (int i = 0; i < image.rows; ++i)
      for (int j = 0; j < image.cols; ++j) {
        const int s = image.s0 + i, t = image.t0 + j;
        const double u = std::clamp(1.3 + (s - 7.0) * u_per_s, 0.0, size[0] - 1.0);
        const double v = std::clamp(0.9 + (t - 300.0) * 0.005, 0.0, size[1] - 1.0);
        const int iu = std::min(int(u), size[0] - 2), iv = std::min(int(v), size[1] - 2);
        const double wu = u - iu, wv = v - iv;
        const double low = sample(iu, iv, s, t) * (1 - wv) + sample(iu, iv + 1, s, t) * wv;
        const double high = sample(iu + 1, iv, s, t) * (1 - wv) + sample(iu + 1, iv + 1, s, t) * wv;
        const double want = low * (1 - wu) + high * wu;
        ASSERT_NEAR(values[std::size_t(i * image.cols + j)], want, 1e-4 * (1 + std::abs(want)))
            << u_per_s << " " << i << " " << j;
      }
  }
}

// A map whose (u, v) slope along the image overflows a float (the source all but on the (s, t)
// plane) gets no source image: the blend would step (u, v) to NaN and read from NaN cells.
TEST(SourceImagePairs, NoImageWhereTheUvSlopeOverflowsAFloat) {
  SourceImageCase k = make_case(60, 0.1, 40, 40);
  SourceImage image;
  ASSERT_TRUE(source_image_box(k.g, k.m, 40, 40, 1L << 20, &image));
  for (int a : {0, 1}) {
    SourceImageCase steep = k;
    steep.m.gain[a] = 1e30f;
    steep.m.gain[a + 2] = 1e-20f;
    EXPECT_FALSE(source_image_box(steep.g, steep.m, 40, 40, 1L << 20, &image)) << a;
  }
}

}  // namespace
}  // namespace lftrack::tracking

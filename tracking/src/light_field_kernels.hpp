#pragma once
// Private to the light-field renderer: the per-render ray map and the vectorised kernel.

#include <Eigen/Core>
#include <cstdint>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/light_field.hpp"

namespace lftrack::tracking {

// Per-render constants: continuous sample index f_a = base_a + gain_a * q (q = q1 for u, s and
// q2 for v, t), and the affine ray direction.
struct RayMap {
  float base[4], gain[4];
  float limit[4];                     // size - 1 per axis
  Eigen::Vector3d d00, d_row, d_col;  // direction of pixel (row0, col0) and its increments, CT frame
};

// True if every pixel ray of row r (columns 0 .. cols - 1 from the map's pixel (0, 0)) runs
// towards the planes (d.n > 0) and reaches them inside the field on all four axes, with a margin
// far beyond the kernels' float rounding: the kernels' per-pixel test then passes for each of
// them, and a kernel may skip it. Along a row a coordinate q = (e0 + e1 c) / (n0 + n1 c) is
// monotonic where the denominator keeps its sign, so the row's two end rays bound it.
bool row_inside_field(const LightFieldGeometry& g, const RayMap& m, int r, int cols);
// True if row_inside_field holds for every row from r_first to r_last (inclusive), judged from
// the block's four corner rays: one test instead of one a row. A false says nothing of single
// rows (the bounds are the block's): test those one by one.
bool rows_inside_field(const LightFieldGeometry& g, const RayMap& m, int r_first, int r_last, int cols);

// True if this CPU runs the AVX2 kernel (AVX2 and FMA).
bool light_field_avx2_available();

// One render's source image (light_field_source_image.cpp): the field blended bilinearly in
// (u, v) once per (s, t) sample of a box, at the (u, v) where the ray from the moved source
// through that (s, t) sample crosses the source plane. The source plane and the (s, t) plane are
// parallel, so that (u, v) is affine in (s, t): u depends on s only and v on t only, and the
// (u, v) cell of neighbouring samples is nearly always the same. A pixel then needs only its
// four (s, t) neighbours in the image instead of sixteen samples of the field. Against the
// quadrilinear blend at the pixel's own ray the difference is the change of the (u, v) weights
// between the pixel's ray and its (s, t) neighbours' rays: 0 where the source sits on the source
// plane (the nominal pose), and a few thousandths of the difference between neighbouring (u, v)
// samples at the envelope's edge.
struct SourceImage {
  // The image as the portable render reads it: rows x cols, row-major, sample (s0 + i, t0 + j)
  // at i * cols + j.
  float* values = nullptr;
  // The image as the AVX2 render reads it, in row pairs: (rows - 1) x cols pairs, row-major,
  // pair (i, j) = the samples (i, j) and (i + 1, j) at 2 (i cols + j). A pixel's four (s, t)
  // neighbours are then the 16 bytes from its cell's pair, one load a pixel wherever the pose
  // lays the pixel rows across the image's rows.
  float* pairs = nullptr;
  int s0 = 0, t0 = 0, rows = 0, cols = 0;
};

// The box of (s, t) samples that the rays of a window's pixels (rows x cols from the map's
// pixel (0, 0)) can read, with a sample's margin for rounding, clamped to the field; false where
// a source image does not suit: a corner ray runs away from the planes, the rays miss the field
// altogether (the per-ray kernels mask them), or the box holds more than max_samples samples.
bool source_image_box(const LightFieldGeometry& g, const RayMap& m, int rows, int cols, long max_samples,
                      SourceImage* box);
// The largest box the renderer blends (rows x cols): the AVX2 render's pair offsets, 2 (i cols +
// j), fit 31 bits. A window that would need more renders per ray.
inline constexpr long kMaxSourceImageSamples = (1L << 30) - 1;
// Fills rows [i_begin, i_end) of the image's values (rows x cols floats).
void blend_source_image_float(const float* samples, const LightFieldGeometry& g, const RayMap& m,
                              const SourceImage& image, int i_begin, int i_end);
void blend_source_image_fixed16(const std::uint16_t* codes, float scale, const LightFieldGeometry& g, const RayMap& m,
                                const SourceImage& image, int i_begin, int i_end);
// Fills pair rows [i_begin, i_end) (at most rows - 1) of the image's pairs (2 (rows - 1) cols
// floats), blending image rows i_begin .. i_end once each: the same floats as the values above,
// without the image itself.
void blend_source_image_pairs_float(const float* samples, const LightFieldGeometry& g, const RayMap& m,
                                    const SourceImage& image, int i_begin, int i_end);
void blend_source_image_pairs_fixed16(const std::uint16_t* codes, float scale, const LightFieldGeometry& g,
                                      const RayMap& m, const SourceImage& image, int i_begin, int i_end);
// Renders rows [r_begin, r_end) of the window from the image's values, bilinearly in (s, t):
// the per-ray kernels' mask (each pixel's own ray tested against the field) and pixel layout.
// Returns the number of masked pixels.
int render_source_image(const SourceImage& image, const LightFieldGeometry& g, const RayMap& m,
                        ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin, int r_end);
// The same from the image's pairs, on AVX2 (light_field_avx2_available(); rows x cols at most
// kMaxSourceImageSamples): equal to the portable render up to float rounding.
int render_source_image_avx2(const SourceImage& image, const LightFieldGeometry& g, const RayMap& m,
                             ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin, int r_end);

// Float storage, 8 pixels at a time in AVX2 lanes, reading runs of samples where eight pixels
// share their (u, v) cells (with `runs`; otherwise, and where they do not, gathering them); the
// same results as the scalar kernel up to float rounding. Needs light_field_avx2_available() and
// fewer than 2^31 samples. Returns the number of masked pixels.
int render_float_avx2(const float* samples, const LightFieldGeometry& g, const RayMap& m,
                      ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin, int r_end,
                      bool runs = true);
// The same for 16-bit storage (value = code * scale).
int render_fixed16_avx2(const std::uint16_t* codes, float scale, const LightFieldGeometry& g, const RayMap& m,
                        ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin,
                        int r_end, bool runs = true);

// True if this CPU runs the AVX-512 kernels (AVX-512F and BW).
bool light_field_avx512_available();

// The same on AVX-512: sixteen pixels at a time, and without gathers wherever sixteen pixels
// read runs of one (u, v) cell (light_field_kernel_avx512.cpp). Needs
// light_field_avx512_available() and fewer than 2^31 samples.
int render_float_avx512(const float* samples, const LightFieldGeometry& g, const RayMap& m,
                        ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin,
                        int r_end);
int render_fixed16_avx512(const std::uint16_t* codes, float scale, const LightFieldGeometry& g,
                          const RayMap& m, ImageView<float> out, ImageView<unsigned char> valid, int cols,
                          int r_begin, int r_end);
// VQ storage, gathers only. The codes must follow the codebook in one buffer (as LightField
// lays them out): a code is read as the 4-byte word ending at it.
int render_vq_avx512(const float* codebook, const std::uint16_t* codes, const LightFieldGeometry& g,
                     const RayMap& m, ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin,
                     int r_end);

}  // namespace lftrack::tracking

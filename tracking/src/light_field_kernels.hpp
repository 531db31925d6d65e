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

// True if this CPU runs the AVX2 kernel (AVX2 and FMA).
bool light_field_avx2_available();

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

// The AVX2 source-image render (light_field_kernels.hpp): eight pixels of a row per chunk, each
// bilinear in (s, t) in the render's source image, read from its row pairs (SourceImage::pairs):
// a pixel's four neighbours are one 16-byte load, put in lanes by a 4 x 4 transpose in each
// 128-bit half, the same work in every chunk however the pose turns the pixel rows across the
// image's rows.
//
// Rows whose rays are all inside the field take two chunks a step, software-pipelined: the next
// step's cells and pair offsets are computed before this step's pairs are read, so that the
// chains of dependent steps of four chunks overlap (BENCHMARKS.md, "Pairs only, two chunks a
// step"). Other rows, and a row's last columns, are rendered a chunk at a time with each ray
// tested against the field, as the per-ray kernels do.
//
// The results equal the portable render's up to float rounding (fused multiply-adds).

#include <cstddef>
#include <cstdint>
#include <cstring>

#include "light_field_avx2_lanes.hpp"
#include "light_field_kernels.hpp"

namespace lftrack::tracking {

#if defined(__x86_64__) && defined(__GNUC__)

namespace {

// A row whose rays are all inside (row_inside_field) in the image's coordinates: s - image.s0 =
// (ns0 + ns1 c) / (dn0 + dn1 c) at column c, likewise t - image.t0 with nt. The same as the map's
// s = base + gain q1, q1 = d.e1 / d.n, with base, gain and the image's origin folded into the
// numerator once a row: two multiply-adds and four integer additions fewer a chunk, and no
// field test.
struct ImageRow {
  __m256 dn0, dn1, ns0, ns1, nt0, nt1;
};

LFTRACK_AVX2 inline ImageRow image_row(const LightFieldGeometry& g, const RayMap& m, const SourceImage& image, int r) {
  const Eigen::Vector3d d_row = m.d00 + m.d_row * r;
  const double dn0 = d_row.dot(g.axis), dn1 = m.d_col.dot(g.axis);
  const double s_off = double(m.base[2]) - image.s0, t_off = double(m.base[3]) - image.t0;
  const double ns0 = s_off * dn0 + double(m.gain[2]) * d_row.dot(g.e1);
  const double ns1 = s_off * dn1 + double(m.gain[2]) * m.d_col.dot(g.e1);
  const double nt0 = t_off * dn0 + double(m.gain[3]) * d_row.dot(g.e2);
  const double nt1 = t_off * dn1 + double(m.gain[3]) * m.d_col.dot(g.e2);
  return {_mm256_set1_ps(float(dn0)), _mm256_set1_ps(float(dn1)), _mm256_set1_ps(float(ns0)),
          _mm256_set1_ps(float(ns1)), _mm256_set1_ps(float(nt0)), _mm256_set1_ps(float(nt1))};
}

// The render's image in row pairs, in lanes: the pairs, its columns (pairs a row) and its
// cells' bounds (the image's rows and columns - 2).
struct PairImage {
  const float* pairs;
  __m256i cols, top_s, top_t;
};

// A chunk's weights in its cells.
struct ChunkWeights {
  __m256 ws, wt;
};

// A chunk's cells (is, it), clamped into the image as the per-ray kernels clamp them, as the
// float offsets of their pairs, 2 (is cols + it) < 2^31 (kMaxSourceImageSamples), stored to
// `at` (eight lanes); returns the weights, measured from the clamped cells.
LFTRACK_AVX2 inline ChunkWeights plan_chunk(const PairImage& image, __m256i is, __m256i it, __m256 cs, __m256 ct,
                                            std::int32_t* at) {
  is = _mm256_max_epi32(_mm256_min_epi32(is, image.top_s), _mm256_setzero_si256());
  it = _mm256_max_epi32(_mm256_min_epi32(it, image.top_t), _mm256_setzero_si256());
  _mm256_store_si256(reinterpret_cast<__m256i*>(at),
                     _mm256_slli_epi32(_mm256_add_epi32(_mm256_mullo_epi32(is, image.cols), it), 1));
  return {_mm256_sub_ps(cs, _mm256_cvtepi32_ps(is)), _mm256_sub_ps(ct, _mm256_cvtepi32_ps(it))};
}

// The same for the chunk of a row whose rays are all inside, from its columns cf.
LFTRACK_AVX2 inline ChunkWeights plan_inside_chunk(const PairImage& image, const ImageRow& row, __m256 cf,
                                                   std::int32_t* at) {
  const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), _mm256_fmadd_ps(row.dn1, cf, row.dn0));
  const __m256 cs = _mm256_mul_ps(_mm256_fmadd_ps(row.ns1, cf, row.ns0), inv);
  const __m256 ct = _mm256_mul_ps(_mm256_fmadd_ps(row.nt1, cf, row.nt0), inv);
  // An inside pixel's cell lies in the image (source_image_box), so the clamps only act on
  // rounding at the image's last row or column.
  return plan_chunk(image, _mm256_cvttps_epi32(cs), _mm256_cvttps_epi32(ct), cs, ct, at);
}

// A planned chunk's value: the pairs at its eight offsets `at`, turned into four registers of
// eight pixels each (the neighbours I(is, it), I(is, it + 1), I(is + 1, it), I(is + 1, it + 1)),
// blended.
LFTRACK_AVX2 inline __m256 blend_chunk(const float* pairs, const std::int32_t* at, const ChunkWeights& w) {
  const auto quad = [pairs](std::int32_t offset) LFTRACK_AVX2 { return _mm_loadu_ps(pairs + offset); };
  // Pixel k in the low half, pixel k + 4 in the high half; each half (a, c, b, d): top left,
  // bottom left, top right, bottom right.
  const __m256 p04 = _mm256_insertf128_ps(_mm256_castps128_ps256(quad(at[0])), quad(at[4]), 1);
  const __m256 p15 = _mm256_insertf128_ps(_mm256_castps128_ps256(quad(at[1])), quad(at[5]), 1);
  const __m256 p26 = _mm256_insertf128_ps(_mm256_castps128_ps256(quad(at[2])), quad(at[6]), 1);
  const __m256 p37 = _mm256_insertf128_ps(_mm256_castps128_ps256(quad(at[3])), quad(at[7]), 1);
  const __m256 ac01 = _mm256_unpacklo_ps(p04, p15), bd01 = _mm256_unpackhi_ps(p04, p15);  // a0 a1 c0 c1 | a4 a5 c4 c5
  const __m256 ac23 = _mm256_unpacklo_ps(p26, p37), bd23 = _mm256_unpackhi_ps(p26, p37);
  const __m256 a = _mm256_shuffle_ps(ac01, ac23, _MM_SHUFFLE(1, 0, 1, 0));  // a0 a1 a2 a3 | a4 a5 a6 a7
  const __m256 c = _mm256_shuffle_ps(ac01, ac23, _MM_SHUFFLE(3, 2, 3, 2));
  const __m256 b = _mm256_shuffle_ps(bd01, bd23, _MM_SHUFFLE(1, 0, 1, 0));
  const __m256 d = _mm256_shuffle_ps(bd01, bd23, _MM_SHUFFLE(3, 2, 3, 2));
  return blend_st(a, b, c, d, w.ws, w.wt);
}

// Renders a row whose rays are all inside, two chunks (sixteen pixels) a step, software-
// pipelined by one step; returns the first column left (cols rounded down to sixteen). The
// offsets go through memory (one store, eight loads a chunk) rather than vpextrd, which is two
// micro-ops on Zen 3; the empty asm tells the compiler that each step's loads read the store
// before it.
LFTRACK_AVX2 inline int render_inside_row(const PairImage& image, const ImageRow& row, int cols, float* dst,
                                          unsigned char* ok_row) {
  const int whole = cols - cols % 16;
  if (whole == 0) return 0;
  const float* const pairs = image.pairs;  // a copy: the stores below may alias `image` as far as GCC knows
  const std::uint64_t all_inside = kMaskBytes.bytes[0xff];
  const __m256 eight = _mm256_set1_ps(8.0f), sixteen = _mm256_set1_ps(16.0f);
  alignas(32) std::int32_t at[2][16];  // the offsets of this step's chunks and the next step's
  __m256 cf = _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7);
  ChunkWeights next0 = plan_inside_chunk(image, row, cf, at[0]);
  ChunkWeights next1 = plan_inside_chunk(image, row, _mm256_add_ps(cf, eight), at[0] + 8);
  for (int c = 0, k = 0; c < whole; c += 16, k ^= 1) {
    const ChunkWeights now0 = next0, now1 = next1;
    cf = _mm256_add_ps(cf, sixteen);
    if (c + 16 < whole) {
      next0 = plan_inside_chunk(image, row, cf, at[k ^ 1]);
      next1 = plan_inside_chunk(image, row, _mm256_add_ps(cf, eight), at[k ^ 1] + 8);
    }
    __asm__("" : "+m"(at));
    _mm256_storeu_ps(dst + c, blend_chunk(pairs, at[k], now0));
    _mm256_storeu_ps(dst + c + 8, blend_chunk(pairs, at[k] + 8, now1));
    if (ok_row) {
      std::memcpy(ok_row + c, &all_inside, 8);
      std::memcpy(ok_row + c + 8, &all_inside, 8);
    }
  }
  return whole;
}

}  // namespace

// The source-image path (light_field_kernels.hpp): rows whose rays are all inside in the image's
// own coordinates (render_inside_row), the others (and a row's last columns) as the per-ray
// kernels do, each ray tested against the field.
LFTRACK_AVX2 int render_source_image_avx2(const SourceImage& image, const LightFieldGeometry& g, const RayMap& m,
                                          ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin,
                                          int r_end) {
  const PairImage pairs{image.pairs, _mm256_set1_epi32(image.cols), _mm256_set1_epi32(image.rows - 2),
                        _mm256_set1_epi32(image.cols - 2)};
  const __m256i s0 = _mm256_set1_epi32(image.s0), t0 = _mm256_set1_epi32(image.t0);
  const MapLanes map(m);
  const bool all_inside = rows_inside_field(g, m, r_begin, r_end - 1, cols);  // else one test a row
  int masked = 0;
  for (int r = r_begin; r < r_end; ++r) {
    float* dst = out.row_ptr(r);
    unsigned char* ok_row = valid.data ? valid.row_ptr(r) : nullptr;
    const bool inside = all_inside || row_inside_field(g, m, r, cols);
    const int c_first = inside ? render_inside_row(pairs, image_row(g, m, image, r), cols, dst, ok_row) : 0;
    if (c_first == cols) continue;
    const RowRays row = row_rays(g, m, r, inside);
    for (int c = c_first; c < cols; c += 8) {
      const ChunkRays k = chunk_rays(row, map, c, cols);
      // Cells in the image (inside pixels' lie in it; the others' values are masked).
      alignas(32) std::int32_t at[8];
      const ChunkWeights w = plan_chunk(pairs, _mm256_sub_epi32(_mm256_cvttps_epi32(k.cs), s0),
                                        _mm256_sub_epi32(_mm256_cvttps_epi32(k.ct), t0),
                                        _mm256_sub_ps(k.cs, _mm256_cvtepi32_ps(s0)),
                                        _mm256_sub_ps(k.ct, _mm256_cvtepi32_ps(t0)), at);
      __asm__("" : "+m"(at));
      masked += k.lanes - __builtin_popcount(static_cast<unsigned>(k.inside_bits));
      store_chunk(k, blend_chunk(image.pairs, at, w), dst + c, ok_row ? ok_row + c : nullptr);
    }
  }
  return masked;
}

#else

int render_source_image_avx2(const SourceImage&, const LightFieldGeometry&, const RayMap&, ImageView<float>,
                             ImageView<unsigned char>, int, int, int) {
  return 0;
}

#endif

}  // namespace lftrack::tracking

// The AVX2 source-image render (light_field_kernels.hpp): eight pixels of a row per iteration,
// each bilinear in (s, t) in the render's source image, with the lanes and blends of the per-ray
// kernel (light_field_avx2_lanes.hpp).
//
// The render reads the image as the per-ray kernel reads the field, in runs of its
// rows, where a chunk's pixels lie in one or two image rows. A pose turned about the view's axis
// tilts the pixel rows across the image's rows; then more chunks straddle two rows, take the
// slower runs or gathers and mispredict the branch between them. From a share of such chunks on
// (kPairsFromShareAcrossRows) the render reads a copy of the image in row pairs
// (SourceImage::pairs) instead: a pixel's four neighbours are one 16-byte load, the same work
// in every chunk however the rows tilt (BENCHMARKS.md, "Row pairs").
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

// An image cell index clamped into 0 .. top (top: the image's rows or columns - 2).
LFTRACK_AVX2 inline __m256i clamp_cell(__m256i index, __m256i top) {
  return _mm256_max_epi32(_mm256_min_epi32(index, top), _mm256_setzero_si256());
}

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

// The common case first, in fewer steps: every lane inside, in one image row and within 6
// samples (nearly nine chunks in ten of a 256 x 256 render). s and t share a lane as two 16-bit
// halves, st = is << 16 | it (the caller keeps the image at most 32,768 samples a side, so is and
// it lie in 0 .. 32,766), so one pair of permutations finds both starts and one saturating
// subtraction tests both offsets against (0, 6) (set1_epi32(6): 0 in the s half, 6 in the t
// half): an offset below 0 wraps to at least 32,770 and fails.
struct OneRowRun {
  __m256i dt;        // each lane's offsets from the run's start, ds << 16 | dt: its t offset where `holds`
  std::size_t run0;  // the run's first sample
  bool holds;
};

LFTRACK_AVX2 inline OneRowRun one_row_narrow_run(__m256i st, std::size_t image_cols) {
  const __m256i lo = _mm256_min_epu16(_mm256_permutevar8x32_epi32(st, _mm256_setzero_si256()),
                                      _mm256_permutevar8x32_epi32(st, _mm256_set1_epi32(7)));
  const __m256i d = _mm256_sub_epi16(st, lo);
  const __m256i over = _mm256_subs_epu16(d, _mm256_set1_epi32(6));  // nonzero where ds > 0 or dt > 6 (or < 0)
  const unsigned start = unsigned(first_lane(lo));
  return {d, std::size_t(start >> 16) * image_cols + std::size_t(start & 0xffff),
          bool(_mm256_testz_si256(over, over))};
}

// Its value: two rows of one run each, each sample of a pair one permutation.
LFTRACK_AVX2 inline __m256 sample_one_row_narrow(const FloatSamples& f, std::size_t image_cols, const OneRowRun& run,
                                                 __m256 ws, __m256 wt) {
  RunLanes l{};  // a narrow run over one row reads only dt and dt_next
  l.dt = run.dt;
  l.dt_next = _mm256_add_epi32(run.dt, _mm256_set1_epi32(1));
  return run_cell<FloatSamples, false>(f, run.run0, image_cols, 0, l, ws, wt);
}

// A source-image chunk's value from its cells (is, it) in the image and weights: its pixels' (s, t)
// neighbours read as runs where all eight lie in at most three rows of 15 samples (and every
// lane is inside, inside_bits 0xff), gathered otherwise.
LFTRACK_AVX2 inline __m256 sample_image_chunk(const FloatSamples& f, const SourceImage& image, __m256i is, __m256i it,
                                              __m256 ws, __m256 wt, int inside_bits) {
  const __m256i zero_i = _mm256_setzero_si256(), last = _mm256_set1_epi32(7), one = _mm256_set1_epi32(1);
  const __m256i two = _mm256_set1_epi32(2), six = _mm256_set1_epi32(6), fourteen = _mm256_set1_epi32(14);
  // The run test in lanes (no round trip through scalar registers but for the run's start):
  // the range's start is the smaller of lanes 0 and 7 (s and t are monotonic along a row),
  // and every lane must lie within 6 (narrow) or 14 (wide) samples and two rows of it.
  const __m256i t_lo = _mm256_min_epi32(_mm256_permutevar8x32_epi32(it, zero_i), _mm256_permutevar8x32_epi32(it, last));
  const __m256i s_lo = _mm256_min_epi32(_mm256_permutevar8x32_epi32(is, zero_i), _mm256_permutevar8x32_epi32(is, last));
  const __m256i dt = _mm256_sub_epi32(it, t_lo), ds = _mm256_sub_epi32(is, s_lo);
  const __m256i off_rows = _mm256_or_si256(_mm256_cmpgt_epi32(zero_i, ds), _mm256_cmpgt_epi32(ds, two));
  const __m256i off_wide =
      _mm256_or_si256(off_rows, _mm256_or_si256(_mm256_cmpgt_epi32(zero_i, dt), _mm256_cmpgt_epi32(dt, fourteen)));
  // A run reads 8 or 16 samples from (s_lo, t_lo), t_lo <= cols - 2: past the last row's end
  // only into the image's tail (SourceImage::kTailFloats).
  if (inside_bits == 0xff && _mm256_testz_si256(off_wide, off_wide)) {
    RunRange range;
    range.s0 = first_lane(s_lo);
    range.t0 = first_lane(t_lo);
    range.s_span = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(ds, one)))      ? 2
                   : _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(ds, zero_i))) ? 1
                                                                                              : 0;
    const bool narrow = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(dt, six))) == 0;
    const std::size_t run0 = std::size_t(range.s0) * std::size_t(image.cols) + std::size_t(range.t0);
    const RunLanes l = run_lanes(is, it, range);
    return narrow ? run_cell<FloatSamples, false>(f, run0, std::size_t(image.cols), range.s_span, l, ws, wt)
                  : run_cell<FloatSamples, true>(f, run0, std::size_t(image.cols), range.s_span, l, ws, wt);
  }
  const __m256i v_cols = _mm256_set1_epi32(image.cols);
  return gathered_cell(f, _mm256_add_epi32(_mm256_mullo_epi32(is, v_cols), it), v_cols, ws, wt);
}

// A chunk's cells in the image as st = is << 16 | it (one_row_narrow_run), and its weights.
struct ImageCells {
  __m256i st;
  __m256 ws, wt;
};

LFTRACK_AVX2 inline ImageCells image_cells(const ImageRow& row, __m256 cf, __m256i top_s, __m256i top_t) {
  const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), _mm256_fmadd_ps(row.dn1, cf, row.dn0));
  const __m256 cs = _mm256_mul_ps(_mm256_fmadd_ps(row.ns1, cf, row.ns0), inv);
  const __m256 ct = _mm256_mul_ps(_mm256_fmadd_ps(row.nt1, cf, row.nt0), inv);
  // Cells clamped into the image, as the per-ray kernels clamp them, and the weights measured
  // from the clamped cell (an inside pixel's cell lies in the image, source_image_box, so the
  // clamps only act on rounding at the image's last row or column).
  const __m256i is = clamp_cell(_mm256_cvttps_epi32(cs), top_s), it = clamp_cell(_mm256_cvttps_epi32(ct), top_t);
  return {_mm256_or_si256(_mm256_slli_epi32(is, 16), it), _mm256_sub_ps(cs, _mm256_cvtepi32_ps(is)),
          _mm256_sub_ps(ct, _mm256_cvtepi32_ps(it))};
}

// Renders the whole chunks of a row whose rays are all inside; returns the first column left.
// Software-pipelined by one chunk: the next chunk's cells and run test are computed before this
// chunk's samples are read, so that the two chunks' chains of dependent steps overlap. Needs an
// image of at most 32,768 samples a side (one_row_narrow_run).
LFTRACK_AVX2 inline int render_inside_row_runs(const FloatSamples& f, const SourceImage& image,
                                               const ImageRow& row, int cols, float* dst, unsigned char* ok_row) {
  struct Planned {
    ImageCells cells;
    OneRowRun run;
  };
  // Copies for the common chunk: the mask bytes' stores may alias the image's fields as far as
  // the compiler knows, which would reload them every chunk.
  const std::size_t image_cols = std::size_t(image.cols);
  const __m256i top_s = _mm256_set1_epi32(image.rows - 2), top_t = _mm256_set1_epi32(image.cols - 2);
  const __m256 step = _mm256_set1_ps(8.0f);
  const std::uint64_t all_inside = kMaskBytes.bytes[0xff];
  const int whole = cols - cols % 8;
  if (whole == 0) return 0;
  const auto plan = [&](__m256 cf) LFTRACK_AVX2 {
    Planned p;
    p.cells = image_cells(row, cf, top_s, top_t);
    p.run = one_row_narrow_run(p.cells.st, image_cols);
    return p;
  };
  __m256 cf = _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7);
  Planned next = plan(cf);
  for (int c = 0; c < whole; c += 8) {
    const Planned p = next;
    cf = _mm256_add_ps(cf, step);
    if (c + 8 < whole) next = plan(cf);
    __m256 value;
    if (p.run.holds) {
      value = sample_one_row_narrow(f, image_cols, p.run, p.cells.ws, p.cells.wt);
    } else {
      const __m256i is = _mm256_srli_epi32(p.cells.st, 16);
      const __m256i it = _mm256_and_si256(p.cells.st, _mm256_set1_epi32(0xffff));
      value = sample_image_chunk(f, image, is, it, p.cells.ws, p.cells.wt, 0xff);
    }
    _mm256_storeu_ps(dst + c, value);
    if (ok_row) std::memcpy(ok_row + c, &all_inside, 8);
  }
  return whole;
}

// Reads the image in runs of its rows: render_inside_row_runs and sample_image_chunk.
struct RunsReader {
  const SourceImage& image;
  FloatSamples f;
  bool cells_fit_16_bits;  // render_inside_row_runs's packed cells
  LFTRACK_AVX2 inline int inside_row(const ImageRow& row, int cols, float* dst, unsigned char* ok_row) const {
    return cells_fit_16_bits ? render_inside_row_runs(f, image, row, cols, dst, ok_row) : 0;
  }
  LFTRACK_AVX2 inline __m256 chunk(__m256i is, __m256i it, __m256 ws, __m256 wt, int inside_bits) const {
    return sample_image_chunk(f, image, is, it, ws, wt, inside_bits);
  }
};

// A source-image chunk's value from its cells (is, it), clamped into the image, and weights. The
// image's row pairs (SourceImage::pairs) hold a pixel's four neighbours I(is, it), I(is + 1, it),
// I(is, it + 1), I(is + 1, it + 1) in the 16 bytes from pair (is, it): one load a pixel, the
// same work wherever the pixels fall, however the pose turns the pixel rows across the image's
// rows. The eight loads are turned into four registers of eight pixels each by a 4 x 4
// transpose in each 128-bit half.
LFTRACK_AVX2 inline __m256 sample_pairs_chunk(const float* pairs, __m256i pair_cols, __m256i is, __m256i it, __m256 ws,
                                              __m256 wt) {
  // Float offsets of the pixels' pairs: 2 (is cols + it) < 2^31 (render_source_image_avx2's bound).
  alignas(32) std::int32_t at[8];
  _mm256_store_si256(reinterpret_cast<__m256i*>(at),
                     _mm256_slli_epi32(_mm256_add_epi32(_mm256_mullo_epi32(is, pair_cols), it), 1));
  // Read back from memory: one store and eight loads, where GCC would otherwise extract each
  // lane with vpextrd (two micro-ops each on Zen 3).
  __asm__("" : "+m"(at));
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
  return blend_st(a, b, c, d, ws, wt);
}

// A render's image in row pairs, in lanes: the pairs, its columns (pairs a row) and its cells' bounds.
struct PairImage {
  const float* pairs;
  __m256i cols, top_s, top_t;
};

// Renders the whole chunks of a row whose rays are all inside; returns the first column left.
LFTRACK_AVX2 inline int render_inside_row_pairs(const PairImage& image, const ImageRow& row, int cols, float* dst,
                                                unsigned char* ok_row) {
  const __m256 step = _mm256_set1_ps(8.0f);
  const std::uint64_t all_inside = kMaskBytes.bytes[0xff];
  const int whole = cols - cols % 8;
  __m256 cf = _mm256_setr_ps(0, 1, 2, 3, 4, 5, 6, 7);
  for (int c = 0; c < whole; c += 8, cf = _mm256_add_ps(cf, step)) {
    const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), _mm256_fmadd_ps(row.dn1, cf, row.dn0));
    const __m256 cs = _mm256_mul_ps(_mm256_fmadd_ps(row.ns1, cf, row.ns0), inv);
    const __m256 ct = _mm256_mul_ps(_mm256_fmadd_ps(row.nt1, cf, row.nt0), inv);
    // Cells clamped into the image, as the per-ray kernels clamp them, and the weights measured
    // from the clamped cell (an inside pixel's cell lies in the image, source_image_box, so the
    // clamps only act on rounding at the image's last row or column).
    const __m256i is = clamp_cell(_mm256_cvttps_epi32(cs), image.top_s);
    const __m256i it = clamp_cell(_mm256_cvttps_epi32(ct), image.top_t);
    const __m256 ws = _mm256_sub_ps(cs, _mm256_cvtepi32_ps(is)), wt = _mm256_sub_ps(ct, _mm256_cvtepi32_ps(it));
    _mm256_storeu_ps(dst + c, sample_pairs_chunk(image.pairs, image.cols, is, it, ws, wt));
    if (ok_row) std::memcpy(ok_row + c, &all_inside, 8);
  }
  return whole;
}

// Reads the image's row pairs: render_inside_row_pairs and sample_pairs_chunk.
struct PairsReader {
  PairImage pairs;
  LFTRACK_AVX2 inline int inside_row(const ImageRow& row, int cols, float* dst, unsigned char* ok_row) const {
    return render_inside_row_pairs(pairs, row, cols, dst, ok_row);
  }
  LFTRACK_AVX2 inline __m256 chunk(__m256i is, __m256i it, __m256 ws, __m256 wt, int) const {
    return sample_pairs_chunk(pairs.pairs, pairs.cols, is, it, ws, wt);
  }
};

// The source-image path (light_field_kernels.hpp), reading the image as `Reader` does: rows
// whose rays are all inside in the image's own coordinates (Reader::inside_row), the others (and
// a row's last partial chunk) as the per-ray kernels do, each ray tested against the field.
template <class Reader>
LFTRACK_AVX2 int render_image_avx2(const Reader& reader, const SourceImage& image, const LightFieldGeometry& g,
                                   const RayMap& m, ImageView<float> out, ImageView<unsigned char> valid, int cols,
                                   int r_begin, int r_end) {
  const __m256i s0 = _mm256_set1_epi32(image.s0), t0 = _mm256_set1_epi32(image.t0);
  const __m256i top_s = _mm256_set1_epi32(image.rows - 2), top_t = _mm256_set1_epi32(image.cols - 2);
  const MapLanes map(m);
  const bool all_inside = rows_inside_field(g, m, r_begin, r_end - 1, cols);  // else one test a row
  int masked = 0;
  for (int r = r_begin; r < r_end; ++r) {
    float* dst = out.row_ptr(r);
    unsigned char* ok_row = valid.data ? valid.row_ptr(r) : nullptr;
    const bool inside = all_inside || row_inside_field(g, m, r, cols);
    const int c_first = inside ? reader.inside_row(image_row(g, m, image, r), cols, dst, ok_row) : 0;
    if (c_first == cols) continue;
    const RowRays row = row_rays(g, m, r, inside);
    for (int c = c_first; c < cols; c += 8) {
      const ChunkRays k = chunk_rays(row, map, c, cols);
      // Image indices, clamped into it (inside pixels are already; the others' values are masked).
      const __m256i is = clamp_cell(_mm256_sub_epi32(_mm256_cvttps_epi32(k.cs), s0), top_s);
      const __m256i it = clamp_cell(_mm256_sub_epi32(_mm256_cvttps_epi32(k.ct), t0), top_t);
      const __m256 ws = _mm256_sub_ps(k.cs, _mm256_cvtepi32_ps(_mm256_add_epi32(is, s0)));
      const __m256 wt = _mm256_sub_ps(k.ct, _mm256_cvtepi32_ps(_mm256_add_epi32(it, t0)));
      masked += k.lanes - __builtin_popcount(static_cast<unsigned>(k.inside_bits));
      store_chunk(k, reader.chunk(is, it, ws, wt, k.inside_bits), dst + c, ok_row ? ok_row + c : nullptr);
    }
  }
  return masked;
}

// The source-image path: the image's row pairs where it has them, else runs of its rows.
LFTRACK_AVX2 int render_image_avx2(const SourceImage& image, const LightFieldGeometry& g, const RayMap& m,
                                   ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin,
                                   int r_end) {
  if (image.pairs) {
    const PairsReader pairs{{image.pairs, _mm256_set1_epi32(image.cols), _mm256_set1_epi32(image.rows - 2),
                             _mm256_set1_epi32(image.cols - 2)}};
    return render_image_avx2(pairs, image, g, m, out, valid, cols, r_begin, r_end);
  }
  const RunsReader runs{image, FloatSamples{image.values}, image.rows <= 32768 && image.cols <= 32768};
  return render_image_avx2(runs, image, g, m, out, valid, cols, r_begin, r_end);
}

// Rows [i_begin, i_end) of the image's row pairs from its rows i and i + 1.
LFTRACK_AVX2 void pair_rows(const SourceImage& image, int i_begin, int i_end) {
  const std::size_t cols = std::size_t(image.cols);
  for (int i = i_begin; i < i_end; ++i) {
    const float* top = image.values + std::size_t(i) * cols;
    const float* bottom = top + cols;
    float* pair = image.pairs + 2 * std::size_t(i) * cols;
    std::size_t j = 0;
    for (; j + 8 <= cols; j += 8) {
      const __m256 t = _mm256_loadu_ps(top + j), b = _mm256_loadu_ps(bottom + j);
      const __m256 lo = _mm256_unpacklo_ps(t, b), hi = _mm256_unpackhi_ps(t, b);  // t0 b0 t1 b1 | t4 b4 t5 b5
      _mm256_storeu_ps(pair + 2 * j, _mm256_permute2f128_ps(lo, hi, 0x20));
      _mm256_storeu_ps(pair + 2 * j + 8, _mm256_permute2f128_ps(lo, hi, 0x31));
    }
    for (; j < cols; ++j) {
      pair[2 * j] = top[j];
      pair[2 * j + 1] = bottom[j];
    }
  }
}

}  // namespace

int render_source_image_avx2(const SourceImage& image, const LightFieldGeometry& g, const RayMap& m,
                             ImageView<float> out, ImageView<unsigned char> valid, int cols, int r_begin, int r_end) {
  return render_image_avx2(image, g, m, out, valid, cols, r_begin, r_end);
}

void pair_source_image_avx2(const SourceImage& image, int i_begin, int i_end) { pair_rows(image, i_begin, i_end); }

#else

int render_source_image_avx2(const SourceImage&, const LightFieldGeometry&, const RayMap&, ImageView<float>,
                             ImageView<unsigned char>, int, int, int) {
  return 0;
}
void pair_source_image_avx2(const SourceImage&, int, int) {}

#endif

}  // namespace lftrack::tracking

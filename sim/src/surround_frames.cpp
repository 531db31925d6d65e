#include "lftrack/sim/surround_frames.hpp"

#include "lftrack/sim/poisson_sampler.hpp"

#include <algorithm>
#include <cmath>
#include <random>

namespace lftrack::sim {

using sim_spec::check_physics;
using sim_spec::kMaxPhotonsPerPixel;
using sim_spec::XrayPhysicsSpec;

using namespace lftrack::tracking;

namespace {

// splitmix64 (Steele, Lea and Flood 2014): one 64-bit draw per pixel.
std::uint64_t next_bits(std::uint64_t* state) {
  std::uint64_t z = (*state += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

// About a standard normal deviate: the sum of four 16-bit uniforms (Irwin-Hall, variance 1/3),
// centred and scaled.
double approx_normal(std::uint64_t bits) {
  const double sum = double(bits & 0xffff) + double((bits >> 16) & 0xffff) + double((bits >> 32) & 0xffff) +
                     double(bits >> 48);
  return (sum / 65536.0 - 2.0) * 1.7320508075688772;
}

constexpr double kExactBelowPhotons = 30;

}  // namespace

tracking::MuVolume surround_volume(const tracking::MuVolume& mu) {
  Eigen::Vector3i factor;
  for (int a = 0; a < 3; ++a)
    factor[a] = std::max(1, int(std::lround(kSurroundVoxelMm / mu.geometry.spacing_mm[a])));
  return tracking::block_averaged(mu, factor);
}

SurroundSynthesizer::Axis SurroundSynthesizer::make_axis(int pixels, int coarse) {
  Axis a;
  a.lower.resize(std::size_t(pixels));
  a.weight.resize(std::size_t(pixels));
  for (int i = 0; i < pixels; ++i) {
    // Pixel i's centre in coarse pixel coordinates (coarse pixel k's centre is k).
    const double u = std::clamp((i + 0.5) * coarse / pixels - 0.5, 0.0, double(coarse - 1));
    const int lower = std::min(int(u), std::max(0, coarse - 2));
    a.lower[std::size_t(i)] = lower;
    a.weight[std::size_t(i)] = coarse > 1 ? float(u - lower) : 0.f;
  }
  return a;
}

Result<std::unique_ptr<SurroundSynthesizer>> SurroundSynthesizer::create(const PixelWindow& window,
                                                                         const DetectorModel& model,
                                                                         const XrayPhysicsSpec& physics, int rows,
                                                                         int cols, double pitch_mm,
                                                                         std::uint64_t pattern_seed, int cells) {
  LFTRACK_RETURN_IF_ERROR(check_physics(physics));
  LFTRACK_RETURN_IF_ERROR(check_detector_model(model));
  if (rows < 2 || cols < 2 || rows > 16384 || cols > 16384 || !window.inside(rows, cols))
    return invalid_argument("surround frame: the window must lie inside a detector of 2..16384 pixels a side");
  if (!(pitch_mm > 0 && std::isfinite(pitch_mm))) return invalid_argument("surround frame: pitch must be positive");
  if (cells < 2 || cells > 1024) return invalid_argument("surround frame: 2..1024 coarse pixels a side");
  // A coarse pixel is a detector pixel of the coarse view: at most 100 mm (XrayView::validate).
  if (pitch_mm * double(std::max(rows, cols)) / cells > 100)
    return invalid_argument("surround frame: coarse pixels over 100 mm; more cells");
  std::unique_ptr<SurroundSynthesizer> s(new SurroundSynthesizer());
  s->window_ = window;
  s->model_ = model;
  s->rows_ = rows;
  s->cols_ = cols;
  // Square coarse pixels, `cells` along the longer side (at least 2 along the shorter).
  const double coarse_pitch_px = double(std::max(rows, cols)) / cells;
  s->coarse_rows_ = std::clamp(int(std::lround(rows / coarse_pitch_px)), 2, rows);  // rows >= 2
  s->coarse_cols_ = std::clamp(int(std::lround(cols / coarse_pitch_px)), 2, cols);
  s->row_axis_ = make_axis(rows, s->coarse_rows_);
  s->col_axis_ = make_axis(cols, s->coarse_cols_);
  const int cr = s->coarse_rows_, cc = s->coarse_cols_;
  s->line_integral_ = Image<float>(cr, cc);
  s->primary_ = Image<float>(cr, cc);
  s->thickness_cm_ = Image<float>(cr, cc);
  s->total_ = Image<float>(cr, cc);
  if (physics.spectrum) {
    auto table = beam_attenuation_table(*physics.spectrum);
    if (!table.ok()) return table.status();
    s->table_ = std::move(table).value();
    s->bone_integral_ = Image<float>(cr, cc);
  }
  if (physics.scatter)
    s->scatter_ = std::make_unique<ScatterModel>(cr, cc, pitch_mm * coarse_pitch_px, *physics.scatter);
  s->heel_.assign(std::size_t(rows), 1.f);
  if (physics.detector) {  // the same fixed pattern as the window's (FrameSynthesizer::create)
    const DetectorPattern pattern(effects_of_detector(*physics.detector, pattern_seed), rows, cols);
    s->effects_ = true;
    s->gain_ = Image<float>(rows, cols, 1.f);
    s->stuck_ = Image<float>(rows, cols, -1.f);
    for (int r = 0; r < rows; ++r) {
      s->heel_[std::size_t(r)] = float(pattern.heel(r));
      for (int c = 0; c < cols; ++c) {
        s->gain_.at(r, c) = float(pattern.gain(r, c));
        s->stuck_.at(r, c) = float(pattern.stuck_level(r, c));
      }
    }
  }
  return s;
}

Status SurroundSynthesizer::synthesize(const PatientRenderers& exact, const Pose& gold, const XrayView& view,
                                       std::uint64_t seed, ImageView<std::uint16_t> frame) {
  if (view.rows != rows_ || view.cols != cols_ || frame.rows != rows_ || frame.cols != cols_)
    return invalid_argument("surround frame: the view and the frame must be the detector it was made for");
  if (table_ ? (exact.water == nullptr || exact.bone == nullptr) : exact.attenuation == nullptr)
    return invalid_argument(table_ ? "surround frame: a spectrum needs the water and bone renderers"
                                   : "surround frame: no attenuation renderer");
  const int cr = coarse_rows_, cc = coarse_cols_;
  // The view's geometry without its name: copying a long name would allocate in the frame.
  geometry_.source_mm = view.source_mm;
  geometry_.pixel00_mm = view.pixel00_mm;
  geometry_.col_axis = view.col_axis;
  geometry_.row_axis = view.row_axis;
  geometry_.pitch_col_mm = view.pitch_col_mm;
  geometry_.pitch_row_mm = view.pitch_row_mm;
  geometry_.rows = view.rows;
  geometry_.cols = view.cols;
  const XrayView coarse = geometry_.resampled(0, 0, rows_, cols_, cr, cc);
  LFTRACK_RETURN_IF_ERROR(transmitted_signal(
      exact, table_ ? &*table_ : nullptr, scatter_.get(), gold, coarse, PixelWindow{0, 0, cr, cc},
      {line_integral_.view(), bone_integral_.view(), primary_.view(), thickness_cm_.view(), total_.view()}));
  // The same photon and count levels as the window's (FrameSynthesizer::synthesize): the ideal
  // model has no grid; physics scales by the grid's primary transmission.
  const double photons_open = model_.photons_per_pixel * (scatter_ ? scatter_->photon_fraction() : 1.0);
  const DetectorCorrection correction = detector_correction(model_);
  const double counts_per_photon = correction.open_field_counts / photons_open;
  const double stuck_counts = std::min(correction.open_field_counts, double(correction.saturation_counts));
  std::mt19937_64 rng(seed);  // the exact draws
  std::uint64_t state = seed * 0x2545f4914f6cdd1dull + 1;  // the approximate ones
  // Expected photons per coarse pixel before the heel (the total's share of the open field).
  for (float& t : total_.pixels()) t = std::isfinite(t) ? float(photons_open * std::max(0.f, t)) : 0.f;
  const float max_counts = float(correction.saturation_counts);
  auto draw_row_part = [&](int r, int c_begin, int c_end) {
    const int r0 = row_axis_.lower[std::size_t(r)];
    const int r1 = std::min(r0 + 1, cr - 1);
    const float wr = row_axis_.weight[std::size_t(r)];
    const float heel = heel_[std::size_t(r)];
    const float* top = &total_.at(r0, 0);
    const float* bottom = &total_.at(r1, 0);
    const float* gain = effects_ ? &gain_.at(r, 0) : nullptr;
    const float* stuck = effects_ ? &stuck_.at(r, 0) : nullptr;
    std::uint16_t* out = &frame.at(r, 0);
    for (int c = c_begin; c < c_end; ++c) {
      const int c0 = col_axis_.lower[std::size_t(c)];
      const int c1 = std::min(c0 + 1, cc - 1);
      const float wc = col_axis_.weight[std::size_t(c)];
      const float upper = top[c0] + wc * (top[c1] - top[c0]);
      const float lower = bottom[c0] + wc * (bottom[c1] - bottom[c0]);
      const double expected = std::min(kMaxPhotonsPerPixel, double(heel * (upper + wr * (lower - upper))));
      double photons = expected;
      if (model_.noise)
        photons = expected < kExactBelowPhotons
                      ? double(poisson_draw(expected, rng))
                      : std::max(0.0, expected + std::sqrt(expected) * approx_normal(next_bits(&state)));
      float counts = float(photons * counts_per_photon);
      if (effects_) counts = stuck[c] > 0 ? stuck[c] * float(stuck_counts) : counts * gain[c];
      counts = counts > 0 ? std::min(counts, max_counts) : 0.f;  // NaN: 0
      out[c] = static_cast<std::uint16_t>(counts + 0.5f);
    }
  };
  for (int r = 0; r < rows_; ++r) {
    if (r >= window_.row0 && r < window_.row0 + window_.rows) {  // the window's pixels are the frame synthesizer's
      draw_row_part(r, 0, window_.col0);
      draw_row_part(r, window_.col0 + window_.cols, cols_);
    } else {
      draw_row_part(r, 0, cols_);
    }
  }
  return {};
}

}  // namespace lftrack::sim

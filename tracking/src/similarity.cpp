// Similarity measures (see similarity.hpp for the contract). Sums are accumulated in double; the
// images are a few tens of thousands of pixels, so one pass each is cheap and exact enough.

#include "lftrack/tracking/similarity.hpp"

#include "lftrack/tracking/correlation_sums.hpp"
#include "mutual_information.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace lftrack::tracking {
namespace {

// The fixed image and its usable pixels, shared by every measure.
class FixedImage {
 public:
  Status set(const ImageView<const float>& fixed, const ImageView<const unsigned char>& valid) {
    if (fixed.empty()) return invalid_argument("similarity: the fixed image is empty");
    if (!valid.empty() && (valid.rows != fixed.rows || valid.cols != fixed.cols))
      return invalid_argument("similarity: the fixed mask's size differs from the image's");
    rows = fixed.rows;
    cols = fixed.cols;
    values.assign(static_cast<std::size_t>(rows) * cols, 0.f);
    usable.assign(values.size(), 0);
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c < cols; ++c) {
        const float v = fixed.at(r, c);
        const std::size_t i = index(r, c);
        values[i] = v;
        usable[i] = std::isfinite(v) && (valid.empty() || valid.at(r, c) != 0);
      }
    }
    return {};
  }
  std::size_t index(int r, int c) const { return static_cast<std::size_t>(r) * cols + c; }
  bool fits(const ImageView<const float>& m, const ImageView<const unsigned char>& mv) const {
    return m.rows == rows && m.cols == cols && m.data != nullptr &&
           (mv.empty() || (mv.rows == rows && mv.cols == cols));
  }
  // Pixel usable in both images.
  bool both(const ImageView<const float>& m, const ImageView<const unsigned char>& mv, int r, int c) const {
    return usable[index(r, c)] && std::isfinite(m.at(r, c)) && (mv.empty() || mv.at(r, c) != 0);
  }

  int rows = 0;
  int cols = 0;
  std::vector<float> values;
  std::vector<unsigned char> usable;
};

// Central-difference gradients; a gradient is usable where its 4 neighbours are.
struct Gradient {
  double gx = 0, gy = 0;
};
inline bool gradient_at(const FixedImage& f, const ImageView<const float>& m,
                        const ImageView<const unsigned char>& mv, int r, int c, Gradient* gf, Gradient* gm) {
  if (r < 1 || c < 1 || r + 1 >= f.rows || c + 1 >= f.cols) return false;
  if (!f.both(m, mv, r, c - 1) || !f.both(m, mv, r, c + 1) || !f.both(m, mv, r - 1, c) ||
      !f.both(m, mv, r + 1, c))
    return false;
  gf->gx = double(f.values[f.index(r, c + 1)]) - f.values[f.index(r, c - 1)];
  gf->gy = double(f.values[f.index(r + 1, c)]) - f.values[f.index(r - 1, c)];
  gm->gx = double(m.at(r, c + 1)) - m.at(r, c - 1);
  gm->gy = double(m.at(r + 1, c)) - m.at(r - 1, c);
  return true;
}

// Correlation sums of the pixels usable in both images, row by row without a branch per pixel: a
// pixel that is not usable in both adds zeros, which leaves every sum as it was.
CorrelationSums pixel_sums(const FixedImage& f, const ImageView<const float>& m,
                           const ImageView<const unsigned char>& mv) {
  CorrelationSums s;
  for (int r = 0; r < f.rows; ++r) {
    const float* f_row = &f.values[f.index(r, 0)];
    const unsigned char* usable_row = &f.usable[f.index(r, 0)];
    const float* m_row = m.row_ptr(r);
    const unsigned char* mv_row = mv.empty() ? nullptr : mv.row_ptr(r);
    for (int c = 0; c < f.cols; ++c) {
      const bool ok = usable_row[c] && std::isfinite(m_row[c]) && (mv_row == nullptr || mv_row[c] != 0);
      const double fv = ok ? f_row[c] : 0.0, mvv = ok ? m_row[c] : 0.0;
      s.n += ok;
      s.a += fv;
      s.b += mvv;
      s.aa += fv * fv;
      s.bb += mvv * mvv;
      s.ab += fv * mvv;
    }
  }
  return s;
}

class Ncc final : public Similarity {
 public:
  std::string_view name() const override { return "ncc"; }
  double worst_score() const override { return -1; }
  Status prepare(const ImageView<const float>& f, const ImageView<const unsigned char>& v) override {
    return fixed_.set(f, v);
  }
  double score(const ImageView<const float>& m, const ImageView<const unsigned char>& mv) override {
    if (!fixed_.fits(m, mv)) return worst_score();
    const CorrelationSums s = pixel_sums(fixed_, m, mv);
    return s.n < kMinPixels ? worst_score() : s.value();
  }
  std::unique_ptr<Similarity> clone() const override { return std::make_unique<Ncc>(*this); }

 private:
  FixedImage fixed_;
};

// NCC with Tukey's biweight on the residual of the standardised images (one reweighting step):
// r = (f - mean f) / sd f - (m - mean m) / sd m over the usable pixels, whose RMS is
// sqrt(2 (1 - ncc)); a pixel's weight is (1 - (r / c)^2)^2 below c = tukey_c * RMS and 0 above,
// and the score is the weighted NCC. Pixels that the DRR cannot explain at this pose (an organ edge
// that moved with breathing, a rib, a gas pocket) stop pulling it, while the weights stay a smooth
// function of the pose. By Chebyshev at most 1 / tukey_c^2 of the pixels get weight 0, so the
// measure cannot reach a high score by discarding most of the image. Constant images give 0.
class RobustNcc final : public Similarity {
 public:
  explicit RobustNcc(double tukey_c) : tukey_c_(tukey_c) {}
  std::string_view name() const override { return "rncc"; }
  double worst_score() const override { return -1; }
  Status prepare(const ImageView<const float>& f, const ImageView<const unsigned char>& v) override {
    return fixed_.set(f, v);
  }
  double score(const ImageView<const float>& m, const ImageView<const unsigned char>& mv) override {
    if (!fixed_.fits(m, mv)) return worst_score();
    const CorrelationSums s = pixel_sums(fixed_, m, mv);  // pass 1: the plain sums
    if (s.n < kMinPixels) return worst_score();
    const double mean_f = s.a / s.n, mean_m = s.b / s.n;
    const double var_f = s.aa / s.n - mean_f * mean_f, var_m = s.bb / s.n - mean_m * mean_m;
    if (!(var_f > 0) || !(var_m > 0) || !std::isfinite(var_f * var_m)) return 0;
    const double ncc = s.value();
    const double rms = std::sqrt(std::max(0.0, 2 * (1 - ncc)));
    // Below this the residual is rounding (pass 2's weights are formed in float): nothing to
    // reweight, and the plain NCC is the answer.
    if (!(rms > 1e-5)) return ncc;
    // Pass 2: the weighted sums of the standardised images. A pixel is standardised in double
    // (a standardised value is at most sqrt(n), so it fits a float whatever the image's range)
    // and weighted in float (the weights need no more); the sums are in double.
    const double inv_sd_f = 1 / std::sqrt(var_f), inv_sd_m = 1 / std::sqrt(var_m);
    const float inv_c2 = static_cast<float>(1 / (tukey_c_ * tukey_c_ * rms * rms));
    double w_sum = 0, wf = 0, wm = 0, wff = 0, wmm = 0, wfm = 0;
    for (int r = 0; r < fixed_.rows; ++r) {
      const float* f_row = &fixed_.values[fixed_.index(r, 0)];
      const unsigned char* usable_row = &fixed_.usable[fixed_.index(r, 0)];
      const float* m_row = m.row_ptr(r);
      const unsigned char* mv_row = mv.empty() ? nullptr : mv.row_ptr(r);
      for (int c = 0; c < fixed_.cols; ++c) {
        const bool ok = usable_row[c] && std::isfinite(m_row[c]) && (mv_row == nullptr || mv_row[c] != 0);
        const float fv = ok ? static_cast<float>((f_row[c] - mean_f) * inv_sd_f) : 0.f;
        const float mvv = ok ? static_cast<float>((m_row[c] - mean_m) * inv_sd_m) : 0.f;
        const float u = std::min((fv - mvv) * (fv - mvv) * inv_c2, 1.f);
        const float w = ok ? (1 - u) * (1 - u) : 0.f;
        const float w_f = w * fv, w_m = w * mvv;
        w_sum += w;
        wf += w_f;
        wm += w_m;
        wff += w_f * fv;
        wmm += w_m * mvv;
        wfm += w_f * mvv;
      }
    }
    if (!(w_sum > 0)) return 0;
    const double cov = wfm - wf * wm / w_sum;
    const double denom = std::sqrt(std::max(wff - wf * wf / w_sum, 0.0) * std::max(wmm - wm * wm / w_sum, 0.0));
    if (!(denom > 1e-300) || !std::isfinite(denom)) return 0;
    return std::clamp(cov / denom, -1.0, 1.0);
  }
  std::unique_ptr<Similarity> clone() const override { return std::make_unique<RobustNcc>(*this); }

 private:
  double tukey_c_;
  FixedImage fixed_;
};

class GradientCorrelation final : public Similarity {
 public:
  std::string_view name() const override { return "gc"; }
  double worst_score() const override { return -1; }
  Status prepare(const ImageView<const float>& f, const ImageView<const unsigned char>& v) override {
    return fixed_.set(f, v);
  }
  double score(const ImageView<const float>& m, const ImageView<const unsigned char>& mv) override {
    if (!fixed_.fits(m, mv)) return worst_score();
    CorrelationSums sx, sy;
    Gradient gf, gm;
    for (int r = 1; r + 1 < fixed_.rows; ++r) {
      for (int c = 1; c + 1 < fixed_.cols; ++c) {
        if (!gradient_at(fixed_, m, mv, r, c, &gf, &gm)) continue;
        sx.add(gf.gx, gm.gx);
        sy.add(gf.gy, gm.gy);
      }
    }
    return sx.n < kMinPixels ? worst_score() : 0.5 * (sx.value() + sy.value());
  }
  std::unique_ptr<Similarity> clone() const override { return std::make_unique<GradientCorrelation>(*this); }

 private:
  FixedImage fixed_;
};

// Pattern intensity on the difference of the standardised images, over the pixel pairs closer
// than the radius (each pair once), averaged.
class PatternIntensity final : public Similarity {
 public:
  PatternIntensity(int radius, double sigma)
      : radius_(std::clamp(radius, 1, 16)), sigma_(sigma > 0 ? sigma : 0.1) {}
  std::string_view name() const override { return "pi"; }
  double worst_score() const override { return 0; }
  Status prepare(const ImageView<const float>& f, const ImageView<const unsigned char>& v) override {
    LFTRACK_RETURN_IF_ERROR(fixed_.set(f, v));
    difference_.assign(fixed_.values.size(), 0.f);
    usable_.assign(fixed_.values.size(), 0);
    offsets_.clear();
    for (int dr = 0; dr <= radius_; ++dr)
      for (int dc = -radius_; dc <= radius_; ++dc)
        if ((dr > 0 || dc > 0) && dr * dr + dc * dc <= radius_ * radius_) offsets_.push_back({dr, dc});
    return {};
  }
  double score(const ImageView<const float>& m, const ImageView<const unsigned char>& mv) override {
    if (!fixed_.fits(m, mv)) return worst_score();
    const CorrelationSums s = pixel_sums(fixed_, m, mv);
    if (s.n < kMinPixels) return worst_score();
    const double mean_f = s.a / s.n, mean_m = s.b / s.n;
    const double sd_f = std::sqrt(std::max(0.0, s.aa / s.n - mean_f * mean_f));
    const double sd_m = std::sqrt(std::max(0.0, s.bb / s.n - mean_m * mean_m));
    const double inv_f = sd_f > 1e-300 ? 1.0 / sd_f : 0.0, inv_m = sd_m > 1e-300 ? 1.0 / sd_m : 0.0;
    for (int r = 0; r < fixed_.rows; ++r) {
      for (int c = 0; c < fixed_.cols; ++c) {
        const std::size_t i = fixed_.index(r, c);
        usable_[i] = fixed_.both(m, mv, r, c);
        difference_[i] =
            usable_[i]
                ? static_cast<float>((fixed_.values[i] - mean_f) * inv_f - (m.at(r, c) - mean_m) * inv_m)
                : 0.f;
      }
    }
    const double s2 = sigma_ * sigma_;
    double sum = 0, pairs = 0;
    for (int r = 0; r < fixed_.rows; ++r) {
      for (int c = 0; c < fixed_.cols; ++c) {
        const std::size_t i = fixed_.index(r, c);
        if (!usable_[i]) continue;
        for (const auto& [dr, dc] : offsets_) {
          const int r2 = r + dr, c2 = c + dc;
          if (r2 >= fixed_.rows || c2 < 0 || c2 >= fixed_.cols) continue;
          const std::size_t j = fixed_.index(r2, c2);
          if (!usable_[j]) continue;
          const double d = double(difference_[i]) - difference_[j];
          sum += s2 / (s2 + d * d);
          pairs += 1;
        }
      }
    }
    return pairs > 0 ? sum / pairs : worst_score();
  }
  std::unique_ptr<Similarity> clone() const override { return std::make_unique<PatternIntensity>(*this); }

 private:
  struct Offset {
    int dr, dc;
  };
  int radius_;
  double sigma_;
  FixedImage fixed_;
  std::vector<float> difference_;
  std::vector<unsigned char> usable_;
  std::vector<Offset> offsets_;
};

// Gradient difference: sum over pixels of A_y / (A_y + (gy_f - s gy_m)^2) + A_x / (A_x + ...),
// A = variance of the fixed gradient, s = least-squares scale of the moving gradients; divided
// by the pixel count.
class GradientDifference final : public Similarity {
 public:
  std::string_view name() const override { return "gd"; }
  double worst_score() const override { return 0; }
  Status prepare(const ImageView<const float>& f, const ImageView<const unsigned char>& v) override {
    LFTRACK_RETURN_IF_ERROR(fixed_.set(f, v));
    moving_gradient_.assign(fixed_.values.size(), {});
    fixed_gradient_.assign(fixed_.values.size(), {});
    usable_.assign(fixed_.values.size(), 0);
    return {};
  }
  double score(const ImageView<const float>& m, const ImageView<const unsigned char>& mv) override {
    if (!fixed_.fits(m, mv)) return worst_score();
    double n = 0, fm = 0, mm = 0, sfx = 0, sfxx = 0, sfy = 0, sfyy = 0;
    for (int r = 0; r < fixed_.rows; ++r) {
      for (int c = 0; c < fixed_.cols; ++c) {
        const std::size_t i = fixed_.index(r, c);
        Gradient gf, gm;
        usable_[i] = gradient_at(fixed_, m, mv, r, c, &gf, &gm);
        if (!usable_[i]) continue;
        fixed_gradient_[i] = gf;
        moving_gradient_[i] = gm;
        n += 1;
        fm += gf.gx * gm.gx + gf.gy * gm.gy;
        mm += gm.gx * gm.gx + gm.gy * gm.gy;
        sfx += gf.gx;
        sfxx += gf.gx * gf.gx;
        sfy += gf.gy;
        sfyy += gf.gy * gf.gy;
      }
    }
    if (n < kMinPixels) return worst_score();
    const double scale = mm > 1e-300 ? fm / mm : 0.0;
    const double ax = std::max(sfxx / n - (sfx / n) * (sfx / n), 1e-12);
    const double ay = std::max(sfyy / n - (sfy / n) * (sfy / n), 1e-12);
    double sum = 0;
    for (std::size_t i = 0; i < usable_.size(); ++i) {
      if (!usable_[i]) continue;
      const double dx = fixed_gradient_[i].gx - scale * moving_gradient_[i].gx;
      const double dy = fixed_gradient_[i].gy - scale * moving_gradient_[i].gy;
      sum += ax / (ax + dx * dx) + ay / (ay + dy * dy);
    }
    return sum / n;
  }
  std::unique_ptr<Similarity> clone() const override { return std::make_unique<GradientDifference>(*this); }

 private:
  FixedImage fixed_;
  std::vector<Gradient> fixed_gradient_, moving_gradient_;
  std::vector<unsigned char> usable_;
};

}  // namespace

std::vector<std::string> similarity_names() {
  return {"mi", "nmi", "ncc", "rncc", "gc", "pi", "gd"};
}

Result<std::unique_ptr<Similarity>> make_similarity(std::string_view name, const SimilarityOptions& options) {
  if ((name == "mi" || name == "nmi") && (options.histogram_bins < 2 || options.histogram_bins > 1024))
    return out_of_range(std::string(name) + ": histogram bins must be in 2..1024, not " +
                        std::to_string(options.histogram_bins));
  if (name == "mi") return make_mutual_information(options.histogram_bins, false, options.vector_lanes);
  if (name == "nmi") return make_mutual_information(options.histogram_bins, true, options.vector_lanes);
  if (name == "ncc") return std::unique_ptr<Similarity>(new Ncc());
  if (name == "rncc") {
    if (!(options.tukey_c >= 1 && options.tukey_c <= 100))
      return out_of_range("rncc: Tukey's c must be in 1..100 (times the residual's RMS), not " +
                          std::to_string(options.tukey_c));
    return std::unique_ptr<Similarity>(new RobustNcc(options.tukey_c));
  }
  if (name == "gc") return std::unique_ptr<Similarity>(new GradientCorrelation());
  if (name == "pi")
    return std::unique_ptr<Similarity>(
        new PatternIntensity(options.pattern_radius_px, options.pattern_sigma));
  if (name == "gd") return std::unique_ptr<Similarity>(new GradientDifference());
  std::string known;
  for (const auto& n : similarity_names()) known += (known.empty() ? "" : ", ") + n;
  return invalid_argument("unknown similarity measure '" + std::string(name) + "' (known: " + known + ")");
}

}  // namespace lftrack::tracking

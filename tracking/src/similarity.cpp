// Similarity measures (see similarity.hpp for the contract). Sums are accumulated in double; the
// images are a few tens of thousands of pixels, so one pass each is cheap and exact enough.

#include "lftrack/tracking/similarity.hpp"

#include "lftrack/tracking/correlation_sums.hpp"

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

// Correlation sums of the pixels usable in both images.
CorrelationSums pixel_sums(const FixedImage& f, const ImageView<const float>& m,
                           const ImageView<const unsigned char>& mv) {
  CorrelationSums s;
  for (int r = 0; r < f.rows; ++r)
    for (int c = 0; c < f.cols; ++c)
      if (f.both(m, mv, r, c)) s.add(f.values[f.index(r, c)], m.at(r, c));
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

// Mutual information from a joint histogram: the fixed image's bin is fixed at prepare(); the
// moving value is split linearly between its two nearest bins (partial-volume binning), which
// keeps the measure continuous in the pose.
class MutualInformation final : public Similarity {
 public:
  MutualInformation(int bins, bool normalised) : bins_(std::clamp(bins, 2, 1024)), normalised_(normalised) {}
  std::string_view name() const override { return normalised_ ? "nmi" : "mi"; }
  double worst_score() const override { return normalised_ ? 1.0 : 0.0; }

  Status prepare(const ImageView<const float>& f, const ImageView<const unsigned char>& v) override {
    LFTRACK_RETURN_IF_ERROR(fixed_.set(f, v));
    float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest();
    for (std::size_t i = 0; i < fixed_.values.size(); ++i) {
      if (!fixed_.usable[i]) continue;
      lo = std::min(lo, fixed_.values[i]);
      hi = std::max(hi, fixed_.values[i]);
    }
    fixed_bin_.assign(fixed_.values.size(), kUnusable);
    pair_bin_.assign(fixed_.values.size(), 0);
    pair_value_.assign(fixed_.values.size(), 0.f);
    const double scale = hi > lo ? (bins_ - 1e-9) / (double(hi) - lo) : 0.0;
    for (std::size_t i = 0; i < fixed_.values.size(); ++i) {
      if (fixed_.usable[i])
        fixed_bin_[i] = static_cast<std::uint16_t>(
            std::clamp(static_cast<int>((fixed_.values[i] - lo) * scale), 0, bins_ - 1));
    }
    joint_.assign(static_cast<std::size_t>(bins_) * bins_, 0.0);
    joint_odd_.assign(joint_.size(), 0.0);
    fixed_marginal_.assign(bins_, 0.0);
    moving_marginal_.assign(bins_, 0.0);
    return {};
  }

  double score(const ImageView<const float>& m, const ImageView<const unsigned char>& mv) override {
    if (!fixed_.fits(m, mv)) return worst_score();
    // Pass 1: the usable pixels' fixed bins and moving values, compacted without branches, and
    // the moving range.
    int n = 0;
    float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest();
    for (int r = 0; r < fixed_.rows; ++r) {
      const float* moving = m.row_ptr(r);
      const unsigned char* moving_valid = mv.empty() ? nullptr : mv.row_ptr(r);
      const std::uint16_t* bins = &fixed_bin_[fixed_.index(r, 0)];
      for (int c = 0; c < fixed_.cols; ++c) {
        const float v = moving[c];
        const bool ok = (bins[c] != kUnusable) & (moving_valid == nullptr || moving_valid[c] != 0) &
                        (std::abs(v) <= std::numeric_limits<float>::max());  // false for NaN and inf
        pair_bin_[std::size_t(n)] = bins[c];
        pair_value_[std::size_t(n)] = v;
        lo = ok && v < lo ? v : lo;
        hi = ok && v > hi ? v : hi;
        n += ok ? 1 : 0;
      }
    }
    if (n < kMinPixels) return worst_score();
    if (!(double(hi) - lo > 1e-12 * std::max(1.0, std::abs(double(hi))))) return worst_score();  // constant
    // Pass 2: the joint histogram, the moving value split between its two nearest bins. Even
    // and odd pixels go to two copies, so that neighbours (often in the same bin) do not wait
    // on each other's update; the copies are summed afterwards.
    std::fill(joint_.begin(), joint_.end(), 0.0);
    std::fill(joint_odd_.begin(), joint_odd_.end(), 0.0);
    const float scale = float((bins_ - 1) / (double(hi) - lo));
    const int last = bins_ - 2;
    auto add = [&](std::vector<double>& joint, int i) {
      const float x = (pair_value_[std::size_t(i)] - lo) * scale;
      const int j = std::min(static_cast<int>(x), last);
      const double w = double(x) - j;
      double* row = &joint[static_cast<std::size_t>(pair_bin_[std::size_t(i)]) * bins_ + j];
      row[0] += 1.0 - w;
      row[1] += w;
    };
    int i = 0;
    for (; i + 1 < n; i += 2) {
      add(joint_, i);
      add(joint_odd_, i + 1);
    }
    if (i < n) add(joint_, i);
    for (std::size_t k = 0; k < joint_.size(); ++k) joint_[k] += joint_odd_[k];
    std::fill(fixed_marginal_.begin(), fixed_marginal_.end(), 0.0);
    std::fill(moving_marginal_.begin(), moving_marginal_.end(), 0.0);
    for (int a = 0; a < bins_; ++a) {
      for (int b = 0; b < bins_; ++b) {
        const double p = joint_[static_cast<std::size_t>(a) * bins_ + b];
        fixed_marginal_[a] += p;
        moving_marginal_[b] += p;
      }
    }
    const double inv_n = 1.0 / n;
    auto entropy = [&](const std::vector<double>& counts) {
      double h = 0;
      for (double k : counts)
        if (k > 0) h -= k * inv_n * std::log(k * inv_n);
      return h;
    };
    const double h_fixed = entropy(fixed_marginal_), h_moving = entropy(moving_marginal_),
                 h_joint = entropy(joint_);
    if (normalised_) return h_joint > 1e-12 ? std::clamp((h_fixed + h_moving) / h_joint, 1.0, 2.0) : 1.0;
    return std::max(0.0, h_fixed + h_moving - h_joint);
  }
  std::unique_ptr<Similarity> clone() const override { return std::make_unique<MutualInformation>(*this); }

 private:
  static constexpr std::uint16_t kUnusable = 0xFFFF;
  int bins_;
  bool normalised_;
  FixedImage fixed_;
  std::vector<std::uint16_t> fixed_bin_;  // kUnusable where the fixed pixel is not usable
  std::vector<std::uint16_t> pair_bin_;   // scratch: compacted usable pixels
  std::vector<float> pair_value_;
  std::vector<double> joint_, joint_odd_, fixed_marginal_, moving_marginal_;
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
  return {"mi", "nmi", "ncc", "gc", "pi", "gd"};
}

Result<std::unique_ptr<Similarity>> make_similarity(std::string_view name, const SimilarityOptions& options) {
  if ((name == "mi" || name == "nmi") && (options.histogram_bins < 2 || options.histogram_bins > 1024))
    return out_of_range(std::string(name) + ": histogram bins must be in 2..1024, not " +
                        std::to_string(options.histogram_bins));
  if (name == "mi") return std::unique_ptr<Similarity>(new MutualInformation(options.histogram_bins, false));
  if (name == "nmi") return std::unique_ptr<Similarity>(new MutualInformation(options.histogram_bins, true));
  if (name == "ncc") return std::unique_ptr<Similarity>(new Ncc());
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

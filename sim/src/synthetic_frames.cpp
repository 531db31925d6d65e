#include "lftrack/sim/synthetic_frames.hpp"

#include "lftrack/sim/poisson_sampler.hpp"

#include <algorithm>
#include <cmath>
#include <random>

namespace lftrack::sim {

using sim_spec::BeamSpec;
using sim_spec::check_physics;
using sim_spec::DetectorEffectsSpec;
using sim_spec::kMaxPhotonsPerPixel;
using sim_spec::XrayPhysicsSpec;

using namespace lftrack::tracking;

DetectorCorrection detector_correction(const DetectorModel& model) {
  return tracking::nominal_detector_correction(model.bits, model.open_field_fraction);
}

namespace {

// The open field at most a million times full scale (an AEC's dose behind a line integral of 14).
constexpr double kMaxOpenFieldFraction = 1e6;

}  // namespace

Status check_detector_model(const DetectorModel& model) {
  if (!(model.photons_per_pixel > 0 && model.photons_per_pixel <= kMaxPhotonsPerPixel) ||
      !(model.open_field_fraction > 0 && model.open_field_fraction <= kMaxOpenFieldFraction) || model.bits < 8 ||
      model.bits > 16)
    return invalid_argument("synthetic frame: photons in (0, 1e9], open-field fraction in (0, 1e6], 8-16 bits");
  return {};
}

DetectorEffectsSpec effects_of_detector(const DetectorEffectsSpec& effects, std::uint64_t detector_seed) {
  DetectorEffectsSpec e = effects;
  e.pattern_seed = e.pattern_seed * 1000003ull + detector_seed;
  return e;
}

Result<PolyenergeticTable> beam_attenuation_table(const BeamSpec& beam) {
  auto spectrum = make_spectrum(beam.spectrum);
  if (!spectrum.ok()) return spectrum.status();
  return PolyenergeticTable::create(*spectrum);
}

Status transmitted_signal(const PatientRenderers& patient, const PolyenergeticTable* table, ScatterModel* scatter,
                          const Pose& gold, const XrayView& view, const PixelWindow& window, const SignalBuffers& b) {
  if (table != nullptr) {
    LFTRACK_RETURN_IF_ERROR(patient.water->render(gold, view, window, b.line));
    LFTRACK_RETURN_IF_ERROR(patient.bone->render(gold, view, window, b.bone));
  } else {
    LFTRACK_RETURN_IF_ERROR(patient.attenuation->render(gold, view, window, b.line));
  }
  const double mu_water_per_cm = 10 * kDefaultMuWaterPerMm;
  for (int r = 0; r < window.rows; ++r)
    for (int c = 0; c < window.cols; ++c) {
      if (table != nullptr) {
        const float w = b.line.at(r, c), bone = b.bone.at(r, c);
        b.primary.at(r, c) = float(std::exp(-double(table->log_attenuation(w, bone))));
        b.thickness_cm.at(r, c) = std::max(0.f, w) + std::max(0.f, bone);  // g/cm^2 ~ cm of water
      } else {
        const double p = b.line.at(r, c);
        b.primary.at(r, c) = float(std::exp(-p));
        b.thickness_cm.at(r, c) = float(std::max(0.0, p) / mu_water_per_cm);
      }
    }
  if (scatter != nullptr) return scatter->add_scatter(b.primary, b.thickness_cm, b.total);
  for (int r = 0; r < window.rows; ++r)
    for (int c = 0; c < window.cols; ++c) b.total.at(r, c) = b.primary.at(r, c);
  return {};
}

FrameSynthesizer::FrameSynthesizer(const PixelWindow& window, const DetectorModel& model)
    : window_(window),
      model_(model),
      line_integral_(window.rows, window.cols),
      photons_(window.rows, window.cols),
      blurred_(window.rows, window.cols),
      blur_(window.rows, window.cols, model.blur_sigma_px) {}

Status FrameSynthesizer::synthesize(const DrrRenderer& renderer, const Pose& gold, const XrayView& view,
                                    std::uint64_t seed, ImageView<std::uint16_t> frame) {
  PatientRenderers patient;
  patient.attenuation = &renderer;
  return synthesize(patient, gold, view, seed, frame);
}

Result<std::unique_ptr<FrameSynthesizer>> FrameSynthesizer::create(const PixelWindow& window,
                                                                   const DetectorModel& model,
                                                                   const XrayPhysicsSpec& physics, int rows,
                                                                   int cols, double pitch_mm,
                                                                   std::uint64_t pattern_seed) {
  LFTRACK_RETURN_IF_ERROR(check_detector_model(model));
  LFTRACK_RETURN_IF_ERROR(check_physics(physics));
  if (!window.inside(rows, cols)) return invalid_argument("synthetic frame: the window must lie inside the detector");
  if (!(pitch_mm > 0 && std::isfinite(pitch_mm))) return invalid_argument("synthetic frame: pitch must be positive");
  auto s = std::make_unique<FrameSynthesizer>(window, model);
  const int wr = window.rows, wc = window.cols;
  if (physics.spectrum) {
    auto table = beam_attenuation_table(*physics.spectrum);
    if (!table.ok()) return table.status();
    s->table_ = std::move(table).value();
    s->bone_integral_ = Image<float>(wr, wc);
  }
  if (physics.scatter) s->scatter_ = std::make_unique<ScatterModel>(wr, wc, pitch_mm, *physics.scatter);
  if (physics.detector) {
    const DetectorEffectsSpec effects = effects_of_detector(*physics.detector, pattern_seed);
    s->effects_ = effects;
    const DetectorPattern pattern(effects, rows, cols);
    if (effects.glare_fraction > 0)
      s->glare_ = std::make_unique<GaussianBlur>(wr, wc, effects.glare_sigma_mm / pitch_mm);
    s->gain_ = Image<float>(wr, wc, 1.f);
    s->stuck_ = Image<float>(wr, wc, -1.f);
    s->heel_ = Image<float>(wr, wc, 1.f);
    for (int r = 0; r < wr; ++r)
      for (int c = 0; c < wc; ++c) {
        s->gain_.at(r, c) = float(pattern.gain(window.row0 + r, window.col0 + c));
        s->stuck_.at(r, c) = float(pattern.stuck_level(window.row0 + r, window.col0 + c));
        s->heel_.at(r, c) = float(pattern.heel(window.row0 + r));
      }
    s->glared_ = Image<float>(wr, wc);
    s->previous_ = Image<float>(wr, wc);
  }
  s->primary_ = Image<float>(wr, wc);
  s->thickness_cm_ = Image<float>(wr, wc);
  s->total_ = Image<float>(wr, wc);
  return s;
}

Status FrameSynthesizer::synthesize(const PatientRenderers& patient, const Pose& gold, const XrayView& view,
                                    std::uint64_t seed, ImageView<std::uint16_t> frame) {
  LFTRACK_RETURN_IF_ERROR(check_detector_model(model_));
  if (frame.rows != view.rows || frame.cols != view.cols || !window_.inside(view.rows, view.cols))
    return invalid_argument("synthetic frame: the frame must be the whole detector, the window inside it");
  const bool physics = table_ || scatter_ || effects_;
  if (table_ ? (patient.water == nullptr || patient.bone == nullptr) : patient.attenuation == nullptr)
    return invalid_argument(table_ ? "synthetic frame: a spectrum needs the water and bone renderers"
                                   : "synthetic frame: no attenuation renderer");
  std::mt19937_64 rng(seed);
  auto draw = [&](double expected) {
    if (!model_.noise) return static_cast<float>(expected);
    return static_cast<float>(poisson_draw(expected, rng));
  };
  const DetectorCorrection correction = detector_correction(model_);
  if (!physics) {
    LFTRACK_RETURN_IF_ERROR(patient.attenuation->render(gold, view, window_, line_integral_.view()));
    // Photons, with Poisson noise.
    for (int r = 0; r < window_.rows; ++r)
      for (int c = 0; c < window_.cols; ++c)
        photons_.at(r, c) = draw(model_.photons_per_pixel * std::exp(-double(line_integral_.at(r, c))));
    // Detector blur, then quantisation.
    LFTRACK_RETURN_IF_ERROR(blur_.blur(photons_.view(), {}, blurred_.view()));
    const double counts_per_photon = correction.open_field_counts / model_.photons_per_pixel;
    for (int r = 0; r < window_.rows; ++r)
      for (int c = 0; c < window_.cols; ++c)
        frame.at(window_.row0 + r, window_.col0 + c) = static_cast<std::uint16_t>(std::clamp(
            std::lround(blurred_.at(r, c) * counts_per_photon), 0L, long(correction.saturation_counts)));
    return {};
  }
  // The primary's transmission, each ray's water-equivalent thickness (cm), the scatter.
  LFTRACK_RETURN_IF_ERROR(transmitted_signal(
      patient, table_ ? &*table_ : nullptr, scatter_.get(), gold, view, window_,
      {line_integral_.view(), bone_integral_.view(), primary_.view(), thickness_cm_.view(), total_.view()}));
  // Photons reaching the detector: the heel's intensity, the grid's share.
  const double photon_fraction = scatter_ ? scatter_->photon_fraction() : 1.0;
  const double photons_open = model_.photons_per_pixel * photon_fraction;
  for (int r = 0; r < window_.rows; ++r)
    for (int c = 0; c < window_.cols; ++c) {
      const double heel = effects_ ? double(heel_.at(r, c)) : 1.0;
      const double expected = photons_open * heel * std::max(0.0, double(total_.at(r, c)));
      photons_.at(r, c) = draw(std::isfinite(expected) ? expected : 0.0);
    }
  LFTRACK_RETURN_IF_ERROR(blur_.blur(photons_.view(), {}, blurred_.view()));
  if (effects_ && glare_) {
    LFTRACK_RETURN_IF_ERROR(glare_->blur(blurred_.view(), {}, glared_.view()));
    const float g = float(effects_->glare_fraction);
    for (std::size_t i = 0; i < blurred_.pixels().size(); ++i)
      blurred_.pixels()[i] = (1 - g) * blurred_.pixels()[i] + g * glared_.pixels()[i];
  }
  if (effects_ && effects_->lag_fraction > 0) {
    const float lag = float(effects_->lag_fraction);
    for (std::size_t i = 0; i < blurred_.pixels().size(); ++i) {
      const float now = blurred_.pixels()[i];
      if (has_previous_) blurred_.pixels()[i] = (1 - lag) * now + lag * previous_.pixels()[i];
      previous_.pixels()[i] = now;
    }
    has_previous_ = true;
  }
  // Counts: the gridded open field reads the open-field level.
  const double counts_per_photon = correction.open_field_counts / photons_open;
  for (int r = 0; r < window_.rows; ++r)
    for (int c = 0; c < window_.cols; ++c) {
      double counts = blurred_.at(r, c) * counts_per_photon;
      if (effects_) {
        counts *= gain_.at(r, c);
        // A stuck pixel reads its level of the detector's own open field, whatever the dose.
        if (stuck_.at(r, c) > 0)
          counts = stuck_.at(r, c) * std::min(correction.open_field_counts, double(correction.saturation_counts));
      }
      frame.at(window_.row0 + r, window_.col0 + c) = static_cast<std::uint16_t>(
          std::clamp(std::isfinite(counts) ? std::lround(counts) : 0L, 0L, long(correction.saturation_counts)));
    }
  return {};
}

Result<Image<std::uint16_t>> synthesize_frame(const DrrRenderer& exact, const Pose& gold,
                                              const XrayView& view, const PixelWindow& window,
                                              const DetectorModel& model, std::uint64_t seed) {
  LFTRACK_RETURN_IF_ERROR(check_detector_model(model));
  Image<std::uint16_t> frame(view.rows, view.cols, 0);
  FrameSynthesizer synthesizer(window, model);
  LFTRACK_RETURN_IF_ERROR(synthesizer.synthesize(exact, gold, view, seed, frame.view()));
  return frame;
}

}  // namespace lftrack::sim

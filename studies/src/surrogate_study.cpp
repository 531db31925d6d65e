#include "lftrack/studies/surrogate_study.hpp"

#include <fmt/format.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <random>

#include <spdlog/spdlog.h>

#include <algorithm>

#include "lftrack/sim/breathing_surrogate.hpp"
#include "lftrack/sim/patient_motion.hpp"
#include "lftrack/studies/plot.hpp"
#include "quantile.hpp"
#include "study_outputs.hpp"

namespace lftrack::studies {

using loop::check_correlation_model_spec;
using loop::CorrelationModel;
using loop::CorrelationModelSpec;
using loop::model_window_at;
using loop::rate_window_at;
using loop::SurrogateSample;
using loop::SurrogateStream;
namespace {

namespace fs = std::filesystem;
constexpr std::int64_t kNsPerS = 1'000'000'000;

// The registrations' noise: one stream per seed, apart from the surrogate's (seeded by o.seed),
// the same for every X-ray rate and for imaging every correction.
std::uint64_t registration_seed(const SurrogateStudyOptions& o) {
  return o.seed ^ 0x5851F42D4C957F2Dull;
}
constexpr const char* kSurrogateOutputs[] = {"surrogate.csv", "surrogate_trace.png", "surrogate_trace.dat",
                                             "surrogate_trace.gp"};

Eigen::Vector3d target_at(const sim_spec::PatientMotionSpec& motion, double t_s) {
  return sim::patient_offset(motion, t_s).head<3>();
}

void summarise(std::vector<double> errors, SurrogateStudyRow* row) {
  row->corrections = std::int64_t(errors.size());
  if (errors.empty()) return;
  double sum2 = 0, worst = 0;
  for (double e : errors) {
    sum2 += e * e;
    worst = std::max(worst, e);
  }
  row->rms_mm = std::sqrt(sum2 / double(errors.size()));
  row->max_mm = worst;
  row->p95_mm = quantile(std::move(errors), 0.95);
}

// One run of the model at `xray_hz`; the trace is filled when asked for.
SurrogateStudyRow run_model(const SurrogateStudyOptions& o, double xray_hz, SurrogateTrace* trace) {
  SurrogateStudyRow row;
  row.imaging = fmt::format("model, {:g} Hz X-rays", xray_hz);
  row.xray_hz = xray_hz;
  sim::BreathingSurrogate chest(o.surrogate);
  std::mt19937_64 random(registration_seed(o));
  std::normal_distribution<double> registration_noise(0.0, o.registration_sd_mm);
  CorrelationModelSpec spec = o.model;
  spec.window = model_window_at(o.model, xray_hz);
  CorrelationModel model(spec);
  SurrogateStream stream(rate_window_at(o.surrogate.sample_rate_hz));
  bool tracing = trace != nullptr, traced = false;  // the trace: one stretch without a gap
  // Every event on one integer clock: surrogate readings, corrections and X-rays. The k-th event of
  // a stream at f Hz is at floor(k 1e9 / f) ns from its start (not k rounded periods, which drift
  // apart: a reading then never falls on a correction). X-rays start half a period in; an early
  // pair moves the schedule on from itself.
  const auto at = [](std::int64_t k, double hz, std::int64_t from) {
    return from + std::int64_t(std::floor(double(k) * 1e9 / hz));
  };
  const std::int64_t end_ns = std::int64_t(o.duration_s * 1e9);
  std::int64_t k_reading = 0, k_correction = 1, k_xray = 0, xray_from = at(1, 2 * xray_hz, 0);
  std::int64_t next_reading = 0, next_correction = at(1, o.correction_hz, 0), next_xray = xray_from;
  std::int64_t last_early_ns = -kNsPerS;
  std::vector<double> errors;
  int pairs = 0;
  while (true) {
    const std::int64_t t = std::min({next_reading, next_correction, next_xray});
    if (t > end_ns) break;
    const double t_s = double(t) / kNsPerS;
    if (t == next_reading) {
      stream.push(t, chest.sample(t_s));
      SurrogateSample reading;
      if (stream.newest(&reading)) model.observe(reading);
      next_reading = at(++k_reading, o.surrogate.sample_rate_hz, 0);
      continue;  // a reading first: corrections and X-rays at the same time see it
    }
    SurrogateSample now;
    const bool have_rate = stream.newest(&now);
    if (t == next_xray) {
      next_xray = at(++k_xray, xray_hz, xray_from);
      if (!have_rate) continue;
      ++pairs;
      Eigen::Vector3d registered = target_at(o.motion, t_s);
      for (int k = 0; k < 3; ++k) registered[k] += registration_noise(random);
      switch (model.check(now, registered)) {
        case CorrelationModel::Check::kMissRefitted:
          ++row.refits;
          break;
        case CorrelationModel::Check::kMissAgain:
          ++row.holds;
          model.reset();  // the loop holds, aligns again and starts a new model
          break;
        default:
          break;
      }
      if (model.ready() && row.first_ready_s < 0) row.first_ready_s = t_s;
      if (tracing && traced) {
        trace->xray_t_s.push_back(t_s);
        trace->xray_si_mm.push_back(registered.z());
      }
    }
    if (t == next_correction) {
      next_correction = at(++k_correction, o.correction_hz, 0);
      if (!have_rate || !model.ready()) {
        if (traced) tracing = false;  // the trace ends at the model's first gap
        continue;
      }
      // A reading beyond the breaths the model was fitted on: an X-ray pair now, not a guess (at
      // most one early pair a second).
      if (!model.within_fit(now) && t - last_early_ns >= kNsPerS) {
        ++row.early_pairs;
        last_early_ns = t;
        xray_from = t + 1;  // the next event: this correction's pair, and the schedule on from it
        k_xray = 0;
        next_xray = xray_from;
      }
      const Eigen::Vector3d predicted = model.predict(now), truth = target_at(o.motion, t_s);
      errors.push_back((predicted - truth).norm());
      if (tracing && (!traced || t_s - trace->t_s.front() <= 30)) {
        traced = true;
        trace->t_s.push_back(t_s);
        trace->true_si_mm.push_back(truth.z());
        trace->predicted_si_mm.push_back(predicted.z());
        trace->surrogate.push_back(now.amplitude);
      }
    }
  }
  row.pairs_per_minute = 60.0 * pairs / o.duration_s;
  summarise(std::move(errors), &row);
  if (row.first_ready_s < 0) row.never_ready_because = model.not_ready_reason();
  return row;
}

}  // namespace

Status check_surrogate_study_options(const SurrogateStudyOptions& o) {
  LFTRACK_RETURN_IF_ERROR(check_correlation_model_spec(o.model));
  if (!(o.correction_hz >= 1 && o.correction_hz <= 100))
    return invalid_argument(fmt::format(
        "surrogate study: the scene's correction rate, {:g} Hz (1000 / loop.period_ms), must be 1..100 Hz",
        o.correction_hz));
  if (o.xray_hz.empty()) return invalid_argument("surrogate study: no X-ray rate");
  // The most pairs a model keeps must span a breathing cycle with model_window_at's quarter to
  // spare (early pairs shorten the span): more X-rays, never no model.
  const double most_hz =
      double(CorrelationModel::kCapacity - 1) / (1.25 * std::max(o.model.min_span_s, 1e-9));
  for (double hz : o.xray_hz) {
    if (!(hz >= 0.05 && hz <= o.correction_hz))
      return invalid_argument(
          fmt::format("surrogate study: an X-ray rate of {} Hz (0.05 Hz to the correction rate, {:g} Hz)", hz,
                      o.correction_hz));
    if (hz > most_hz)
      return invalid_argument(
          fmt::format("surrogate study: at {:g} Hz the model's {} pairs span less than a breathing cycle "
                      "({:g} s): at most "
                      "{:.3g} Hz",
                      hz, CorrelationModel::kCapacity, o.model.min_span_s, most_hz));
  }
  if (!(o.surrogate.sample_rate_hz >= o.correction_hz && o.surrogate.sample_rate_hz <= 1000))
    return invalid_argument("surrogate study: the surrogate's rate must be the correction rate..1000 Hz");
  if (!(o.duration_s >= 10 && o.duration_s <= 24 * 3600))
    return invalid_argument("surrogate study: the duration must be 10 s..24 h");
  if (!(o.registration_sd_mm >= 0 && o.registration_sd_mm <= 10))
    return invalid_argument("surrogate study: the registration's deviation must be 0..10 mm");
  if (!(o.surrogate.period_s >= 1 && o.surrogate.period_s <= 20))
    return invalid_argument("surrogate study: the breathing period must be 1..20 s");
  for (double v : {o.surrogate.amplitude, o.surrogate.lead_s, o.surrogate.drift_per_s, o.surrogate.noise_sd})
    if (!std::isfinite(v) || std::abs(v) > 1000)
      return invalid_argument("surrogate study: a surrogate setting is absurd");
  if (!(o.surrogate.noise_sd >= 0))
    return invalid_argument("surrogate study: the surrogate's noise must be >= 0");
  if (!(std::abs(o.surrogate.amplitude) > 0))
    return invalid_argument("surrogate study: the surrogate does not move");
  if (!o.motion.breathing_amplitude.allFinite() || !o.motion.drift_per_s.allFinite())
    return invalid_argument("surrogate study: the target's motion is not finite");
  if (o.motion.breathing_amplitude.head<3>().cwiseAbs().maxCoeff() > 50)
    return invalid_argument(
        "surrogate study: the target's breathing must stay within 50 mm per axis (as a scene's)");
  return {};
}

Result<SurrogateStudy> run_surrogate_study(const SurrogateStudyOptions& o) {
  LFTRACK_RETURN_IF_ERROR(check_surrogate_study_options(o));
  SurrogateStudy study;
  for (double hz : o.xray_hz) {
    // The plot shows the first rate whose model was ever used.
    const bool traced = !study.trace.t_s.empty();
    study.rows.push_back(run_model(o, hz, traced ? nullptr : &study.trace));
    if (!traced) study.trace_xray_hz = hz;
    if (!traced && study.trace.t_s.empty()) study.trace = {};
  }
  // Imaging every correction: the registration's error alone.
  SurrogateStudyRow every;
  every.imaging = fmt::format("every correction, {:g} Hz", o.correction_hz);
  every.xray_hz = o.correction_hz;
  every.pairs_per_minute = 60 * o.correction_hz;
  every.first_ready_s = 0;
  std::mt19937_64 random(registration_seed(o));
  std::normal_distribution<double> noise(0.0, o.registration_sd_mm);
  std::vector<double> errors(std::size_t(o.duration_s * o.correction_hz));
  for (double& e : errors) e = Eigen::Vector3d(noise(random), noise(random), noise(random)).norm();
  summarise(std::move(errors), &every);
  study.rows.push_back(every);
  return study;
}

Status check_surrogate_study_out(const fs::path& out_dir) {
  return refuse_existing_outputs(out_dir, kSurrogateOutputs);
}

Result<bool> write_surrogate_study(const SurrogateStudy& s, const SurrogateStudyOptions& o,
                                   const fs::path& out_dir) {
  LFTRACK_RETURN_IF_ERROR(check_surrogate_study_out(out_dir));
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  if (ec) return io_error(out_dir.string() + ": cannot create: " + ec.message());
  {
    std::ofstream csv(out_dir / "surrogate.csv");
    if (!csv)
      return io_error((out_dir / "surrogate.csv").string() + ": cannot write: " + std::strerror(errno));
    csv << "imaging,xray_hz,pairs_per_minute,corrections,rms_mm,p95_mm,max_mm,refits,holds,early_pairs,"
           "first_ready_s,never_ready_because\n";
    for (const SurrogateStudyRow& r : s.rows) {
      // A model never ready has no figures: empty, not zero.
      const bool used = r.corrections > 0;
      const auto figure = [used](double v) { return used ? fmt::format("{:.4f}", v) : std::string(); };
      csv << fmt::format("\"{}\",{:g},{:.1f},{},{},{},{},{},{},{},{},\"{}\"\n", r.imaging, r.xray_hz,
                         r.pairs_per_minute, r.corrections, figure(r.rms_mm), figure(r.p95_mm),
                         figure(r.max_mm), r.refits, r.holds, r.early_pairs,
                         r.first_ready_s >= 0 ? fmt::format("{:.2f}", r.first_ready_s) : std::string(),
                         r.never_ready_because);
    }
    csv.flush();
    if (!csv) return io_error((out_dir / "surrogate.csv").string() + ": write failed (disk full?)");
  }
  if (s.trace.t_s.empty()) return false;
  LinePlot plot;
  plot.title = fmt::format("target superior-inferior: the model from {:g} Hz X-rays, the chest {:g} s ahead",
                           s.trace_xray_hz, o.surrogate.lead_s);
  plot.x_label = "time (s)";
  plot.y_label = "superior-inferior (mm)";
  plot.x = s.trace.t_s;
  plot.series = {{"true target", s.trace.true_si_mm}, {"model's prediction", s.trace.predicted_si_mm}};
  // The X-ray pairs' registrations, at the corrections nearest them (a gap elsewhere).
  PlotSeries xrays{"X-ray pair (registered)", std::vector<double>(plot.x.size(), std::nan("")), true};
  for (std::size_t i = 0; i < s.trace.xray_t_s.size(); ++i) {
    const auto it = std::lower_bound(plot.x.begin(), plot.x.end(), s.trace.xray_t_s[i]);
    if (it != plot.x.end()) xrays.y[std::size_t(it - plot.x.begin())] = s.trace.xray_si_mm[i];
  }
  plot.series.push_back(xrays);
  plot.key_position = "top right";
  auto drawn = draw_line_plot(plot, out_dir / "surrogate_trace.png");
  if (!drawn.ok()) {
    spdlog::warn("no plot: {} (surrogate.csv is written)", drawn.status().message());
    return false;
  }
  return drawn;
}

}  // namespace lftrack::studies

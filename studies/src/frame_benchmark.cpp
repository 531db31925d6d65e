#include "lftrack/studies/frame_benchmark.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <optional>

#include "lftrack/session/scene_registration.hpp"
#include "lftrack/sim/synthetic_frames.hpp"
#include "lftrack/sim_devices/sim_detectors.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"
#include "lftrack/studies/drr_benchmark.hpp"
#include "lftrack/tracking/image_metrics.hpp"
#include "quantile.hpp"

namespace lftrack::studies {

using session::PreparedScene;
using session::SimDetectorsOptions;
using sim_devices::make_scene_patient;
using sim_devices::make_sim_frame_renderer;
using sim_devices::scene_detector_model;
using sim_devices::sim_frame_margin_px;
using sim_devices::SimDetectors;
using sim_devices::SimulatedPatient;
namespace {

using Clock = std::chrono::steady_clock;

double seconds_from(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// What renders the simulated detectors' frames of `scene` as the simulated loop builds it
// (loop_session.cpp): the renderer of ideal frames, or the realistic patient.
struct FrameRenderers {
  std::shared_ptr<const tracking::DrrRenderer> ideal;
  std::shared_ptr<const SimulatedPatient> patient;

  static Result<FrameRenderers> create(const PreparedScene& p, const std::filesystem::path& lf_dir,
                                       tracking::ThreadPool* pool) {
    FrameRenderers r;
    auto patient = make_scene_patient(p, lf_dir, pool);
    if (!patient.ok()) return patient.status();
    r.patient = *patient;
    if (!r.patient) {
      auto renderer = make_sim_frame_renderer(p, lf_dir, pool);
      if (!renderer.ok()) return renderer.status();
      r.ideal = *renderer;
    }
    return r;
  }
};

// The simulated detectors as SimFrameSource::open makes them (SimDetectors), and their frames.
struct BenchDetectors {
  std::optional<SimDetectors> detectors;
  std::vector<tracking::Image<std::uint16_t>> frames;

  static Result<BenchDetectors> create(const PreparedScene& p, const FrameRenderers& r, const sim::DetectorModel& model,
                                       bool whole_detector) {
    SimDetectorsOptions options;
    options.margin_px = sim_frame_margin_px(p);
    options.whole_detector = whole_detector;
    auto d = SimDetectors::create(p, r.ideal, r.patient, model, options);
    if (!d.ok()) return d.status();
    BenchDetectors b;
    b.detectors = std::move(d).value();
    b.frames = b.detectors->make_frames();
    return b;
  }
  Status expose(const tracking::Pose& pose, std::uint64_t seed) { return detectors->expose(pose, seed, &frames); }
};

// The counts of `frame` inside `window`, as floats.
tracking::Image<float> window_counts(const tracking::Image<std::uint16_t>& frame, const tracking::PixelWindow& w) {
  tracking::Image<float> out(w.rows, w.cols);
  for (int r = 0; r < w.rows; ++r)
    for (int c = 0; c < w.cols; ++c) out.at(r, c) = float(frame.at(w.row0 + r, w.col0 + c));
  return out;
}

// Each pose's noiseless frames (expected counts) as the loop's detectors expose them, no lag from
// an earlier frame, cropped to the ROI windows: what the registration sees of them.
Result<std::vector<std::vector<tracking::Image<float>>>> expected_frames(const PreparedScene& p,
                                                                        const FrameRenderers& renderers,
                                                                        const std::vector<tracking::Pose>& poses) {
  sim::DetectorModel model = scene_detector_model(p);
  model.noise = false;
  auto detectors = BenchDetectors::create(p, renderers, model, false);
  if (!detectors.ok()) return detectors.status();
  std::vector<std::vector<tracking::Image<float>>> out;
  for (const tracking::Pose& pose : poses) {
    detectors->detectors->forget_previous_frames();
    LFTRACK_RETURN_IF_ERROR(detectors->expose(pose, 1));
    out.emplace_back();
    for (std::size_t v = 0; v < detectors->frames.size(); ++v)
      out.back().push_back(window_counts(detectors->frames[v], p.roi_windows[v]));
  }
  return out;
}

}  // namespace

Result<FrameBenchReport> run_frame_benchmark(const PreparedScene& scene, const FrameBenchOptions& o,
                                             tracking::ThreadPool* pool) {
  if (o.pairs < 1 || o.pairs > 1000000) return out_of_range("bench frames: --pairs must be in [1, 1000000]");
  FrameBenchReport report;
  report.scene = scene.scene.name;
  report.physics = sim_spec::describe(scene.scene.sim.physics);
  report.pairs = o.pairs;
  for (const auto& d : scene.scene.detectors) report.views.push_back(d.view.name);
  const auto poses = sample_envelope_poses(scene, o.pairs, o.seed);
  // The fidelity poses: a handful is enough for a mean and a worst case.
  const std::vector<tracking::Pose> check_poses(poses.begin(), poses.begin() + std::min<std::ptrdiff_t>(4, o.pairs));
  std::vector<std::vector<tracking::Image<float>>> siddon_expected;
  for (const char* name : {"siddon", "lightfield"}) {
    PreparedScene p = scene;
    p.scene.sim.renderer = name;
    FrameRendererFigures fig;
    fig.renderer = name;
    spdlog::info("bench frames: {} renderer: setting up", name);
    const auto t0 = Clock::now();
    auto renderers = FrameRenderers::create(p, o.light_field_dir, pool);
    if (!renderers.ok()) return renderers.status().with_context(std::string("the ") + name + " frames");
    fig.setup_s = seconds_from(t0);
    // The ROI windows alone, and the whole detectors (the windows and the rest, coarser), timed
    // pose by pose side by side.
    auto windows = BenchDetectors::create(p, *renderers, scene_detector_model(p), false);
    if (!windows.ok()) return windows.status();
    auto whole = BenchDetectors::create(p, *renderers, scene_detector_model(p), true);
    if (!whole.ok()) return whole.status();
    fig.exposed_pixels = int(windows->detectors->written_pixels());
    fig.whole_detector_pixels = whole->detectors->written_pixels();
    LFTRACK_RETURN_IF_ERROR(windows->expose(poses[0], o.seed));  // warm: first touches of the data
    LFTRACK_RETURN_IF_ERROR(whole->expose(poses[0], o.seed));
    std::vector<double> ms, whole_ms;
    for (std::size_t k = 0; k < poses.size(); ++k) {
      const std::uint64_t seed = o.seed * 1000003ull + k * 7919ull;
      auto t = Clock::now();
      LFTRACK_RETURN_IF_ERROR(windows->expose(poses[k], seed));
      ms.push_back(1e3 * seconds_from(t));
      t = Clock::now();
      LFTRACK_RETURN_IF_ERROR(whole->expose(poses[k], seed));
      whole_ms.push_back(1e3 * seconds_from(t));
    }
    fig.pair_ms_median = quantile(ms, 0.5);
    fig.pair_ms_p95 = quantile(ms, 0.95);
    fig.pair_ms_min = *std::min_element(ms.begin(), ms.end());
    fig.whole_pair_ms_median = quantile(whole_ms, 0.5);
    fig.whole_pair_ms_p95 = quantile(whole_ms, 0.95);
    auto expected = expected_frames(p, *renderers, check_poses);
    if (!expected.ok()) return expected.status();
    if (siddon_expected.empty()) {  // the reference itself
      siddon_expected = std::move(expected).value();
      fig.ncc_vs_siddon = fig.ncc_min_vs_siddon = 1;
    } else {
      double sum = 0, worst = 1;
      int n = 0;
      for (std::size_t k = 0; k < check_poses.size(); ++k)
        for (std::size_t v = 0; v < report.views.size(); ++v) {
          const double ncc =
              tracking::normalized_cross_correlation(siddon_expected[k][v].view(), (*expected)[k][v].view());
          sum += ncc;
          worst = std::isfinite(ncc) ? std::min(worst, ncc) : ncc;  // NaN (a non-finite count) stays NaN
          ++n;
        }
      fig.ncc_vs_siddon = sum / n;
      fig.ncc_min_vs_siddon = std::isfinite(fig.ncc_vs_siddon) ? worst : fig.ncc_vs_siddon;
    }
    report.renderers.push_back(fig);
  }
  for (auto& f : report.renderers) f.speedup_vs_siddon = report.renderers[0].pair_ms_median / f.pair_ms_median;
  return report;
}

nlohmann::json to_json(const FrameBenchReport& r) {
  nlohmann::json renderers = nlohmann::json::array();
  for (const auto& f : r.renderers)
    renderers.push_back({{"renderer", f.renderer},
                         {"setup_s", f.setup_s},
                         {"exposed_pixels", f.exposed_pixels},
                         {"whole_detector_pixels", f.whole_detector_pixels},
                         {"whole_pair_ms", {{"median", f.whole_pair_ms_median}, {"p95", f.whole_pair_ms_p95}}},
                         {"pair_ms", {{"median", f.pair_ms_median}, {"p95", f.pair_ms_p95}, {"min", f.pair_ms_min}}},
                         {"speedup_vs_siddon", f.speedup_vs_siddon},
                         {"ncc_vs_siddon", f.ncc_vs_siddon},
                         {"ncc_min_vs_siddon", f.ncc_min_vs_siddon}});
  return {{"scene", r.scene}, {"physics", r.physics},     {"pairs", r.pairs},
          {"views", r.views}, {"renderers", renderers}, {"threads", 1}};
}

}  // namespace lftrack::studies

// The daily QA's detector checks (daily_qa.hpp, DetectorQaOptions): each detector's frames of
// today against the calibration the loop corrects it with.

#include <fmt/format.h>

#include <algorithm>
#include <optional>

#include "daily_qa_runs.hpp"
#include "lftrack/qa/daily_qa.hpp"
#include "lftrack/session/detector_calibration_file.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/session/scene_exposure.hpp"
#include "lftrack/sim/panel_frames.hpp"
#include "lftrack/sim/synthetic_frames.hpp"

namespace lftrack::qa {
namespace {

// A simulated detector's baseline from twice the frames of today's (at least 16 of each).
constexpr int kBaselineFramesPerToday = 2;
constexpr std::uint64_t kBaselineSeed = 1, kTodaySeed = 2;
constexpr double kFloodOfFullScale = 0.5;

// Frames a simulated panel gives today: the tolerances' minimum (at least calib::kMinQaFrames).
int frames_today(const DetectorQaOptions& o) {
  return std::max(calib::kMinQaFrames, o.tolerances.min_frames);
}

// Detector `i`'s panel as the simulator models it (sim/panel_frames.hpp).
sim::PanelSpec panel_of(const session::PreparedScene& p, std::size_t i) {
  const session::DetectorSpec& d = p.scene.detectors[i];
  sim::PanelSpec s;
  s.rows = d.view.rows;
  s.cols = d.view.cols;
  s.bits = d.bits;
  s.open_field_fraction = kFloodOfFullScale;
  s.photons_per_pixel =
      p.scene.sim.photons_per_pixel * kFloodOfFullScale / session::kReferenceOpenFieldFraction;
  // The same fixed pattern as the loop's frames of this detector (sim_detectors.cpp: seed i + 1).
  if (p.scene.sim.physics.detector)
    s.effects = sim::effects_of_detector(*p.scene.sim.physics.detector, i + 1);
  return s;
}

Result<DetectorFrames> panel_frames(const sim::PanelSpec& panel, int count, std::uint64_t seed) {
  DetectorFrames f;
  auto dark = sim::simulate_panel_frames(panel, false, count, seed);
  if (!dark.ok()) return dark.status();
  auto flood = sim::simulate_panel_frames(panel, true, count, seed);
  if (!flood.ok()) return flood.status();
  f.dark = std::move(dark).value();
  f.flood = std::move(flood).value();
  return f;
}

// What detector `i` is judged against: its file, or its simulated panel's calibration.
Result<calib::DetectorCalibration> baseline_of(const session::PreparedScene& p, std::size_t i, bool simulated,
                                               int today_frames, std::string* source) {
  const session::DetectorSpec& d = p.scene.detectors[i];
  if (!d.calibration_file.empty()) {
    *source = "calibration " + d.calibration_file;
    auto loaded = session::load_detector_calibration(d.calibration_file);
    if (loaded.ok() && !loaded->detector.empty() && loaded->detector != d.view.name)
      return failed_precondition(fmt::format("{} was made for detector '{}', not '{}'", d.calibration_file,
                                             loaded->detector, d.view.name));
    return loaded;
  }
  if (!simulated)
    return failed_precondition(
        "detector " + d.view.name + " has no calibration file to judge it against" +
        (d.simulator_calibration ? " (`calibration: simulator` is the served twin's model, not a calibration)"
                                 : "") +
        ": name one as detectors[].calibration (lftrack calibrate detector)");
  *source = "its simulated panel's calibration, made now";
  auto frames = panel_frames(panel_of(p, i), kBaselineFramesPerToday * today_frames, kBaselineSeed);
  if (!frames.ok()) return frames.status();
  calib::DetectorCalibrationOptions rule;
  rule.bits = d.bits;
  auto made = calib::calibrate_detector(frames->dark, frames->flood, rule);
  if (made.ok()) made->detector = d.view.name;
  return made;
}

Result<DetectorFrames> today_of(const session::PreparedScene& p, std::size_t i, bool simulated,
                                const DetectorQaOptions& o, std::string* source) {
  if (!o.frames.empty()) {
    *source = "the frames given";
    if (!o.frames[i].unreadable.empty()) return invalid_argument(o.frames[i].unreadable);
    return o.frames[i];
  }
  if (!simulated)
    return failed_precondition(
        "no frames of today were given for detector " + p.scene.detectors[i].view.name +
        " (qa detector --frames DIR or qa daily --detector-frames DIR: DIR/" +
        p.scene.detectors[i].view.name + "/dark and DIR/" + p.scene.detectors[i].view.name + "/flood)");
  *source = "its simulated panel's frames";
  return panel_frames(panel_of(p, i), frames_today(o), kTodaySeed);
}

std::string tolerance_text(const calib::DetectorQaTolerances& t) {
  return fmt::format(
      "dark drift within {} % of the open field, temporal noise within x{} (and above x1/{}), flat-field "
      "non-uniformity within {} %, new defects within {} % of the pixels and no new defective line",
      100 * t.max_dark_drift_fraction, t.max_noise_ratio, t.max_noise_ratio, 100 * t.max_nonuniformity,
      100 * t.max_new_defect_fraction);
}

}  // namespace

std::vector<QaCheck> detector_checks(const session::PreparedScene& p, const DetectorQaOptions& o,
                                     const std::function<void(const std::string&)>& progress) {
  const bool simulated = session::frames_are_simulated(p.scene);
  std::vector<QaCheck> checks;
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    QaCheck c;
    c.name = "detector " + p.scene.detectors[i].view.name;
    c.tolerance = tolerance_text(o.tolerances);
    std::string baseline_source, today_source;
    auto judged = [&]() -> Result<calib::DetectorQaResult> {
      auto baseline = baseline_of(p, i, simulated, frames_today(o), &baseline_source);
      if (!baseline.ok()) return baseline.status().with_context("the baseline");
      auto today = today_of(p, i, simulated, o, &today_source);
      if (!today.ok()) return today.status();
      if (o.fault) o.fault(int(i), &*today);
      return calib::check_detector_quality(*baseline, today->dark, today->flood, o.tolerances);
    }();
    if (judged.ok()) {
      c.passed = judged->passed;
      c.why = judged->why;
      c.measured = fmt::format("{} (today: {}; against {})", judged->measured, today_source, baseline_source);
    } else {
      c.why = judged.status().message();
      c.measured = "not judged";
    }
    if (progress) progress(c.name + ": " + (c.passed ? "pass (" + c.measured + ")" : "FAIL: " + c.why));
    checks.push_back(std::move(c));
  }
  return checks;
}

std::optional<std::string> simulated_detector_note(const session::PreparedScene& p,
                                                   const DetectorQaOptions& o) {
  if (!session::frames_are_simulated(p.scene) || !o.frames.empty()) return std::nullopt;
  for (const session::DetectorSpec& d : p.scene.detectors)
    if (d.calibration_file.empty())
      return "a drift of the detectors: a simulated panel has no history, so each is judged against its own "
             "calibration made as the QA starts; that runs the check (its faults are tested), not a detector";
  return std::nullopt;
}

Status check_detector_qa_options(const session::PreparedScene& p, const DetectorQaOptions& o) {
  LFTRACK_RETURN_IF_ERROR(calib::check_detector_qa_tolerances(o.tolerances));
  if (!o.frames.empty() && o.frames.size() != p.scene.detectors.size())
    return invalid_argument(fmt::format("frames were given for {} detectors; the scene has {}",
                                        o.frames.size(), p.scene.detectors.size()));
  return {};
}

Result<DailyQaReport> run_detector_qa(const session::PreparedScene& p, const DetectorQaOptions& o,
                                      const std::function<void(const std::string&)>& progress) {
  LFTRACK_RETURN_IF_ERROR(check_detector_qa_options(p, o));
  DailyQaReport report = new_report(p, "detector");
  report.checks = detector_checks(p, o, progress);
  report.not_checked = {"the offset test, the beam-permit path and the latency chain: lftrack qa daily"};
  if (auto note = simulated_detector_note(p, o)) report.not_checked.push_back(*note);
  return report;
}

}  // namespace lftrack::qa

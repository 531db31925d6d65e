#pragma once
// `lftrack study surrogate` (issue 58): the surrogate-to-target correlation model
// (correlation_model.hpp) on a scene's breathing, without images, so that the model itself is
// measured apart from the registration. The target moves as the scene's motion says (its
// translations: breathing and drift, or breathing given here); a simulated chest marker
// (breathing_surrogate.hpp) streams at its rate with its lead, drift and noise; an X-ray pair every
// 1 / xray_hz seconds registers the target with Gaussian error of registration_sd_mm per axis and
// is checked against the model (a miss refits it; a second miss in a row is a HOLD, after which
// the model starts again, as the loop's would); and at every correction (correction_hz) the model
// predicts the target from the newest surrogate reading; a reading beyond the breaths it was fitted
// on takes an X-ray pair early (counted among the pairs). The error is the prediction against the
// true target, 3D, over every correction while the model is ready. Imaging every correction is the
// row beside it: its error is the registration's alone, at 60 * correction_hz pairs per minute.

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/loop/correlation_model.hpp"
#include "lftrack/sim_spec/breathing_surrogate_spec.hpp"
#include "lftrack/sim_spec/patient_motion_spec.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::studies {

struct SurrogateStudyOptions {
  sim_spec::PatientMotionSpec motion;  // the target's: translations (mm) of the registration origin
  sim_spec::BreathingSurrogateSpec surrogate;
  loop::CorrelationModelSpec model;
  std::vector<double> xray_hz{0.5, 1, 2};
  double correction_hz = 30;
  double duration_s = 300;
  double registration_sd_mm = 0.1;  // per axis
  std::uint64_t seed = 1;
};

Status check_surrogate_study_options(const SurrogateStudyOptions& options);
// Whether `out_dir` can take the study's files: none of their names there. Checked before the
// study runs, and again before writing.
Status check_surrogate_study_out(const std::filesystem::path& out_dir);

struct SurrogateStudyRow {
  std::string imaging;  // "model, 1 Hz X-rays" or "every correction, 30 Hz"
  double xray_hz = 0;
  double pairs_per_minute = 0;
  std::int64_t corrections = 0;  // predicted (while the model was ready), or imaged
  double rms_mm = 0, p95_mm = 0, max_mm = 0;
  int refits = 0;                   // misses the model was refitted after
  int holds = 0;                    // second misses in a row
  int early_pairs = 0;              // taken because a reading left the fitted breaths (within_fit)
  double first_ready_s = -1;        // when the model could first be used (-1: never)
  std::string never_ready_because;  // the model's reason, where it never was
};

struct SurrogateTrace {  // up to 30 s of one X-ray rate from its model's first use, without a gap
  std::vector<double> t_s, true_si_mm, predicted_si_mm, surrogate;
  std::vector<double> xray_t_s, xray_si_mm;
};

struct SurrogateStudy {
  std::vector<SurrogateStudyRow> rows;
  SurrogateTrace trace;  // of the first X-ray rate whose model was used
  double trace_xray_hz = 0;
};

Result<SurrogateStudy> run_surrogate_study(const SurrogateStudyOptions& options);

// `out_dir`/surrogate.csv (the rows; a model never ready has empty figures and its reason),
// surrogate_trace.png (its .dat and .gp beside it) where a model was used. Refuses to replace files
// of those names. Returns whether the PNG was drawn; a plot that fails is a warning (the CSV
// stands), not an error.
Result<bool> write_surrogate_study(const SurrogateStudy& study, const SurrogateStudyOptions& options,
                                   const std::filesystem::path& out_dir);

}  // namespace lftrack::studies

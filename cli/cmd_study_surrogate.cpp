// `lftrack study surrogate --scene S --out DIR`: the surrogate-to-target correlation model on the
// scene's breathing, without images (surrogate_study.hpp): its error at X-ray rates beside
// imaging every correction, a CSV and a plot of the first 30 s.

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>

#include "cli_commands.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/studies/surrogate_study.hpp"

namespace lftrack::cli {

using session::load_scene;

using studies::check_surrogate_study_out;
using studies::run_surrogate_study;
using studies::SurrogateStudyOptions;
using studies::SurrogateStudyRow;
using studies::write_surrogate_study;

using loop::CorrelationModelSpec;

Command add_study_surrogate_command(CLI::App* parent) {
  struct Options {
    std::string scene = "builtin:phantom";
    std::string out_dir;
    std::string xray_hz = "0.5,1,2";
    std::vector<double> breathing_mm;  // empty: the scene's
    double lead_s = 0.2, drift_mm_per_min = 0.5, noise_mm = 0.1, surrogate_mm = 10, surrogate_hz = 60;
    double registration_sd_mm = 0.1, duration_s = 300, tolerance_mm = 1.5;
    std::string model = "linear";
    bool no_hysteresis = false;
    std::uint64_t seed = 1;
  };
  auto o = std::make_shared<Options>();
  auto* app = parent->add_subcommand(
      "surrogate",
      "The breathing surrogate's correlation model on the scene's breathing, without images: its error "
      "against the true target with X-ray pairs at a few Hz, beside imaging every correction");
  app->add_option("--scene", o->scene, "Scene file, or builtin:phantom (its motion and loop period)")
      ->check(not_empty());
  app->add_option("--out", o->out_dir,
                  "Folder for surrogate.csv and surrogate_trace.png (nothing in it is replaced)")
      ->required()
      ->check(not_empty());
  app->add_option("--xray-hz", o->xray_hz, "X-ray pair rates to compare (Hz, comma-separated)")
      ->capture_default_str();
  app->add_option("--breathing-mm", o->breathing_mm,
                  "The target's breathing amplitude X,Y,Z (mm, room frame; default the scene's)")
      ->delimiter(',')
      ->expected(3)
      ->check(finite_in(-50, 50));
  app->add_option("--lead-s", o->lead_s, "How far the chest runs ahead of the target (s)")
      ->check(CLI::Range(-2.0, 2.0));
  app->add_option("--drift-mm-per-min", o->drift_mm_per_min, "The surrogate's drift from the target (mm/min)")
      ->check(CLI::Range(-60.0, 60.0));
  app->add_option("--noise-mm", o->noise_mm, "The surrogate's noise (mm, one deviation)")
      ->check(CLI::Range(0.0, 10.0));
  app->add_option("--surrogate-mm", o->surrogate_mm, "The chest marker's travel, exhale to inhale (mm)")
      ->check(CLI::Range(0.1, 100.0));
  app->add_option("--surrogate-hz", o->surrogate_hz, "The surrogate's stream rate (Hz)")
      ->check(CLI::Range(1.0, 1000.0));
  app->add_option("--registration-sd-mm", o->registration_sd_mm,
                  "Each X-ray registration's error per axis (mm)")
      ->check(CLI::Range(0.0, 10.0));
  app->add_option("--duration-s", o->duration_s, "Seconds of breathing")->check(CLI::Range(10.0, 86400.0));
  app->add_option("--model", o->model, "linear or quadratic")->check(CLI::IsMember({"linear", "quadratic"}));
  app->add_flag("--no-hysteresis", o->no_hysteresis,
                "Leave out the rate term (inhale and exhale on one curve)");
  app->add_option("--tolerance-mm", o->tolerance_mm,
                  "A check further than this (3D) from the registration misses")
      ->check(CLI::Range(0.01, 20.0));
  app->add_option("--seed", o->seed, "Seed of the surrogate's and the registrations' noise")
      ->check(seed_value());
  return [o, app]() -> Status {
    if (!app->parsed()) return {};
    LFTRACK_RETURN_IF_ERROR(check_surrogate_study_out(o->out_dir));  // before the study, not after it
    auto scene = load_scene(o->scene);
    if (!scene.ok()) return scene.status();
    SurrogateStudyOptions options;
    options.motion = scene->motion.motion;
    options.motion.shifts.clear();  // a sudden shift is the loop's to hold, not the model's to follow
    if (!o->breathing_mm.empty())
      options.motion.breathing_amplitude.head<3>() =
          Eigen::Vector3d(o->breathing_mm[0], o->breathing_mm[1], o->breathing_mm[2]);
    options.surrogate.amplitude = o->surrogate_mm;
    options.surrogate.period_s = options.motion.breathing_period_s;
    options.surrogate.lead_s = o->lead_s;
    options.surrogate.drift_per_s = o->drift_mm_per_min / 60;
    options.surrogate.noise_sd = o->noise_mm;
    options.surrogate.sample_rate_hz = o->surrogate_hz;
    options.surrogate.seed = o->seed;
    options.model.order =
        o->model == "linear" ? CorrelationModelSpec::Order::kLinear : CorrelationModelSpec::Order::kQuadratic;
    options.model.hysteresis = !o->no_hysteresis;
    options.model.min_span_s = options.motion.breathing_period_s;
    options.model.tolerance_mm = o->tolerance_mm;
    // Each rate a number: CLI11's list splitting would drop an empty one ("1,,2") unseen.
    options.xray_hz.clear();
    std::size_t from = 0;
    while (true) {
      const std::size_t comma = o->xray_hz.find(',', from);
      const std::string item =
          o->xray_hz.substr(from, comma == std::string::npos ? std::string::npos : comma - from);
      char* end = nullptr;
      const double hz = std::strtod(item.c_str(), &end);
      if (item.empty() || end != item.c_str() + item.size() || !std::isfinite(hz))
        return invalid_argument("--xray-hz: '" + item + "' in '" + o->xray_hz + "' is not a rate in Hz");
      options.xray_hz.push_back(hz);
      if (comma == std::string::npos) break;
      from = comma + 1;
    }
    options.correction_hz = 1000.0 / scene->loop.period_ms;
    options.duration_s = o->duration_s;
    options.registration_sd_mm = o->registration_sd_mm;
    options.seed = o->seed;
    auto study = run_surrogate_study(options);
    if (!study.ok()) return study.status();
    const auto& b = options.motion.breathing_amplitude;
    std::printf(
        "%s: target breathing [%.2g, %.2g, %.2g] mm every %.3g s; chest %.3g mm, %.3g s ahead, drift %.3g "
        "mm/min, noise %.3g mm at %.3g Hz; registrations %.3g mm per axis; %s model%s; %.0f s\n",
        scene->name.c_str(), b[0], b[1], b[2], options.motion.breathing_period_s, o->surrogate_mm, o->lead_s,
        o->drift_mm_per_min, o->noise_mm, o->surrogate_hz, o->registration_sd_mm, o->model.c_str(),
        o->no_hysteresis ? "" : " with the rate term", o->duration_s);
    std::printf("%-28s %10s %11s %9s %9s %9s %7s %6s %6s %8s\n", "imaging", "pairs/min", "corrections",
                "rms mm", "p95 mm", "max mm", "refits", "holds", "early", "ready s");
    for (const SurrogateStudyRow& r : study->rows) {
      if (r.corrections == 0) {  // never ready: no figures, not zeros
        std::printf("%-28s %10.1f %11d %9s %9s %9s %7d %6d %6d %8s\n", r.imaging.c_str(), r.pairs_per_minute,
                    0, "-", "-", "-", r.refits, r.holds, r.early_pairs, "never");
        continue;
      }
      std::printf("%-28s %10.1f %11lld %9.3f %9.3f %9.3f %7d %6d %6d %8.1f\n", r.imaging.c_str(),
                  r.pairs_per_minute, static_cast<long long>(r.corrections), r.rms_mm, r.p95_mm, r.max_mm,
                  r.refits, r.holds, r.early_pairs, r.first_ready_s);
    }
    for (const SurrogateStudyRow& r : study->rows)
      if (!r.never_ready_because.empty())
        std::printf("%s: the model was never ready: %s\n", r.imaging.c_str(), r.never_ready_because.c_str());
    auto drawn = write_surrogate_study(*study, options, o->out_dir);
    if (!drawn.ok()) return drawn.status();
    if (*drawn)
      std::printf("wrote %s/{surrogate.csv,surrogate_trace.png}\n", o->out_dir.c_str());
    else if (study->trace.t_s.empty())
      std::printf("wrote %s/surrogate.csv; no plot: no model was ever ready\n", o->out_dir.c_str());
    else
      std::printf(
          "wrote %s/{surrogate.csv,surrogate_trace.dat,surrogate_trace.gp}; no PNG (gnuplot missing or "
          "failed: see the warning)\n",
          o->out_dir.c_str());
    return {};
  };
}

}  // namespace lftrack::cli

// The scene's imaging on demand (imaging_on_demand.hpp): tracking.imaging and the surrogate section.

#include <fmt/format.h>

#include <algorithm>
#include <sstream>

#include "lftrack/drivers/igtl_surrogate.hpp"
#include "scene_yaml.hpp"

namespace lftrack::session {

using loop::check_correlation_model_spec;
using loop::CorrelationModel;
using loop::CorrelationModelSpec;
using loop::ImagingSpec;
using loop::SurrogateLimits;

// A number in [lo, hi], with what the range means when it is refused.
Status SceneParser::number_in(const YAML::Node& n, const std::string& what, double lo, double hi,
                              const std::string& why, double* out) const {
  LFTRACK_RETURN_IF_ERROR(number(n, what, out));
  if (*out < lo || *out > hi) {
    std::ostringstream m;
    m << what << " must be in " << lo << ".." << hi << " (" << why << "), got " << n.Scalar();
    return error(n, m.str());
  }
  return {};
}

Status SceneParser::parse_imaging(const YAML::Node& n, ImagingSpec* imaging, ImagingTechniqueSpec* technique,
                                  bool* min_span_given) const {
  if (n.IsScalar()) {  // `tracking.imaging: model`, the mode alone
    std::string mode;
    LFTRACK_RETURN_IF_ERROR(one_of(n, "tracking.imaging", {"every_cycle", "model"}, &mode));
    imaging->mode = mode == "model" ? ImagingSpec::Mode::kModel : ImagingSpec::Mode::kEveryCycle;
    return {};
  }
  LFTRACK_RETURN_IF_ERROR(
      check_keys(n, "tracking.imaging", {"mode", "xray_hz", "stale_s", "model", "technique"}));
  if (n["mode"]) {
    std::string mode;
    LFTRACK_RETURN_IF_ERROR(one_of(n["mode"], "tracking.imaging.mode", {"every_cycle", "model"}, &mode));
    imaging->mode = mode == "model" ? ImagingSpec::Mode::kModel : ImagingSpec::Mode::kEveryCycle;
  }
  if (n["xray_hz"])
    LFTRACK_RETURN_IF_ERROR(number_in(n["xray_hz"], "tracking.imaging.xray_hz", 0.05, 100,
                                      "X-ray pairs per second; at most the loop's rate", &imaging->xray_hz));
  if (n["stale_s"])
    LFTRACK_RETURN_IF_ERROR(number_in(n["stale_s"], "tracking.imaging.stale_s", 0.1, 600,
                                      "a model unconfirmed this long takes a pair", &imaging->stale_s));
  if (const YAML::Node m = n["model"]) {
    CorrelationModelSpec& model = imaging->model;
    LFTRACK_RETURN_IF_ERROR(
        check_keys(m, "tracking.imaging.model",
                   {"order", "hysteresis", "window", "min_pairs", "min_span_s", "tolerance_mm"}));
    if (m["order"]) {
      std::string order;
      LFTRACK_RETURN_IF_ERROR(
          one_of(m["order"], "tracking.imaging.model.order", {"linear", "quadratic"}, &order));
      model.order = order == "quadratic" ? CorrelationModelSpec::Order::kQuadratic
                                         : CorrelationModelSpec::Order::kLinear;
    }
    if (m["hysteresis"])
      LFTRACK_RETURN_IF_ERROR(
          boolean(m["hysteresis"], "tracking.imaging.model.hysteresis", &model.hysteresis));
    long value = 0;
    if (m["window"]) {
      LFTRACK_RETURN_IF_ERROR(
          integer(m["window"], "tracking.imaging.model.window", 4, CorrelationModel::kCapacity, &value));
      model.window = int(value);
    }
    if (m["min_pairs"]) {
      LFTRACK_RETURN_IF_ERROR(integer(m["min_pairs"], "tracking.imaging.model.min_pairs", 3,
                                      CorrelationModel::kCapacity, &value));
      model.min_pairs = int(value);
    }
    if (m["min_span_s"]) {
      LFTRACK_RETURN_IF_ERROR(number_in(m["min_span_s"], "tracking.imaging.model.min_span_s", 1, 60,
                                        "at least one breathing cycle", &model.min_span_s));
      *min_span_given = true;
    }
    if (m["tolerance_mm"])
      LFTRACK_RETURN_IF_ERROR(number_in(m["tolerance_mm"], "tracking.imaging.model.tolerance_mm", 0.1, 20,
                                        "a prediction this far from a pair's registration misses",
                                        &model.tolerance_mm));
    const Status checked = check_correlation_model_spec(model);
    if (!checked.ok()) return error(m, "tracking.imaging.model: " + checked.message());
  }
  if (const YAML::Node t = n["technique"]) {
    LFTRACK_RETURN_IF_ERROR(check_keys(t, "tracking.imaging.technique", {"kvp", "mas"}));
    if (t["kvp"])
      LFTRACK_RETURN_IF_ERROR(number_in(t["kvp"], "tracking.imaging.technique.kvp", 40, 150,
                                        "a diagnostic tube's range", &technique->kvp));
    if (t["mas"])
      LFTRACK_RETURN_IF_ERROR(number_in(t["mas"], "tracking.imaging.technique.mas", 0.01, 1000,
                                        "per view and pair", &technique->mas));
  }
  return {};
}

Status SceneParser::parse_surrogate(const YAML::Node& n, SurrogateSpec* surrogate,
                                    SurrogateLimits* limits) const {
  LFTRACK_RETURN_IF_ERROR(
      check_keys(n, "surrogate", {"source", "rate_hz", "stale_ms", "jump_mm", "freeze_s", "sim", "igtl"}));
  YAML::Node source;
  LFTRACK_RETURN_IF_ERROR(need(n, "source", "surrogate", &source));
  LFTRACK_RETURN_IF_ERROR(one_of(source, "surrogate.source", {"sim", "igtl"}, &surrogate->source));
  if (n["rate_hz"])
    LFTRACK_RETURN_IF_ERROR(
        number_in(n["rate_hz"], "surrogate.rate_hz", 5, 1000, "an optical tracker's rate", &limits->rate_hz));
  surrogate->sim.sample_rate_hz = limits->rate_hz;
  if (n["stale_ms"])
    LFTRACK_RETURN_IF_ERROR(number_in(n["stale_ms"], "surrogate.stale_ms", 1, 10000,
                                      "the newest reading older than this stops the model",
                                      &limits->stale_ms));
  if (n["jump_mm"])
    LFTRACK_RETURN_IF_ERROR(
        number_in(n["jump_mm"], "surrogate.jump_mm", 0.01, 1000, "between two readings", &limits->jump));
  if (n["freeze_s"])
    LFTRACK_RETURN_IF_ERROR(number_in(n["freeze_s"], "surrogate.freeze_s", 0.05, 60,
                                      "a reading unchanged this long is frozen", &limits->freeze_s));
  if (limits->stale_ms < 2e3 / limits->rate_hz) {
    std::ostringstream m;
    m << "surrogate.stale_ms (" << limits->stale_ms
      << " ms) must allow at least two readings at surrogate.rate_hz (" << limits->rate_hz
      << " Hz: " << 2e3 / limits->rate_hz << " ms)";
    return error(n["stale_ms"] ? n["stale_ms"] : n, m.str());
  }
  if (const YAML::Node s = n["sim"]) {
    LFTRACK_RETURN_IF_ERROR(
        check_keys(s, "surrogate.sim", {"amplitude_mm", "lead_s", "drift_mm_per_min", "noise_sd_mm"}));
    sim_spec::BreathingSurrogateSpec& b = surrogate->sim;
    if (s["amplitude_mm"])
      LFTRACK_RETURN_IF_ERROR(number_in(s["amplitude_mm"], "surrogate.sim.amplitude_mm", 0.1, 100,
                                        "a chest marker's travel", &b.amplitude));
    if (s["lead_s"])
      LFTRACK_RETURN_IF_ERROR(
          number_in(s["lead_s"], "surrogate.sim.lead_s", -2, 2, "the chest ahead of the target", &b.lead_s));
    if (s["drift_mm_per_min"]) {
      double per_min = 0;
      LFTRACK_RETURN_IF_ERROR(number_in(s["drift_mm_per_min"], "surrogate.sim.drift_mm_per_min", -60, 60,
                                        "the relation's slow change", &per_min));
      b.drift_per_s = per_min / 60;
    }
    if (s["noise_sd_mm"])
      LFTRACK_RETURN_IF_ERROR(number_in(s["noise_sd_mm"], "surrogate.sim.noise_sd_mm", 0, 10,
                                        "the tracker's noise", &b.noise_sd));
  }
  if (const YAML::Node g = n["igtl"]) {
    if (surrogate->source != "igtl") return error(g, "surrogate.igtl is for surrogate.source igtl");
    LFTRACK_RETURN_IF_ERROR(check_keys(g, "surrogate.igtl", {"host", "port", "device", "axis"}));
    if (g["host"]) LFTRACK_RETURN_IF_ERROR(text(g["host"], "surrogate.igtl.host", &surrogate->igtl_host));
    if (g["port"]) {
      long port = 0;
      LFTRACK_RETURN_IF_ERROR(integer(g["port"], "surrogate.igtl.port", 1, 65535, &port));
      surrogate->igtl_port = int(port);
    }
    if (g["device"]) {
      LFTRACK_RETURN_IF_ERROR(text(g["device"], "surrogate.igtl.device", &surrogate->igtl_device));
      if (const std::string why = drivers::igtl_device_name_problem(surrogate->igtl_device); !why.empty())
        return error(g["device"], "surrogate.igtl.device \"" + surrogate->igtl_device + "\": " + why);
    }
    if (g["axis"])
      LFTRACK_RETURN_IF_ERROR(unit_vec3(g["axis"], "surrogate.igtl.axis", &surrogate->igtl_axis));
  }
  return {};
}

// tracking.imaging and surrogate, once loop and motion are known: `model` needs a surrogate, whose
// simulated marker breathes with the patient, and a model spans a breath unless the scene says.
Status SceneParser::parse_imaging_sections(const YAML::Node& root, Scene* scene) const {
  ImagingSpec& imaging = scene->loop.imaging;
  bool min_span_given = false;
  const YAML::Node tracking = root["tracking"];
  // Where an error is reported: tracking.imaging, or the scene (a default YAML::Node is a null node,
  // which tests true: never a stand-in for "absent").
  const YAML::Node node = tracking && tracking["imaging"] ? tracking["imaging"] : root;
  if (tracking && tracking["imaging"])
    LFTRACK_RETURN_IF_ERROR(parse_imaging(node, &imaging, &scene->technique, &min_span_given));
  if (root["surrogate"]) {
    LFTRACK_RETURN_IF_ERROR(parse_surrogate(root["surrogate"], &scene->surrogate, &imaging.surrogate));
    scene->lines["surrogate"] = where(root["surrogate"]);
  }
  const double period_s = scene->motion.motion.breathing_period_s;
  scene->surrogate.sim.period_s = period_s;
  scene->surrogate.sim.seed = scene->sim.seed;
  // A model spans a breath; check_correlation_model_spec needs at least a second.
  if (!min_span_given) imaging.model.min_span_s = std::max(1.0, period_s);
  if (!imaging.model_mode()) return {};
  if (scene->surrogate.source.empty())
    return error(node, "tracking.imaging.mode model needs a `surrogate` section (source sim or igtl)");
  const double loop_hz = 1e3 / scene->loop.period_ms;
  const YAML::Node xray_node = node.IsMap() && node["xray_hz"] ? node["xray_hz"] : node;
  if (imaging.xray_hz > loop_hz) {
    std::ostringstream m;
    m << "tracking.imaging.xray_hz " << imaging.xray_hz << " is above the loop's rate (" << loop_hz
      << " Hz, loop.period_ms " << scene->loop.period_ms << ")";
    return error(xray_node, m.str());
  }
  if (imaging.stale_s <= 1 / imaging.xray_hz)
    return error(
        node,
        fmt::format("tracking.imaging.stale_s ({:g} s) must exceed the time between pairs (1 / xray_hz = "
                    "{:g} s); otherwise every pair comes early",
                    imaging.stale_s, 1 / imaging.xray_hz));
  if (double(CorrelationModel::kCapacity - 1) < 1.25 * imaging.model.min_span_s * imaging.xray_hz)
    return error(
        node, "tracking.imaging: at xray_hz the model's 64 pairs cannot span its min_span_s; lower xray_hz");
  return {};
}

}  // namespace lftrack::session

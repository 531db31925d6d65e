// The scene's host-loop sections: sim, loop, safety, actuator, motion.

#include <sstream>

#include "lftrack/session/calibration_files.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/registration.hpp"
#include "scene_yaml.hpp"

namespace lftrack::session {

using loop::LoopSpec;
using loop::SafetyLimits;

Status SceneParser::vec6(const YAML::Node& n, const std::string& what, const char* translation_key,
                         const char* rotation_key, tracking::Vector6d* out) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(n, what, {translation_key, rotation_key}));
  Vector3d t = Vector3d::Zero(), r = Vector3d::Zero();
  if (n[translation_key]) LFTRACK_RETURN_IF_ERROR(vec3(n[translation_key], what + "." + translation_key, &t));
  if (n[rotation_key]) LFTRACK_RETURN_IF_ERROR(vec3(n[rotation_key], what + "." + rotation_key, &r));
  out->head<3>() = t;
  out->tail<3>() = r * tracking::deg_to_rad(1.0);
  return {};
}

Status SceneParser::parse_sim(const YAML::Node& n, SimFrameSpec* sim) const {
  LFTRACK_RETURN_IF_ERROR(
      check_keys(n, "sim",
                 {"exposure", "aec_level", "photons_per_pixel", "detector_blur_px", "renderer", "light_field", "seed",
                  "couch_link", "physics"}));
  if (n["exposure"]) LFTRACK_RETURN_IF_ERROR(one_of(n["exposure"], "sim.exposure", {"aec", "fixed"}, &sim->exposure));
  if (n["aec_level"]) {
    LFTRACK_RETURN_IF_ERROR(number(n["aec_level"], "sim.aec_level", &sim->aec_level));
    if (!(sim->aec_level >= 0.01 && sim->aec_level <= 0.8))
      return error(n["aec_level"],
                   "sim.aec_level must be from 0.01 to 0.8 of the detector's full scale: below, the ROI is "
                   "almost black; above, its brighter parts saturate");
  }
  if (n["physics"]) LFTRACK_RETURN_IF_ERROR(parse_physics(n["physics"], sim));
  if (n["photons_per_pixel"])
    LFTRACK_RETURN_IF_ERROR(positive_at_most(
        n["photons_per_pixel"], "sim.photons_per_pixel", sim_spec::kMaxPhotonsPerPixel,
        "no detector counts more; a 16-bit panel saturates far below", &sim->photons_per_pixel));
  if (n["detector_blur_px"]) {
    LFTRACK_RETURN_IF_ERROR(number(n["detector_blur_px"], "sim.detector_blur_px", &sim->detector_blur_px));
    if (sim->detector_blur_px < 0 || sim->detector_blur_px > 20)
      return error(n["detector_blur_px"], "sim.detector_blur_px must be in 0..20");
  }
  if (n["renderer"])
    LFTRACK_RETURN_IF_ERROR(one_of(n["renderer"], "sim.renderer", {"siddon", "lightfield"}, &sim->renderer));
  if (n["light_field"])
    LFTRACK_RETURN_IF_ERROR(parse_light_field(n["light_field"], "sim.light_field", &sim->light_field));
  if (n["couch_link"]) {
    std::string link;
    LFTRACK_RETURN_IF_ERROR(text(n["couch_link"], "sim.couch_link", &link));
    sim->couch_link = (fs::path(link).is_absolute() ? fs::path(link) : folder_of(n["couch_link"]) / link).string();
  }
  if (n["seed"]) {
    long seed = 0;
    LFTRACK_RETURN_IF_ERROR(integer(n["seed"], "sim.seed", 0, 2147483647L, &seed));
    sim->seed = static_cast<std::uint64_t>(seed);
  }
  return {};
}

Status SceneParser::parse_loop(const YAML::Node& n, LoopSpec* loop) const {
  LFTRACK_RETURN_IF_ERROR(
      check_keys(n, "loop",
                 {"period_ms", "registration_budget_ms", "acquire_timeout_ms", "align_plan", "track_plan",
                  "lookahead_s", "prediction_cycles", "prediction_order", "predict_rotations", "realtime",
                  "judge_tracking"}));
  if (n["predict_rotations"])
    LFTRACK_RETURN_IF_ERROR(boolean(n["predict_rotations"], "loop.predict_rotations", &loop->predict_rotations));
  if (n["judge_tracking"]) {
    bool judge = false;
    LFTRACK_RETURN_IF_ERROR(boolean(n["judge_tracking"], "loop.judge_tracking", &judge));
    loop->judge_tracking = judge;
  }

  if (n["period_ms"]) {
    LFTRACK_RETURN_IF_ERROR(positive(n["period_ms"], "loop.period_ms", &loop->period_ms));
    if (loop->period_ms < 1 || loop->period_ms > 10000)
      return error(n["period_ms"], "loop.period_ms must be in 1..10000");
  }
  if (n["registration_budget_ms"])
    LFTRACK_RETURN_IF_ERROR(
        positive(n["registration_budget_ms"], "loop.registration_budget_ms", &loop->registration_budget_ms));
  if (n["acquire_timeout_ms"])
    LFTRACK_RETURN_IF_ERROR(
        positive(n["acquire_timeout_ms"], "loop.acquire_timeout_ms", &loop->acquire_timeout_ms));
  if (loop->registration_budget_ms + loop->acquire_timeout_ms > loop->period_ms)
    return error(n, "loop: acquire_timeout_ms + registration_budget_ms must fit in period_ms (" +
                        std::to_string(loop->period_ms) + " ms)");
  const auto plans = tracking::registration_plan_names();
  if (n["align_plan"])
    LFTRACK_RETURN_IF_ERROR(one_of(n["align_plan"], "loop.align_plan", plans, &loop->align_plan));
  if (n["track_plan"])
    LFTRACK_RETURN_IF_ERROR(one_of(n["track_plan"], "loop.track_plan", plans, &loop->track_plan));
  if (n["lookahead_s"]) {
    double s = 0;
    LFTRACK_RETURN_IF_ERROR(number(n["lookahead_s"], "loop.lookahead_s", &s));
    if (s < 0 || s > 2) return error(n["lookahead_s"], "loop.lookahead_s must be in 0..2 s");
    loop->lookahead_s = s;
  }
  if (n["prediction_cycles"]) {
    long c = 0;
    LFTRACK_RETURN_IF_ERROR(integer(n["prediction_cycles"], "loop.prediction_cycles", 0, 32, &c));
    loop->prediction_cycles = static_cast<int>(c);
  }
  if (n["prediction_order"]) {
    long o = 0;
    LFTRACK_RETURN_IF_ERROR(integer(n["prediction_order"], "loop.prediction_order", 1, 2, &o));
    loop->prediction_order = static_cast<int>(o);
  }
  if (const YAML::Node rt = n["realtime"]) {
    LFTRACK_RETURN_IF_ERROR(check_keys(rt, "loop.realtime", {"mode", "priority", "cpus"}));
    if (rt["mode"]) {
      std::string mode;
      LFTRACK_RETURN_IF_ERROR(one_of(rt["mode"], "loop.realtime.mode", {"enforce", "ignore"}, &mode));
      loop->realtime.enforce = mode == "enforce";
    }
    if (rt["priority"]) {
      long p = 0;
      LFTRACK_RETURN_IF_ERROR(integer(rt["priority"], "loop.realtime.priority", 1, 99, &p));
      loop->realtime.priority = static_cast<int>(p);
    }
    if (const YAML::Node cpus = rt["cpus"]) {
      if (!cpus.IsSequence() || cpus.size() == 0)
        return error(cpus, "loop.realtime.cpus must be a list of CPU numbers");
      for (std::size_t i = 0; i < cpus.size(); ++i) {
        long c = 0;
        LFTRACK_RETURN_IF_ERROR(integer(cpus[i], "loop.realtime.cpus", 0, 1023, &c));
        loop->realtime.cpus.push_back(static_cast<int>(c));
      }
    }
  }
  return {};
}

Status SceneParser::parse_safety(const YAML::Node& n, SafetyLimits* l) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(
      n, "safety",
      {"max_step_mm",        "max_step_deg",          "max_total_mm",           "max_total_deg",
       "min_similarity",     "min_similarity_ratio",  "max_ratio_disagreement", "max_frame_age_ms",
       "max_pair_skew_ms",   "readback_tolerance_mm", "readback_tolerance_deg", "beam_tolerance_mm",
       "beam_tolerance_deg", "max_beam_withheld_s",   "hold_after_failures",    "fault_after_failures",
       "commissioning",      "envelope_edge_mm",      "envelope_edge_deg",      "max_view_shift_mm",
       "view_check_every",   "require_daily_qa"}));
  // Each limit has a ceiling: a tracking correction beyond it is a new set-up for the therapist,
  // never a setting, so a value above it (a 1e9 typed for 10) is refused, not obeyed.
  struct Limit {
    const char* key;
    double* out;
    double most;
    const char* why;
  };
  const Limit limits[] = {
      {"max_step_mm", &l->max_step_mm, 20, "a per-cycle step beyond 20 mm is no tracking correction"},
      {"max_step_deg", &l->max_step_deg, 10, "a per-cycle step beyond 10 degrees is no tracking correction"},
      {"max_total_mm", &l->max_total_mm, 50, "beyond 50 mm from the aligned pose the patient is set up again"},
      {"max_total_deg", &l->max_total_deg, 15, "beyond 15 degrees from the aligned pose the patient is set up again"},
      {"max_ratio_disagreement", &l->max_ratio_disagreement, 10, "beyond 10 the views are never compared"},
      {"max_frame_age_ms", &l->max_frame_age_ms, 10000, "a frame older than 10 s shows a patient who has moved"},
      {"max_pair_skew_ms", &l->max_pair_skew_ms, 1000, "frames a second apart are no pair"},
      {"readback_tolerance_mm", &l->readback_tolerance_mm, 10, "a read-back 10 mm off is a couch fault"},
      {"readback_tolerance_deg", &l->readback_tolerance_deg, 5, "a read-back 5 degrees off is a couch fault"},
      {"beam_tolerance_mm", &l->beam_tolerance_mm, 10, "a patient 10 mm from place is not treated"},
      {"beam_tolerance_deg", &l->beam_tolerance_deg, 5, "a patient 5 degrees from place is not treated"},
      {"max_beam_withheld_s", &l->max_beam_withheld_s, 600,
       "a patient out of place for 10 minutes is set up again, not tracked"}};
  for (const Limit& limit : limits)
    if (n[limit.key])
      LFTRACK_RETURN_IF_ERROR(
          positive_at_most(n[limit.key], std::string("safety.") + limit.key, limit.most, limit.why, limit.out));
  if (l->max_beam_withheld_s < 1)
    return error(n["max_beam_withheld_s"], "safety.max_beam_withheld_s must be at least 1 s (a couch's set-up move "
                                           "takes seconds; shorter would hold after every alignment)");
  if (l->max_step_mm > l->max_total_mm) return error(n, "safety.max_step_mm must not exceed safety.max_total_mm");
  if (l->max_step_deg > l->max_total_deg) return error(n, "safety.max_step_deg must not exceed safety.max_total_deg");
  if (n["min_similarity"])
    LFTRACK_RETURN_IF_ERROR(number(n["min_similarity"], "safety.min_similarity", &l->min_similarity));
  if (n["min_similarity_ratio"]) {
    LFTRACK_RETURN_IF_ERROR(
        number(n["min_similarity_ratio"], "safety.min_similarity_ratio", &l->min_similarity_ratio));
    if (l->min_similarity_ratio < 0 || l->min_similarity_ratio > 1)
      return error(n["min_similarity_ratio"], "safety.min_similarity_ratio must be in 0..1");
  }
  long hold = l->hold_after_failures, fault = l->fault_after_failures;
  if (n["hold_after_failures"])
    LFTRACK_RETURN_IF_ERROR(integer(n["hold_after_failures"], "safety.hold_after_failures", 1, 1000, &hold));
  if (n["fault_after_failures"])
    LFTRACK_RETURN_IF_ERROR(
        integer(n["fault_after_failures"], "safety.fault_after_failures", 1, 10000, &fault));
  if (fault < hold) return error(n, "safety.fault_after_failures must be at least hold_after_failures");
  l->hold_after_failures = static_cast<int>(hold);
  l->fault_after_failures = static_cast<int>(fault);
  return {};
}

Status SceneParser::parse_actuator(const YAML::Node& n, ActuatorSpec* a) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "actuator",
                                     {"type", "latency_s", "max_speed_mm_s", "max_speed_deg_s", "range_mm",
                                      "range_deg", "mounting", "calibration", "modbus", "can"}));
  YAML::Node type;
  LFTRACK_RETURN_IF_ERROR(need(n, "type", "actuator", &type));
  LFTRACK_RETURN_IF_ERROR(one_of(type, "actuator.type", {"none", "virtual", "modbus", "can"}, &a->type));
  if (a->type == "modbus") {
    if (!n["modbus"]) return error(n, "actuator.type modbus needs actuator.modbus: {tcp: {host, port}} or {rtu: ...}");
    LFTRACK_RETURN_IF_ERROR(parse_modbus(n["modbus"], &a->modbus));
  } else if (n["modbus"]) {
    return error(n["modbus"], "actuator.modbus is for actuator.type modbus");
  }
  if (a->type == "can") {
    if (!n["can"]) return error(n, "actuator.type can needs actuator.can: {interface: can0} or {bridge: PATH}");
    LFTRACK_RETURN_IF_ERROR(parse_can(n["can"], &a->can));
  } else if (n["can"]) {
    return error(n["can"], "actuator.can is for actuator.type can");
  }
  drivers::ActuatorDynamics& c = a->dynamics;
  if (n["latency_s"]) {
    LFTRACK_RETURN_IF_ERROR(number(n["latency_s"], "actuator.latency_s", &c.latency_s));
    if (c.latency_s < 0 || c.latency_s > 5)
      return error(n["latency_s"], "actuator.latency_s must be in 0..5 s");
  }
  if (n["max_speed_mm_s"])
    LFTRACK_RETURN_IF_ERROR(positive(n["max_speed_mm_s"], "actuator.max_speed_mm_s", &c.max_speed_mm_s));
  if (n["max_speed_deg_s"])
    LFTRACK_RETURN_IF_ERROR(positive(n["max_speed_deg_s"], "actuator.max_speed_deg_s", &c.max_speed_deg_s));
  if (n["range_mm"]) LFTRACK_RETURN_IF_ERROR(positive(n["range_mm"], "actuator.range_mm", &c.range_mm));
  if (n["range_deg"]) LFTRACK_RETURN_IF_ERROR(positive(n["range_deg"], "actuator.range_deg", &c.range_deg));
  if (const YAML::Node m = n["mounting"]) {
    LFTRACK_RETURN_IF_ERROR(check_keys(m, "actuator.mounting", {"rotation_deg", "centre_mm"}));
    CouchMountingSpec mounting;
    if (m["rotation_deg"]) {
      LFTRACK_RETURN_IF_ERROR(
          vec3(m["rotation_deg"], "actuator.mounting.rotation_deg", &mounting.rotation_rad));
      if (mounting.rotation_rad.norm() > 20)
        return error(m["rotation_deg"], "actuator.mounting.rotation_deg: at most 20 degrees");
      mounting.rotation_rad *= 3.14159265358979323846 / 180;
    }
    if (m["centre_mm"]) {
      Vector3d centre;
      LFTRACK_RETURN_IF_ERROR(vec3(m["centre_mm"], "actuator.mounting.centre_mm", &centre));
      mounting.centre_room_mm = centre;
    }
    a->mounting = mounting;
  }
  if (const YAML::Node cal = n["calibration"]) {
    std::string file;
    LFTRACK_RETURN_IF_ERROR(text(cal, "actuator.calibration", &file));
    const fs::path path = fs::path(file).is_absolute() ? fs::path(file) : folder_of(cal) / file;
    auto read = read_couch_calibration(path.string());
    if (!read.ok()) return error(cal, "actuator.calibration: " + read.status().message());
    a->calibration_file = path.string();
    a->calibration = *read;
  }
  return {};
}

// The simulated patient moves within what a patient on a couch can: each translation component
// within `mm`, each rotation within `deg` (an outside probe's 1e12 mm breathing gave residuals
// of 2e10 mm, a 1e300 mm/s drift infinite ones).
Status SceneParser::check_motion(const YAML::Node& n, const std::string& what, const tracking::Vector6d& v,
                                 double mm, double deg) const {
  if (v.head<3>().cwiseAbs().maxCoeff() > mm || v.tail<3>().cwiseAbs().maxCoeff() > tracking::deg_to_rad(deg)) {
    std::ostringstream m;
    m << what << " must stay within " << mm << " mm and " << deg << " degrees per axis";
    return error(n, m.str());
  }
  return {};
}

Status SceneParser::parse_motion(const YAML::Node& n, MotionSpec* m) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "motion", {"setup_error", "drift", "breathing", "shifts"}));
  if (n["setup_error"]) {
    LFTRACK_RETURN_IF_ERROR(
        vec6(n["setup_error"], "motion.setup_error", "translation_mm", "rotation_deg", &m->setup_error));
    LFTRACK_RETURN_IF_ERROR(check_motion(n["setup_error"], "motion.setup_error", m->setup_error, 100, 45));
  }
  if (n["drift"]) {
    LFTRACK_RETURN_IF_ERROR(vec6(n["drift"], "motion.drift", "translation_mm_per_s", "rotation_deg_per_s",
                                 &m->motion.drift_per_s));
    LFTRACK_RETURN_IF_ERROR(check_motion(n["drift"], "motion.drift (per second)", m->motion.drift_per_s, 10, 5));
  }
  if (const YAML::Node b = n["breathing"]) {
    LFTRACK_RETURN_IF_ERROR(check_keys(b, "motion.breathing", {"amplitude_mm", "amplitude_deg", "period_s"}));
    Vector3d t = Vector3d::Zero(), r = Vector3d::Zero();
    if (b["amplitude_mm"])
      LFTRACK_RETURN_IF_ERROR(vec3(b["amplitude_mm"], "motion.breathing.amplitude_mm", &t));
    if (b["amplitude_deg"])
      LFTRACK_RETURN_IF_ERROR(vec3(b["amplitude_deg"], "motion.breathing.amplitude_deg", &r));
    m->motion.breathing_amplitude.head<3>() = t;
    m->motion.breathing_amplitude.tail<3>() = r * tracking::deg_to_rad(1.0);
    LFTRACK_RETURN_IF_ERROR(check_motion(b, "motion.breathing amplitudes", m->motion.breathing_amplitude, 50, 10));
    if (b["period_s"]) {
      LFTRACK_RETURN_IF_ERROR(
          positive(b["period_s"], "motion.breathing.period_s", &m->motion.breathing_period_s));
      if (m->motion.breathing_period_s < 0.5 || m->motion.breathing_period_s > 60)
        return error(b["period_s"], "motion.breathing.period_s must be in 0.5..60 s");
    }
  }
  if (const YAML::Node shifts = n["shifts"]) {
    if (!shifts.IsSequence())
      return error(shifts, "motion.shifts must be a list of {time_s, translation_mm, rotation_deg}");
    for (std::size_t i = 0; i < shifts.size(); ++i) {
      const YAML::Node s = shifts[i];
      const std::string what = "motion.shifts[" + std::to_string(i) + "]";
      LFTRACK_RETURN_IF_ERROR(check_keys(s, what, {"time_s", "translation_mm", "rotation_deg"}));
      sim_spec::MotionStep step;
      YAML::Node time;
      LFTRACK_RETURN_IF_ERROR(need(s, "time_s", what, &time));
      LFTRACK_RETURN_IF_ERROR(number(time, what + ".time_s", &step.time_s));
      Vector3d t = Vector3d::Zero(), r = Vector3d::Zero();
      if (s["translation_mm"])
        LFTRACK_RETURN_IF_ERROR(vec3(s["translation_mm"], what + ".translation_mm", &t));
      if (s["rotation_deg"]) LFTRACK_RETURN_IF_ERROR(vec3(s["rotation_deg"], what + ".rotation_deg", &r));
      step.delta.head<3>() = t;
      step.delta.tail<3>() = r * tracking::deg_to_rad(1.0);
      LFTRACK_RETURN_IF_ERROR(check_motion(s, what, step.delta, 100, 45));
      if (step.time_s < 0 || step.time_s > 1e6) return error(time, what + ".time_s must be in 0..1e6 s");
      m->motion.shifts.push_back(step);
    }
  }
  return {};
}

// safety: the registration verdict's checks beyond its floors (envelope edge, view shift).
Status SceneParser::parse_verdict_checks(const YAML::Node& n, const PoseEnvelope& envelope,
                                         VerdictChecksSpec* c) const {
  const auto g = [](double x) {
    std::ostringstream o;
    o << x;
    return o.str();
  };
  if (const YAML::Node e = n["envelope_edge_mm"]) {
    LFTRACK_RETURN_IF_ERROR(number(e, "safety.envelope_edge_mm", &c->envelope_edge_mm));
    if (!(c->envelope_edge_mm >= 0 && c->envelope_edge_mm < envelope.translation_mm))
      return error(
          e, "safety.envelope_edge_mm must be at least 0 and less than the envelope's translation_mm (" +
                 g(envelope.translation_mm) + "): a band as wide refuses every result");
  }
  if (const YAML::Node e = n["envelope_edge_deg"]) {
    LFTRACK_RETURN_IF_ERROR(number(e, "safety.envelope_edge_deg", &c->envelope_edge_deg));
    if (!(c->envelope_edge_deg >= 0 && c->envelope_edge_deg < envelope.rotation_deg))
      return error(e,
                   "safety.envelope_edge_deg must be at least 0 and less than the envelope's rotation_deg (" +
                       g(envelope.rotation_deg) + "): a band as wide refuses every result");
  }
  if (const YAML::Node m = n["max_view_shift_mm"]) {
    LFTRACK_RETURN_IF_ERROR(number(m, "safety.max_view_shift_mm", &c->max_view_shift_mm));
    if (!(c->max_view_shift_mm >= 0 && c->max_view_shift_mm <= 20))
      return error(m,
                   "safety.max_view_shift_mm must be in [0, 20] (0: the views are not registered alone); two "
                   "views 20 mm apart do not see one patient");
  }
  if (const YAML::Node e = n["view_check_every"]) {
    long every = 0;
    LFTRACK_RETURN_IF_ERROR(integer(e, "safety.view_check_every", 0, 100000, &every));
    c->view_check_every = static_cast<int>(every);
  }
  return {};
}

}  // namespace lftrack::session

#include "lftrack/studies/registration_benchmark.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <random>

#include "lftrack/session/progress_bar.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "quantile.hpp"

namespace lftrack::studies {

using session::make_scene_registration;
using session::make_scene_renderer;
using session::pose_at_tre;
using session::PreparedScene;
using session::preprocess_scene_frames;
using session::ProgressBar;
using session::scene_tre;
using session::SceneFrames;
using sim_devices::scene_detector_model;
using sim_devices::synthesize_scene_frames;

using tracking::Pose;
using tracking::PoseDelta;

namespace {

struct Sample {
  double ms = 0, tre_mm = 0;
  int evaluations = 0;
  std::vector<tracking::RegistrationPassSummary> passes;
};

Sample sample_of(const tracking::RegistrationResult& r, double tre_mm) {
  return {r.elapsed_ms, tre_mm, r.evaluations, r.passes};
}


TimedRegistrations summarize(const std::vector<Sample>& samples) {
  TimedRegistrations t;
  t.runs = int(samples.size());
  if (samples.empty()) return t;
  std::vector<double> ms, evals;
  int ok = 0;
  for (const Sample& s : samples) {
    ms.push_back(s.ms);
    evals.push_back(s.evaluations);
    t.mean_tre_mm += s.tre_mm / double(samples.size());
    t.max_tre_mm = std::max(t.max_tre_mm, s.tre_mm);
    ok += s.tre_mm < 2.0;
  }
  t.median_ms = quantile(ms, 0.5);
  t.p95_ms = quantile(ms, 0.95);
  t.max_ms = quantile(ms, 1.0);
  t.success_rate = double(ok) / double(samples.size());
  t.median_evaluations = quantile(evals, 0.5);
  for (std::size_t p = 0;; ++p) {
    std::vector<double> pass_ms, pass_evals;
    for (const Sample& s : samples) {
      if (p >= s.passes.size()) continue;
      pass_ms.push_back(s.passes[p].elapsed_ms);
      pass_evals.push_back(s.passes[p].evaluations);
    }
    if (pass_ms.empty()) break;
    t.passes.push_back({quantile(pass_ms, 0.5), quantile(pass_evals, 0.5)});
  }
  return t;
}

// A random delta with every translation component within +-t_mm and rotation within +-r_deg.
tracking::Vector6d random_delta(std::mt19937_64& rng, double t_mm, double r_deg) {
  std::uniform_real_distribution<double> u(-1, 1);
  tracking::Vector6d v;
  for (int i = 0; i < 3; ++i) v(i) = u(rng) * t_mm;
  for (int i = 3; i < 6; ++i) v(i) = tracking::deg_to_rad(u(rng) * r_deg);
  return v;
}

}  // namespace

Result<RegistrationBenchReport> run_registration_benchmark(const PreparedScene& p,
                                                           const RegistrationBenchOptions& o,
                                                           tracking::ThreadPool* pool) {
  RegistrationBenchReport report;
  report.scene = p.scene.source;
  report.plan = o.cold_plan.empty() ? p.scene.registration.plan : o.cold_plan;
  report.warm_plan = o.warm_plan;
  report.similarity = p.scene.registration.similarity;
  report.threads = pool != nullptr ? pool->size() : 1;
  auto plan = tracking::registration_plan(report.plan);
  if (!plan.ok()) return plan.status();
  auto warm_planned = tracking::registration_plan(o.warm_plan);
  if (!warm_planned.ok()) return warm_planned.status();
  const tracking::RegistrationPlan warm_plan = *warm_planned;
  auto lightfield = make_scene_renderer(p, "lightfield", {}, pool);
  if (!lightfield.ok()) return lightfield.status();
  tracking::RendererOptions ray_options;
  ray_options.pool = pool;
  auto exact = tracking::make_renderer("siddon", p.world_mu, ray_options);
  if (!exact.ok()) return exact.status();
  auto registration = make_scene_registration(p, *lightfield, p.scene.registration, pool);
  if (!registration.ok()) return registration.status();
  tracking::Registration& reg = **registration;
  const tracking::DetectorCorrection correction = sim::detector_correction(scene_detector_model(p));
  const Eigen::Vector3d origin = p.registration_origin_room_mm();
  std::mt19937_64 rng(o.seed);

  auto frames_at = [&](const Pose& gold, std::uint64_t seed) -> Result<SceneFrames> {
    auto raw = synthesize_scene_frames(p, **exact, gold, seed);
    if (!raw.ok()) return raw.status();
    return preprocess_scene_frames(p, *raw, correction);
  };

  // Cold registrations (their gold poses, starts and frames are reused for the renderer comparison).
  std::vector<Sample> cold;
  struct Problem {
    Pose gold, start;
    SceneFrames frames;
  };
  std::vector<Problem> problems;
  ProgressBar cold_bar("cold registrations");
  for (int i = 0; i < o.cold_runs; ++i) {
    const Pose gold = tracking::apply_delta(p.nominal_T_room_from_ct,
                                            PoseDelta::from_vector(random_delta(rng, 3, 2)), origin);
    const double target = std::uniform_real_distribution<double>(0.5, o.cold_max_initial_mm)(rng);
    const Pose start = pose_at_tre(p, gold, random_delta(rng, 1.0, 1.0), target);
    auto frames = frames_at(gold, o.seed * 1000 + std::uint64_t(i));
    if (!frames.ok()) return frames.status();
    LFTRACK_RETURN_IF_ERROR(reg.set_frames(frames->frames(), frames->masks()));
    auto r = reg.run(start, *plan);
    if (!r.ok()) return r.status();
    cold.push_back(sample_of(*r, scene_tre(p, r->T_room_from_ct, gold).mean_mm));
    if (i < o.renderer_runs) problems.push_back({gold, start, std::move(frames).value()});
    cold_bar.update(double(i + 1) / o.cold_runs);
  }
  cold_bar.finish();
  report.cold = summarize(cold);

  // Warm tracking of a moving patient.
  std::vector<Sample> warm;
  ProgressBar warm_bar("warm registrations");
  Pose gold = p.nominal_T_room_from_ct, last = gold;
  for (int i = 0; i < o.warm_runs; ++i) {
    gold = tracking::apply_delta(gold, PoseDelta::from_vector(random_delta(rng, o.warm_translation_mm, o.warm_rotation_deg)),
                                 origin);
    // Keep the patient within the envelope: pull back towards nominal when it drifts far.
    const tracking::Vector6d from_nominal = tracking::delta_between(p.nominal_T_room_from_ct, gold, origin).as_vector();
    if (from_nominal.head<3>().cwiseAbs().maxCoeff() > 0.7 * p.scene.envelope.translation_mm ||
        tracking::rad_to_deg(from_nominal.tail<3>().cwiseAbs().maxCoeff()) > 0.7 * p.scene.envelope.rotation_deg)
      gold = tracking::apply_delta(p.nominal_T_room_from_ct, PoseDelta::from_vector(0.5 * from_nominal), origin);
    auto frames = frames_at(gold, o.seed * 7777 + std::uint64_t(i));
    if (!frames.ok()) return frames.status();
    LFTRACK_RETURN_IF_ERROR(reg.set_frames(frames->frames(), frames->masks()));
    auto r = reg.run(last, warm_plan);
    if (!r.ok()) return r.status();
    warm.push_back(sample_of(*r, scene_tre(p, r->T_room_from_ct, gold).mean_mm));
    last = r->T_room_from_ct;
    warm_bar.update(double(i + 1) / o.warm_runs);
  }
  warm_bar.finish();
  report.warm = summarize(warm);

  // The same cold problems, light field against Siddon inside the registration.
  if (!problems.empty()) {
    auto siddon = tracking::make_renderer("siddon", p.mu, {});
    if (!siddon.ok()) return siddon.status();
    auto siddon_registration = make_scene_registration(
        p, std::shared_ptr<const tracking::DrrRenderer>(std::move(siddon).value()), p.scene.registration, pool);
    if (!siddon_registration.ok()) return siddon_registration.status();
    std::vector<Sample> with_lf, with_siddon;
    ProgressBar bar("Siddon inside registration");
    for (std::size_t i = 0; i < problems.size(); ++i) {
      const Problem& pr = problems[i];
      LFTRACK_RETURN_IF_ERROR(reg.set_frames(pr.frames.frames(), pr.frames.masks()));
      auto a = reg.run(pr.start, *plan);
      LFTRACK_RETURN_IF_ERROR((*siddon_registration)->set_frames(pr.frames.frames(), pr.frames.masks()));
      auto b = (*siddon_registration)->run(pr.start, *plan);
      if (!a.ok()) return a.status();
      if (!b.ok()) return b.status();
      with_lf.push_back(sample_of(*a, scene_tre(p, a->T_room_from_ct, pr.gold).mean_mm));
      with_siddon.push_back(sample_of(*b, scene_tre(p, b->T_room_from_ct, pr.gold).mean_mm));
      bar.update(double(i + 1) / double(problems.size()));
    }
    bar.finish();
    report.lightfield_inside = summarize(with_lf);
    report.siddon_inside = summarize(with_siddon);
  }
  return report;
}

nlohmann::json to_json(const RegistrationBenchReport& r) {
  auto timed = [](const TimedRegistrations& t) {
    // None run (--warm 0): no figures, rather than zeros that read as measured.
    if (t.runs == 0) return nlohmann::json{{"runs", 0}};
    return nlohmann::json{{"runs", t.runs},
                          {"median_ms", t.median_ms},
                          {"p95_ms", t.p95_ms},
                          {"max_ms", t.max_ms},
                          {"mean_tre_mm", t.mean_tre_mm},
                          {"max_tre_mm", t.max_tre_mm},
                          {"success_rate", t.success_rate},
                          {"median_evaluations", t.median_evaluations},
                          {"passes", [&] {
                             auto passes = nlohmann::json::array();
                             for (const auto& p : t.passes)
                               passes.push_back({{"median_ms", p.median_ms}, {"median_evaluations", p.median_evaluations}});
                             return passes;
                           }()}};
  };
  nlohmann::json j{{"scene", r.scene}, {"plan", r.plan}, {"warm_plan", r.warm_plan}, {"similarity", r.similarity},
                   {"threads", r.threads},
                   {"cold", timed(r.cold)}, {"warm", timed(r.warm)}};
  if (r.siddon_inside.runs > 0) {
    j["renderers_inside_registration"] = {
        {"lightfield", timed(r.lightfield_inside)},
        {"siddon", timed(r.siddon_inside)},
        {"mean_tre_difference_mm", std::abs(r.lightfield_inside.mean_tre_mm - r.siddon_inside.mean_tre_mm)}};
  }
  return j;
}

}  // namespace lftrack::studies

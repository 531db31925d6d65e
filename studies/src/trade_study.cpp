// The trade study's points and runs (trade_study.hpp); its files, front and summary are in
// trade_study_report.cpp.

#include "lftrack/studies/trade_study.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <optional>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <random>
#include <set>

#include "lftrack/session/registration_judge.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/session/scene_verdict.hpp"
#include "lftrack/sim_devices/simulated_patient.hpp"
#include "lftrack/studies/study_shard.hpp"
#include "lftrack/tracking/image_metrics.hpp"
#include "lftrack/tracking/octree_volume.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "quantile.hpp"

namespace lftrack::studies {

using session::light_field_files;
using session::load_light_fields;
using session::make_scene_registration;
using session::pose_at_tre;
using session::PreparedScene;
using session::preprocess_scene_frames;
using session::RegistrationSpec;
using session::scene_tre;
using session::scene_verdict_limits;
using session::SceneFrames;
using session::verdict_input_of;
using sim_devices::make_simulated_patient;
using sim_devices::scene_detector_model;
using sim_devices::SceneImager;
using sim_devices::SimulatedPatient;
using sim_devices::synthesize_scene_frames;

using loop::judge_registration;
using loop::RegistrationVerdict;
using loop::VerdictReason;
namespace {

using Clock = std::chrono::steady_clock;
using tracking::Pose;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

std::string fmt_number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

std::string resolution_label(const std::array<int, 4>& r) {
  return std::to_string(r[0]) + "x" + std::to_string(r[1]) + "x" + std::to_string(r[2]) + "x" +
         std::to_string(r[3]);
}

// One registration problem, the same for every point.
struct Problem {
  Pose gold = Pose::Identity();
  Pose start = Pose::Identity();
  SceneFrames frames;
  // Per view, the image-quality gate on the raw frame over its ROI window, as the loop runs it
  // (what the verdict judges first).
  std::vector<tracking::FrameQualityIssue> quality;
  std::vector<tracking::Image<float>> siddon_drr;  // per view, ROI window, at gold (fidelity reference)
};

// With realistic physics the frames come from the simulated patient (kAnatomyDraws deformed
// anatomies shared by the problems in turn), exposed by the scene's imager; ideal frames are
// Siddon DRRs of the world with noise, as before.
constexpr int kAnatomyDraws = 4;

Result<std::vector<Problem>> make_problems(const PreparedScene& p, int count, std::uint64_t seed,
                                           const sim_spec::XrayPhysicsSpec& physics,
                                           tracking::ThreadPool* pool) {
  tracking::RendererOptions options;
  options.pool = pool;
  auto world = tracking::make_renderer("siddon", p.world_mu, options);
  if (!world.ok()) return world.status();
  auto exact = tracking::make_renderer("siddon", p.mu, options);
  if (!exact.ok()) return exact.status();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(-1, 1);
  std::normal_distribution<double> normal(0, 1);
  auto correction = sim::detector_correction(scene_detector_model(p));
  std::optional<SceneImager> imager;
  std::vector<std::shared_ptr<const SimulatedPatient>> patients;
  if (!physics.ideal()) {
    auto made = SceneImager::create(p, physics);
    if (!made.ok()) return made.status();
    imager = std::move(made).value();
    correction = imager->correction();
    patients.resize(physics.anatomy ? kAnatomyDraws : 1);
  }
  std::vector<Problem> problems;
  for (int k = 0; k < count; ++k) {
    Problem pr;
    tracking::Vector6d g;
    for (int a = 0; a < 3; ++a) g(a) = 0.4 * p.scene.envelope.translation_mm * unit(rng);
    for (int a = 3; a < 6; ++a) g(a) = tracking::deg_to_rad(0.4 * p.scene.envelope.rotation_deg * unit(rng));
    pr.gold = tracking::apply_delta(p.nominal_T_room_from_ct, tracking::PoseDelta::from_vector(g),
                                    p.registration_origin_room_mm());
    // The start: along a random direction (1 degree ~ 1 mm) at an initial mean TRE in [1, 4] mm.
    tracking::Vector6d dir;
    for (int a = 0; a < 3; ++a) dir(a) = normal(rng);
    for (int a = 3; a < 6; ++a) dir(a) = tracking::deg_to_rad(normal(rng));
    const double initial_mm = 1 + 3 * std::uniform_real_distribution<double>(0, 1)(rng);
    pr.start = pose_at_tre(p, pr.gold, dir, initial_mm);
    auto expose = [&]() -> Result<std::vector<tracking::Image<std::uint16_t>>> {
      const std::uint64_t frame_seed = seed * 7919 + std::uint64_t(k);
      if (!imager) return synthesize_scene_frames(p, **world, pr.gold, frame_seed);
      auto& patient = patients[std::size_t(k) % patients.size()];
      if (!patient) {
        auto made = make_simulated_patient(p, physics, seed * 7727 + std::uint64_t(k) % patients.size() + 1, pool, pool);
        if (!made.ok()) return made.status();
        patient = std::make_shared<const SimulatedPatient>(std::move(made).value());
      }
      imager->forget_previous_frames();
      return imager->expose(*patient, pr.gold, frame_seed);
    };
    auto raw = expose();
    if (!raw.ok()) return raw.status();
    for (std::size_t v = 0; v < raw->size(); ++v)
      pr.quality.push_back(tracking::assess_frame_quality((*raw)[v].view(), p.roi_windows[v], correction,
                                                          tracking::FrameQualityLimits{}));
    auto frames = preprocess_scene_frames(p, *raw, correction);
    if (!frames.ok()) return frames.status();
    pr.frames = std::move(frames).value();
    for (std::size_t v = 0; v < p.scene.detectors.size(); ++v) {
      const tracking::PixelWindow& w = p.roi_windows[v];
      tracking::Image<float> drr(w.rows, w.cols);
      LFTRACK_RETURN_IF_ERROR((*exact)->render(pr.gold, p.scene.detectors[v].view, w, drr.view()));
      pr.siddon_drr.push_back(std::move(drr));
    }
    problems.push_back(std::move(pr));
  }
  return problems;
}

std::string field_set_key(const std::array<int, 4>& resolution, double envelope_scale) {
  return resolution_label(resolution) + "@" + fmt_number(envelope_scale);
}

// The folder of one float field set inside a trade study's field folder.
std::filesystem::path field_set_dir(const std::filesystem::path& field_dir, const std::array<int, 4>& resolution,
                                    double envelope_scale) {
  return field_dir / ("float-" + resolution_label(resolution) + "-envelope-x" + fmt_number(envelope_scale));
}

using Fields = std::vector<std::shared_ptr<const tracking::LightField>>;

// The record of a field set's build time, named after its files (which are named after what
// they depend on), so that scenes sharing a field folder keep their own.
std::filesystem::path build_record(const std::vector<std::filesystem::path>& files) {
  std::uint64_t h = 1469598103934665603ull;
  for (const auto& f : files)
    for (char c : f.filename().string() + "/") {
      h ^= static_cast<unsigned char>(c);
      h *= 1099511628211ull;
    }
  char name[32];
  std::snprintf(name, sizeof name, "build-%012llx.json", static_cast<unsigned long long>(h & 0xffffffffffffull));
  return files.front().parent_path() / name;
}

// The float fields of one (resolution, envelope scale) set: built in memory (empty `dir`), or
// loaded from `dir` with the build time recorded there, or built and saved there (unless
// `prebuilt`, which refuses). `build_s` gets the time the build took, here or when saved.
Result<Fields> field_set(const PreparedScene& p, const std::array<int, 4>& resolution, double envelope_scale,
                         const std::filesystem::path& dir, bool prebuilt, tracking::ThreadPool* pool,
                         double* build_s) {
  PreparedScene scaled = p;
  scaled.scene.envelope.translation_mm *= envelope_scale;
  scaled.scene.envelope.rotation_deg *= envelope_scale;
  tracking::LightFieldSpec spec = p.scene.light_field;
  spec.resolution = resolution;
  spec.storage = tracking::LightFieldStorage::kFloat32;
  const std::string key = field_set_key(resolution, envelope_scale);
  std::string why_not_loaded;
  const std::vector<std::filesystem::path> files =
      dir.empty() ? std::vector<std::filesystem::path>() : light_field_files(scaled, dir, p.mu.get(), &spec);
  if (!dir.empty()) {
    auto loaded = load_light_fields(scaled, dir, p.mu.get(), &spec);
    std::ifstream record(build_record(files));
    double recorded_s = -1;
    try {
      if (record) recorded_s = nlohmann::json::parse(record).at("build_s").get<double>();
    } catch (const std::exception&) {
      recorded_s = -1;
    }
    if (loaded.ok() && recorded_s >= 0) {
      *build_s = recorded_s;
      return std::move(loaded).value();
    }
    why_not_loaded = loaded.ok() ? build_record(files).string() + " missing or unreadable"
                                 : loaded.status().message();
    if (prebuilt)
      return failed_precondition("light fields " + key + " are not built in " + dir.string() + " (" +
                                 why_not_loaded + "); the study's field job builds them: `lftrack study trade " +
                                 "--build-fields --lf-dir DIR`");
  }
  const auto t0 = Clock::now();
  Fields fields;
  for (std::size_t i = 0; i < scaled.scene.detectors.size(); ++i) {
    auto f = tracking::LightField::build(*p.mu, scaled.light_field_plan(int(i)), spec, pool);
    if (!f.ok()) return f.status().with_context("light field " + key);
    fields.push_back(*f);
  }
  *build_s = seconds_since(t0);
  if (!dir.empty()) {
    spdlog::info("light fields {}: built in {:.1f} s ({}); saving to {}", key, *build_s, why_not_loaded,
                 dir.string());
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    if (ec) return io_error(dir.string() + ": cannot create folder: " + ec.message());
    for (std::size_t i = 0; i < fields.size(); ++i) LFTRACK_RETURN_IF_ERROR(fields[i]->save(files[i]));
    LFTRACK_RETURN_IF_ERROR(write_file_atomically(
        build_record(files), nlohmann::json{{"key", key}, {"build_s", *build_s}}.dump(2) + "\n"));
  }
  return fields;
}

// Renderers of the points, with the float fields of each (resolution, envelope) built or loaded once.
class RendererCache {
 public:
  RendererCache(const PreparedScene& p, const TradeOptions& o, tracking::ThreadPool* pool)
      : p_(p), field_dir_(o.field_dir), prebuilt_(o.fields_prebuilt), pool_(pool) {}

  // The point's renderer, its memory, and the precompute time it needed (the float field's
  // build plus any conversion, or the octree's compression).
  Result<std::shared_ptr<const tracking::DrrRenderer>> make(const TradePoint& t, double* memory_bytes,
                                                            double* precompute_s) {
    // Renders run on the calling thread: the registration spreads its candidates over the pool.
    tracking::RendererOptions options;
    *precompute_s = 0;
    if (t.renderer == "lightfield") {
      auto fields = float_fields(t, precompute_s);
      if (!fields.ok()) return fields.status();
      options.light_fields = *fields;
      if (t.storage != "float") {
        tracking::LightFieldSpec spec = p_.scene.light_field;
        spec.resolution = t.lf_resolution;
        spec.storage =
            t.storage == "fixed16" ? tracking::LightFieldStorage::kFixed16 : tracking::LightFieldStorage::kVq;
        if (t.vq_codebook > 0) spec.vq_codebook_size = t.vq_codebook;
        const auto t0 = Clock::now();
        options.light_fields.clear();
        for (const auto& f : *fields) {
          auto converted = tracking::LightField::convert(*f, spec, pool_);
          if (!converted.ok()) return converted.status();
          options.light_fields.push_back(*converted);
        }
        *precompute_s += seconds_since(t0);
      }
    } else if (t.renderer == "octree") {
      const auto t0 = Clock::now();
      auto tree = tracking::OctreeVolume::build(*p_.mu, t.octree_pivot);
      if (!tree.ok()) return tree.status();
      options.octree = std::make_shared<const tracking::OctreeVolume>(std::move(tree).value());
      *precompute_s = seconds_since(t0);
    }
    auto r = tracking::make_renderer(t.renderer, p_.mu, options);
    if (!r.ok()) return r.status();
    const bool casts_the_volume = t.renderer == "siddon" || t.renderer == "trilinear";
    *memory_bytes = casts_the_volume ? double(p_.mu->values.size() * sizeof(float)) : double((*r)->bytes());
    return std::shared_ptr<const tracking::DrrRenderer>(std::move(r).value());
  }

 private:
  Result<Fields> float_fields(const TradePoint& t, double* build_s) {
    const std::string key = field_set_key(t.lf_resolution, t.envelope_scale);
    auto it = cache_.find(key);
    if (it == cache_.end()) {
      double seconds = 0;
      const std::filesystem::path dir =
          field_dir_.empty() ? std::filesystem::path() : field_set_dir(field_dir_, t.lf_resolution, t.envelope_scale);
      auto fields = field_set(p_, t.lf_resolution, t.envelope_scale, dir, prebuilt_, pool_, &seconds);
      if (!fields.ok()) return fields.status();
      // Only the last few are kept: a full study holds one field set at a time per resolution.
      if (cache_.size() > 2) cache_.clear();
      it = cache_.emplace(key, std::make_pair(std::move(fields).value(), seconds)).first;
    }
    *build_s = it->second.second;
    return it->second.first;
  }

  const PreparedScene& p_;
  std::filesystem::path field_dir_;
  bool prebuilt_ = false;
  tracking::ThreadPool* pool_;
  std::map<std::string, std::pair<Fields, double>> cache_;
};

// The plan of a point: its final step on the last pass, every pass binned `bin` times more, and
// its time budget.
Result<tracking::RegistrationPlan> point_plan(const TradePoint& t) {
  auto plan = tracking::registration_plan(t.plan);
  if (!plan.ok()) return plan.status();
  for (auto& pass : plan->passes) pass.bin *= t.bin;
  auto& last = plan->passes.back();
  last.final_step_mm = t.final_step_mm;
  last.initial_step_mm = std::max(last.initial_step_mm, t.final_step_mm);
  if (t.budget_ms > 0) plan->max_ms = t.budget_ms;
  return plan;
}

}  // namespace

std::vector<TradePoint> trade_points(const PreparedScene& p, bool quick) {
  TradePoint base;
  base.lf_resolution = p.scene.light_field.resolution;
  if (quick) {  // a coarser baseline field: a quick study builds its fields in seconds
    if (base.lf_resolution[0] > 16) base.lf_resolution[0] = base.lf_resolution[1] = 16;
    if (base.lf_resolution[2] > 128) base.lf_resolution[2] = base.lf_resolution[3] = 128;
  }
  base.similarity = p.scene.registration.similarity;
  base.id = "baseline";
  std::vector<TradePoint> points{base};
  auto add = [&](const std::string& id, auto&& edit) {
    TradePoint t = base;
    t.id = id;
    edit(t);
    points.push_back(t);
  };
  // Renderers.
  add("siddon", [](TradePoint& t) { t.renderer = "siddon"; });
  if (!quick) add("trilinear", [](TradePoint& t) { t.renderer = "trilinear"; });
  add("lf-fixed16", [](TradePoint& t) { t.storage = "fixed16"; });
  for (int codebook : quick ? std::vector<int>{256} : std::vector<int>{256, 4096, 65536})
    add("lf-vq" + std::to_string(codebook), [&](TradePoint& t) {
      t.storage = "vq";
      t.vq_codebook = codebook;
    });
  for (double pivot : quick ? std::vector<double>{0.02} : std::vector<double>{0.005, 0.02, 0.07})
    add("octree-P" + fmt_number(pivot), [&](TradePoint& t) {
      t.renderer = "octree";
      t.octree_pivot = pivot;
    });
  // Light-field resolution and envelope.
  const auto r = base.lf_resolution;
  for (int uv : quick ? std::vector<int>{std::max(4, r[0] / 2)} : std::vector<int>{8, 16, 32, 64})
    if (uv != r[0])
      add("lf-uv" + std::to_string(uv), [&](TradePoint& t) { t.lf_resolution[0] = t.lf_resolution[1] = uv; });
  for (int st : quick ? std::vector<int>{std::max(32, r[2] / 2)} : std::vector<int>{64, 128, 256, 512})
    if (st != r[2])
      add("lf-st" + std::to_string(st), [&](TradePoint& t) { t.lf_resolution[2] = t.lf_resolution[3] = st; });
  for (double scale : quick ? std::vector<double>{2} : std::vector<double>{0.5, 2})
    add("envelope-x" + fmt_number(scale), [&](TradePoint& t) { t.envelope_scale = scale; });
  // Detector binning.
  for (int bin : {2, 4}) add("bin" + std::to_string(bin), [&](TradePoint& t) { t.bin = bin; });
  // Similarity measures and plans.
  for (const auto& m : quick ? std::vector<std::string>{"ncc"} : tracking::similarity_names())
    if (m != base.similarity) add("sim-" + m, [&](TradePoint& t) { t.similarity = m; });
  // warm-robust: the tracking plan that holds up on realistic frames (issue 21), against the
  // baseline's warm on the same problems; warm-robust-ncc: the same with plain NCC, cheaper a
  // probe (issue 57).
  for (const auto& plan : quick ? std::vector<std::string>{"quadratic", "warm-robust"}
                                : std::vector<std::string>{"quadratic", "decoupled", "papers", "cmaes", "warm-robust",
                                                           "warm-robust-ncc"})
    add("plan-" + plan, [&](TradePoint& t) { t.plan = plan; });
  // Final step and time budget.
  for (double step : quick ? std::vector<double>{0.25} : std::vector<double>{0.05, 0.25, 0.5})
    add("step" + fmt_number(step), [&](TradePoint& t) { t.final_step_mm = step; });
  for (double budget : quick ? std::vector<double>{25} : std::vector<double>{10, 25, 50, 100})
    add("budget" + fmt_number(budget) + "ms", [&](TradePoint& t) { t.budget_ms = budget; });
  // Combinations: everything coarse, and a coarse field with binning.
  add("fast", [](TradePoint& t) {
    t.bin = 2;
    t.final_step_mm = 0.25;
    t.budget_ms = 25;
  });
  add("coarse-field-bin2", [&](TradePoint& t) {
    t.lf_resolution = {std::max(4, r[0] / 2), std::max(4, r[1] / 2), std::max(32, r[2] / 2),
                       std::max(32, r[3] / 2)};
    t.bin = 2;
  });
  return points;
}

int trade_problem_count(const TradeOptions& o) { return o.problems > 0 ? o.problems : (o.quick ? 6 : 24); }

Result<std::vector<TradePoint>> trade_shard_points(const PreparedScene& p, const TradeOptions& o,
                                                   int* points_total) {
  if (o.shards < 1 || o.shard < 1 || o.shard > o.shards)
    return out_of_range("trade study: shard " + std::to_string(o.shard) + "/" + std::to_string(o.shards) +
                        " (k/n needs 1 <= k <= n)");
  std::vector<TradePoint> all = trade_points(p, o.quick);
  if (!o.only.empty()) {
    std::vector<TradePoint> chosen;
    std::string known;
    for (const TradePoint& t : all) {
      known += (known.empty() ? "" : ", ") + t.id;
      if (std::find(o.only.begin(), o.only.end(), t.id) != o.only.end()) chosen.push_back(t);
    }
    for (const std::string& id : o.only)
      if (std::none_of(all.begin(), all.end(), [&](const TradePoint& t) { return t.id == id; }))
        return not_found("trade study: no point '" + id + "' (" + (o.quick ? "quick" : "full") +
                         " study: " + known + ")");
    all = std::move(chosen);
  }
  if (points_total) *points_total = int(all.size());
  std::vector<TradePoint> mine;
  for (std::size_t i = 0; i < all.size(); ++i)
    if (int(i % std::size_t(o.shards)) == o.shard - 1) mine.push_back(all[i]);
  return mine;
}

Status build_trade_fields(const PreparedScene& p, const TradeOptions& o, tracking::ThreadPool* pool,
                          const std::function<void(const std::string&)>& progress) {
  if (o.field_dir.empty()) return invalid_argument("trade study: building the fields needs a folder (--lf-dir)");
  TradeOptions whole = o;
  whole.shard = whole.shards = 1;
  auto points = trade_shard_points(p, whole);
  if (!points.ok()) return points.status();
  std::set<std::string> done;
  for (const TradePoint& t : *points) {
    if (t.renderer != "lightfield" || !done.insert(field_set_key(t.lf_resolution, t.envelope_scale)).second)
      continue;
    const auto dir = field_set_dir(o.field_dir, t.lf_resolution, t.envelope_scale);
    double build_s = 0;
    auto fields = field_set(p, t.lf_resolution, t.envelope_scale, dir, false, pool, &build_s);
    if (!fields.ok()) return fields.status();
    if (progress)
      progress(dir.string() + ": " + field_set_key(t.lf_resolution, t.envelope_scale) + ", built in " +
               fmt_number(build_s) + " s");
  }
  return {};
}

Result<TradeStudy> run_trade_study(const PreparedScene& p, const TradeOptions& o, tracking::ThreadPool* pool,
                                   const std::function<void(double, const std::string&)>& progress) {
  const int problem_count = trade_problem_count(o);
  int points_total = 0;
  auto mine = trade_shard_points(p, o, &points_total);
  if (!mine.ok()) return mine.status();
  TradeStudy study;
  study.scene = p.scene.name;
  study.fingerprint = study_scene_fingerprint(p);
  study.seed = o.seed;
  study.problems = problem_count;
  study.quick = o.quick;
  study.shard = o.shard;
  study.shards = o.shards;
  study.points_total = points_total;
  study.physics = o.physics_name;
  study.physics_description = sim_spec::describe(o.physics);
  study.verdict_tolerance_mm = p.scene.safety.beam_tolerance_mm;
  if (progress) progress(0, "making the problems");
  auto problems = make_problems(p, problem_count, o.seed, o.physics, pool);
  if (!problems.ok()) return problems.status();
  RendererCache renderers(p, o, pool);
  const double steps = double(mine->size()) * problem_count;
  double done = 0;
  for (const TradePoint& t : *mine) {
    if (progress) progress(done / steps, t.id);
    const auto point_started = Clock::now();
    TradeResult res;
    res.point = t;
    auto renderer = renderers.make(t, &res.memory_bytes, &res.precompute_s);
    if (!renderer.ok()) return renderer.status().with_context("point " + t.id);
    RegistrationSpec spec = p.scene.registration;
    spec.similarity = t.similarity;
    auto reg = make_scene_registration(p, *renderer, spec, pool, t.bin);
    if (!reg.ok()) return reg.status().with_context("point " + t.id);
    auto plan = point_plan(t);
    if (!plan.ok()) return plan.status().with_context("point " + t.id);
    // The scene's verdict for the point's measure, as the loop would judge with it.
    auto limits = scene_verdict_limits(p, t.similarity);
    if (!limits.ok()) return limits.status().with_context("point " + t.id);
    std::vector<double> ms, tre;
    int ok = 0;
    double ncc_sum = 0, psnr_sum = 0;
    int fidelity_n = 0, psnr_n = 0;
    for (Problem& pr : *problems) {
      LFTRACK_RETURN_IF_ERROR((*reg)->set_frames(pr.frames.frames(), pr.frames.masks()));
      auto result = (*reg)->run(pr.start, *plan);
      double final_tre = scene_tre(p, pr.start, pr.gold).mean_mm;
      double elapsed_ms = std::numeric_limits<double>::quiet_NaN();
      bool accepted = false;  // a failed registration: nothing to judge, rejected
      int verdict_reason = int(VerdictReason::kNoResult);
      if (result.ok()) {
        final_tre = scene_tre(p, result->T_room_from_ct, pr.gold).mean_mm;
        elapsed_ms = result->elapsed_ms;
        ms.push_back(result->elapsed_ms);
        auto judged = verdict_input_of(p, **renderer, pr.frames, pr.quality, *result);
        if (!judged.ok()) return judged.status().with_context("point " + t.id);
        const RegistrationVerdict verdict = judge_registration(*limits, *judged);
        accepted = verdict.ok;
        verdict_reason = int(verdict.reason);
      } else {
        spdlog::warn("point {}: {}", t.id, result.status().message());
        if (res.failed_runs++ == 0) res.failure = result.status().message();
      }
      res.problem_accepted.push_back(accepted);
      res.problem_verdict_reason.push_back(verdict_reason);
      tre.push_back(final_tre);
      res.problem_tre_mm.push_back(final_tre);
      res.problem_ms.push_back(elapsed_ms);
      ok += result.ok() && final_tre < 2.0;  // a failed registration is no success, wherever it started
      for (std::size_t v = 0; v < pr.siddon_drr.size(); ++v) {
        const tracking::PixelWindow& w = p.roi_windows[v];
        tracking::Image<float> drr(w.rows, w.cols);
        if (!(*renderer)->render(pr.gold, p.scene.detectors[v].view, w, drr.view()).ok()) continue;
        ncc_sum += tracking::normalized_cross_correlation(pr.siddon_drr[v].view(), drr.view());
        ++fidelity_n;
        const double psnr = tracking::psnr_db(pr.siddon_drr[v].view(), drr.view());
        if (std::isfinite(psnr)) {
          psnr_sum += psnr;
          ++psnr_n;
        }
      }
      done += 1;
      if (progress) progress(done / steps, t.id);
    }
    res.runs = problem_count;
    res.verdict = tally_trade_verdict(res, study.verdict_tolerance_mm);
    const double nan = std::numeric_limits<double>::quiet_NaN();
    res.median_ms = ms.empty() ? nan : quantile(ms, 0.5);  // no registration ran: no time
    res.p95_ms = ms.empty() ? nan : quantile(ms, 0.95);
    double sum = 0;
    for (double x : tre) sum += x;
    res.mean_tre_mm = sum / double(tre.size());
    res.p95_tre_mm = quantile(tre, 0.95);
    res.success_rate = double(ok) / problem_count;
    // Exact renderers give identical images (infinite PSNR); none rendered: unknown.
    res.ncc_vs_siddon = fidelity_n ? ncc_sum / fidelity_n : nan;
    res.psnr_db_vs_siddon = !fidelity_n ? nan
                            : psnr_n    ? psnr_sum / psnr_n
                                        : std::numeric_limits<double>::infinity();
    spdlog::debug("point {}: median {:.1f} ms, mean TRE {:.3f} mm, precompute {:.1f} s, {:.1f} s in all",
                  t.id, res.median_ms, res.mean_tre_mm, res.precompute_s, seconds_since(point_started));
    study.results.push_back(res);
  }
  return study;
}

}  // namespace lftrack::studies

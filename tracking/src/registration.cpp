#include "lftrack/tracking/registration.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::tracking {

// Scratch of one worker: a DRR and its mask per view, and the prepared similarity per blur level
// and view.
struct Registration::Slot {
  std::vector<Image<float>> drr;
  std::vector<Image<unsigned char>> valid;
  std::vector<std::vector<std::unique_ptr<Similarity>>> similarity;  // [level][view]
};

// The optimizer's view of one pass: x = delta from the start pose.
class Registration::Cost final : public CostFunction {
 public:
  Cost(Registration& r, const Pose& start, int level) : r_(r), start_(start), level_(level) {}
  double cost(const Vector6d& x) override {
    double out = 0;
    cost_batch(&x, 1, &out);
    return out;
  }
  // Spreads (candidate, view) pairs over the pool, so a batch of one still uses two threads.
  void cost_batch(const Vector6d* xs, int n, double* out) override {
    const int views = static_cast<int>(r_.setup_.views.size());
    const int slots = static_cast<int>(r_.slots_.size());
    const int tasks = n * views;
    if (r_.pool_ == nullptr || slots < 2 || tasks < 2 || n > kMaxBatch) {
      for (int i = 0; i < n; ++i) out[i] = r_.evaluate(0, level_, pose(xs[i]), nullptr);
      return;
    }
    for (int i = 0; i < n; ++i) inside_[i] = r_.inside_search_region(pose(xs[i]));
    const int grain = (tasks + slots - 1) / slots;
    r_.pool_->parallel_for(tasks, grain, [&](int begin, int end) {
      const int slot = begin / grain;
      for (int t = begin; t < end; ++t) {
        const int i = t / views;
        view_scores_[t] = inside_[i] ? r_.view_score(slot, level_, pose(xs[i]), t % views) : 0.0;
      }
    });
    for (int i = 0; i < n; ++i) {
      out[i] = inside_[i] ? r_.combine(pose(xs[i]), &view_scores_[i * views]) : std::numeric_limits<double>::infinity();
    }
  }
  Pose pose(const Vector6d& x) const {
    return apply_delta(start_, PoseDelta::from_vector(x), r_.setup_.origin_room_mm);
  }

 private:
  static constexpr int kMaxBatch = 64;
  static constexpr int kMaxViews = 4;
  Registration& r_;
  Pose start_;
  int level_;
  std::array<bool, kMaxBatch> inside_{};
  std::array<double, kMaxBatch * kMaxViews> view_scores_{};
};

Registration::~Registration() = default;

std::vector<std::string> registration_plan_names() {
  return {"papers", "decoupled", "quadratic", "cmaes", "warm"};
}

Result<RegistrationPlan> registration_plan(const std::string& name) {
  RegistrationPlan plan;
  plan.name = name;
  if (name == "papers" || name == "decoupled") {
    const std::string opt = name == "papers" ? "best-neighbour" : "decoupled";
    plan.passes = {{opt, 1.5, 5.0, 0.5, 3000}, {opt, 0.0, 2.0, 0.1, 3000}};
  } else if (name == "quadratic") {
    plan.passes = {{"quadratic-neighbour", 1.5, 5.0, 0.5, 3000}, {"quadratic-neighbour", 0.0, 2.0, 0.1, 3000}};
  } else if (name == "cmaes") {
    plan.passes = {{"cmaes", 1.5, 2.5, 0.5, 3000}, {"quadratic-neighbour", 0.0, 1.0, 0.1, 3000}};
  } else if (name == "warm") {
    plan.passes = {{"quadratic-neighbour", 0.0, 1.0, 0.1, 600}};
  } else {
    std::string known;
    for (const auto& n : registration_plan_names()) known += (known.empty() ? "" : ", ") + n;
    return invalid_argument("unknown registration plan '" + name + "' (known: " + known + ")");
  }
  return plan;
}

namespace {

// Mean projected displacement (detector mm) per unit of each delta component, over a 3x3x3
// grid of ROI points and every view.
Vector6d projected_motion_per_unit(const RegistrationSetup& s) {
  Vector6d motion = Vector6d::Zero();
  const double eps[6] = {0.01, 0.01, 0.01, 1e-5, 1e-5, 1e-5};
  int samples = 0;
  for (int i = 0; i < 6; ++i) {
    PoseDelta d;
    Vector6d v = Vector6d::Zero();
    v(i) = eps[i];
    d = PoseDelta::from_vector(v);
    const Pose moved = apply_delta(s.nominal_T_room_from_ct, d, s.origin_room_mm);
    double sum = 0;
    int n = 0;
    for (const RegistrationView& rv : s.views) {
      const double pitch = 0.5 * (rv.view.pitch_col_mm + rv.view.pitch_row_mm);
      for (int a = -1; a <= 1; ++a)
        for (int b = -1; b <= 1; ++b)
          for (int c = -1; c <= 1; ++c) {
            const Eigen::Vector3d p =
                s.roi_centre_ct_mm + 0.5 * Eigen::Vector3d(a, b, c).cwiseProduct(s.roi_size_mm);
            const auto p0 = rv.view.project(s.nominal_T_room_from_ct * p);
            const auto p1 = rv.view.project(moved * p);
            if (!p0 || !p1) continue;
            sum += (*p1 - *p0).norm() * pitch / eps[i];
            ++n;
          }
    }
    motion(i) = n > 0 ? sum / n : 0.0;
    samples += n;
  }
  (void)samples;
  return motion;
}

}  // namespace

Result<std::unique_ptr<Registration>> Registration::create(std::shared_ptr<const DrrRenderer> renderer,
                                                           RegistrationSetup setup, ThreadPool* pool) {
  if (!renderer) return invalid_argument("registration: no renderer");
  if (setup.views.empty() || setup.views.size() > 4) return invalid_argument("registration: needs 1 to 4 views");
  for (const RegistrationView& v : setup.views) {
    LFTRACK_RETURN_IF_ERROR(v.view.validate());
    if (!v.window.inside(v.view.rows, v.view.cols))
      return invalid_argument("registration: the window of view '" + v.view.name + "' lies outside its detector");
  }
  auto probe = make_similarity(setup.similarity, setup.similarity_options);
  if (!probe.ok()) return probe.status();
  std::unique_ptr<Registration> r(new Registration());
  r->renderer_ = std::move(renderer);
  r->pool_ = pool;
  r->levels_mm_ = {0.0};
  for (double s : setup.blur_sigmas_mm) {
    if (!std::isfinite(s) || s < 0) return invalid_argument("registration: blur sigmas must be >= 0");
    if (s > 0 && std::find(r->levels_mm_.begin(), r->levels_mm_.end(), s) == r->levels_mm_.end())
      r->levels_mm_.push_back(s);
  }
  const Vector6d motion = projected_motion_per_unit(setup);
  if (!(motion.array() > 1e-9).all() || !motion.allFinite())
    return invalid_argument("registration: a pose parameter does not move the ROI on any detector");
  r->scales_ = motion.cwiseInverse();
  r->setup_ = std::move(setup);
  const int slots = pool != nullptr ? std::max(1, pool->size()) : 1;
  for (int s = 0; s < slots; ++s) {
    auto slot = std::make_unique<Slot>();
    for (const RegistrationView& v : r->setup_.views) {
      slot->drr.emplace_back(v.window.rows, v.window.cols, 0.f);
      slot->valid.emplace_back(v.window.rows, v.window.cols, 0);
    }
    r->slots_.push_back(std::move(slot));
  }
  return r;
}

Status Registration::set_frames(const std::vector<ImageView<const float>>& frames,
                                const std::vector<ImageView<const unsigned char>>& valid) {
  const std::size_t nv = setup_.views.size();
  if (frames.size() != nv || (!valid.empty() && valid.size() != nv))
    return invalid_argument("registration: expected " + std::to_string(nv) + " frames (and masks)");
  for (std::size_t v = 0; v < nv; ++v) {
    const PixelWindow& w = setup_.views[v].window;
    if (frames[v].rows != w.rows || frames[v].cols != w.cols)
      return invalid_argument("registration: frame " + std::to_string(v) + " is " + std::to_string(frames[v].rows) +
                              " x " + std::to_string(frames[v].cols) + ", its window " + std::to_string(w.rows) +
                              " x " + std::to_string(w.cols));
  }
  for (auto& slot : slots_) {
    slot->similarity.clear();
    slot->similarity.resize(levels_mm_.size());
  }
  for (std::size_t v = 0; v < nv; ++v) {
    const PixelWindow& w = setup_.views[v].window;
    const ImageView<const unsigned char> mask = valid.empty() ? ImageView<const unsigned char>{} : valid[v];
    const double pitch = 0.5 * (setup_.views[v].view.pitch_col_mm + setup_.views[v].view.pitch_row_mm);
    Image<float> blurred(w.rows, w.cols);
    for (std::size_t level = 0; level < levels_mm_.size(); ++level) {
      GaussianBlur blur(w.rows, w.cols, levels_mm_[level] / pitch);
      LFTRACK_RETURN_IF_ERROR(blur.blur(frames[v], mask, blurred.view()));
      auto similarity = make_similarity(setup_.similarity, setup_.similarity_options);
      if (!similarity.ok()) return similarity.status();
      LFTRACK_RETURN_IF_ERROR((*similarity)->prepare(blurred.view(), mask));
      for (std::size_t s = 1; s < slots_.size(); ++s) slots_[s]->similarity[level].push_back((*similarity)->clone());
      slots_[0]->similarity[level].push_back(std::move(*similarity));
    }
  }
  frames_set_ = true;
  return {};
}

int Registration::blur_level(double sigma_mm) const {
  for (std::size_t i = 0; i < levels_mm_.size(); ++i)
    if (std::abs(levels_mm_[i] - sigma_mm) < 1e-9) return static_cast<int>(i);
  return -1;
}

bool Registration::inside_search_region(const Pose& T) const {
  if (setup_.search_translation_mm <= 0 && setup_.search_rotation_deg <= 0) return true;
  const Vector6d d = delta_between(setup_.nominal_T_room_from_ct, T, setup_.origin_room_mm).as_vector();
  if (!d.allFinite()) return false;
  if (setup_.search_translation_mm > 0 && d.head<3>().cwiseAbs().maxCoeff() > setup_.search_translation_mm)
    return false;
  if (setup_.search_rotation_deg > 0 && d.tail<3>().cwiseAbs().maxCoeff() > deg_to_rad(setup_.search_rotation_deg))
    return false;
  return true;
}

double Registration::view_score(int slot_index, int level, const Pose& T, int v) {
  Slot& slot = *slots_[static_cast<std::size_t>(slot_index)];
  const RegistrationView& rv = setup_.views[static_cast<std::size_t>(v)];
  RenderExtras extras;
  extras.valid = slot.valid[std::size_t(v)].view();
  Similarity& similarity = *slot.similarity[static_cast<std::size_t>(level)][std::size_t(v)];
  if (!renderer_->render(T, rv.view, rv.window, slot.drr[std::size_t(v)].view(), &extras).ok())
    return similarity.worst_score();
  const double valid_fraction = 1.0 - double(extras.masked_pixels) / (double(rv.window.rows) * rv.window.cols);
  if (valid_fraction < setup_.min_valid_fraction) return similarity.worst_score();
  return similarity.score(slot.drr[std::size_t(v)].view(), extras.valid);
}

double Registration::combine(const Pose& T, const double* view_scores) const {
  double cost = 0;
  for (std::size_t v = 0; v < setup_.views.size(); ++v) cost -= view_scores[v];
  if (fiducial_) cost += fiducial_->gamma_per_mm * (T * fiducial_->marker_ct_mm - fiducial_->marker_room_mm).norm();
  return std::isfinite(cost) ? cost : std::numeric_limits<double>::infinity();
}

double Registration::evaluate(int slot_index, int level, const Pose& T, std::vector<double>* view_scores) {
  if (view_scores == nullptr && !inside_search_region(T)) return std::numeric_limits<double>::infinity();
  std::array<double, 8> scores{};
  for (std::size_t v = 0; v < setup_.views.size() && v < scores.size(); ++v) {
    scores[v] = view_score(slot_index, level, T, int(v));
    if (view_scores != nullptr) (*view_scores)[v] = scores[v];
  }
  return combine(T, scores.data());
}

double Registration::cost_at(const Pose& T, double blur_sigma_mm) {
  const int level = blur_level(blur_sigma_mm);
  if (!frames_set_ || level < 0) return std::numeric_limits<double>::infinity();
  return evaluate(0, level, T, nullptr);
}

Result<RegistrationResult> Registration::run(const Pose& start, const RegistrationPlan& plan, bool record_trace) {
  if (!frames_set_) return failed_precondition("registration: no frames (call set_frames first)");
  if (!start.matrix().allFinite()) return invalid_argument("registration: the start pose is not finite");
  if (plan.passes.empty()) return invalid_argument("registration: the plan has no passes");
  const auto t0 = std::chrono::steady_clock::now();
  RegistrationResult result;
  Pose current = start;
  for (const RegistrationPass& pass : plan.passes) {
    const int level = blur_level(pass.blur_sigma_mm);
    if (level < 0)
      return invalid_argument("registration: blur " + std::to_string(pass.blur_sigma_mm) +
                              " mm was not prepared in the set-up");
    OptimizerSettings settings;
    settings.scale = scales_;
    settings.initial_step_mm = pass.initial_step_mm;
    settings.final_step_mm = pass.final_step_mm;
    settings.record_trace = record_trace;
    auto optimizer = make_optimizer(pass.optimizer, settings);
    if (!optimizer.ok()) return optimizer.status();
    OptimizerBudget budget;
    budget.max_evaluations = pass.max_evaluations;
    budget.max_ms = plan.max_ms - std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    Cost cost(*this, current, level);
    OptimizerResult r = (*optimizer)->minimize(cost, Vector6d::Zero(), budget);
    const Pose pass_start = current;
    current = cost.pose(r.x);
    result.evaluations += r.evaluations;
    result.cost = r.cost;
    result.stop = r.stop;
    for (const OptimizerTracePoint& p : r.trace) {
      OptimizerTracePoint q = p;
      q.evaluations += result.evaluations - r.evaluations;
      q.x = delta_between(start, cost.pose(p.x), setup_.origin_room_mm).as_vector();
      result.trace.push_back(q);
    }
    (void)pass_start;
    if (r.stop == OptimizerStop::kTimeBudget || r.stop == OptimizerStop::kNonFinite) break;
  }
  result.T_room_from_ct = orthonormalized(current);
  result.delta_from_start = delta_between(start, result.T_room_from_ct, setup_.origin_room_mm);
  result.view_similarity.assign(setup_.views.size(), 0.0);
  evaluate(0, 0, result.T_room_from_ct, &result.view_similarity);
  if (fiducial_)
    result.fiducial_distance_mm = (result.T_room_from_ct * fiducial_->marker_ct_mm - fiducial_->marker_room_mm).norm();
  result.elapsed_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

}  // namespace lftrack::tracking

// Registration (registration.hpp): the image levels, frames, references and the scores the
// passes evaluate. Running a plan's passes is registration_run.cpp's.

#include "lftrack/tracking/registration.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <mutex>
#include <optional>

#include "lftrack/tracking/frame_preprocessing.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::tracking {

// Scratch of one worker: a DRR and its mask per view, and the prepared similarity per measure,
// level and view (each slot prepares its own, so set_frames() reuses them without allocating).
struct Registration::Slot {
  std::vector<std::vector<Image<float>>> drr;            // [level][view]
  std::vector<std::vector<Image<unsigned char>>> valid;  // [level][view]
  std::vector<std::vector<std::optional<BoxHighPass>>> highpass;  // [level][view], levels with one
  // [level][view], levels with a high-pass: pixels usable in the DRR and in the reference, so
  // both are high-passed over the same pixels.
  std::vector<std::vector<Image<unsigned char>>> both_valid;
  std::vector<std::vector<std::vector<std::unique_ptr<Similarity>>>> similarity;  // [measure][level][view]
};

// The reference image of one level and view.
struct Registration::ReferenceLevel {
  ReferenceLevel(int rows, int cols, double blur_sigma_px, double highpass_sigma_px)
      : binned(rows, cols), binned_valid(rows, cols, 1), blurred(rows, cols), blur(rows, cols, blur_sigma_px) {
    if (highpass_sigma_px > 0) highpass.emplace(rows, cols, BoxHighPass::radius_for_sigma(highpass_sigma_px));
  }
  Image<float> binned;
  Image<unsigned char> binned_valid;
  Image<float> blurred;  // blurred and high-passed: what the level's measures compare DRRs with
  GaussianBlur blur;
  std::optional<BoxHighPass> highpass;
};

namespace {
double highpass_sigma_px(const RegistrationSetup::Level& l, const XrayView& view) {
  return l.highpass_sigma_mm > 0 ? l.highpass_sigma_mm / (0.5 * (view.pitch_col_mm + view.pitch_row_mm) * l.bin)
                                 : 0.0;
}
}  // namespace

Registration::~Registration() = default;


namespace {

// Mean projected displacement (detector mm) per unit of each delta component, over a 3x3x3
// grid of ROI points and every view.
Vector6d projected_motion_per_unit(const RegistrationSetup& s) {
  Vector6d motion = Vector6d::Zero();
  const double eps[6] = {0.01, 0.01, 0.01, 1e-5, 1e-5, 1e-5};
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
  }
  return motion;
}

}  // namespace

Result<std::unique_ptr<Registration>> Registration::create(std::shared_ptr<const DrrRenderer> renderer,
                                                           RegistrationSetup setup, ThreadPool* pool) {
  if (!renderer) return invalid_argument("registration: no renderer");
  if (setup.views.empty() || setup.views.size() > 4)
    return invalid_argument("registration: needs 1 to 4 views");
  for (const RegistrationView& v : setup.views) {
    LFTRACK_RETURN_IF_ERROR(v.view.validate());
    if (!v.window.inside(v.view.rows, v.view.cols))
      return invalid_argument("registration: the window of view '" + v.view.name +
                              "' lies outside its detector");
  }
  std::unique_ptr<Registration> r(new Registration());
  r->renderer_ = std::move(renderer);
  r->pool_ = pool;
  const Vector6d motion = projected_motion_per_unit(setup);
  if (!(motion.array() > 1e-9).all() || !motion.allFinite())
    return invalid_argument("registration: a pose parameter does not move the ROI on any detector");
  r->scales_ = motion.cwiseInverse();
  r->setup_ = std::move(setup);
  const int slots = pool != nullptr ? std::max(1, pool->size()) : 1;
  for (int s = 0; s < slots; ++s) r->slots_.push_back(std::make_unique<Slot>());
  for (const auto& view : r->setup_.views) {
    const Image<unsigned char>& region = view.region;
    if (!region.pixels().empty() && (region.rows() != view.window.rows || region.cols() != view.window.cols))
      return invalid_argument("registration: view " + view.view.name + "'s region is " + std::to_string(region.rows()) +
                              " x " + std::to_string(region.cols()) + ", its window " + std::to_string(view.window.rows) +
                              " x " + std::to_string(view.window.cols));
    r->frames_.emplace_back(view.window.rows, view.window.cols);
    r->frame_masks_.emplace_back(view.window.rows, view.window.cols, 1);
  }
  LFTRACK_RETURN_IF_ERROR(r->level_for({0.0, 1, 0.0}).status());  // level 0: the originals
  for (const RegistrationSetup::Level& l : r->setup_.levels) LFTRACK_RETURN_IF_ERROR(r->level_for(l).status());
  LFTRACK_RETURN_IF_ERROR(r->measure_index(r->setup_.similarity).status());
  return r;
}

Result<int> Registration::level_for(const RegistrationSetup::Level& l) {
  if (!std::isfinite(l.blur_sigma_mm) || l.blur_sigma_mm < 0 || l.blur_sigma_mm > 1000 || l.bin < 1 ||
      l.bin > 16 || !std::isfinite(l.highpass_sigma_mm) || l.highpass_sigma_mm < 0 || l.highpass_sigma_mm > 1000)
    return invalid_argument(
        "registration: a level needs a blur of 0 to 1000 mm, a binning of 1 to 16 and a high-pass of 0 to 1000 mm");
  const int known = level_index(l.blur_sigma_mm, l.bin, l.highpass_sigma_mm);
  if (known >= 0) return known;
  if (const RegistrationView* small = view_too_small_for(l.bin))
    return invalid_argument("registration: binning " + std::to_string(l.bin) + " leaves view '" + small->view.name +
                            "' fewer than 4 x 4 pixels");
  // A region (roi.mask) must leave the measures enough blocks at this binning (a block counts
  // when most of it is in the region, as make_reference counts a frame's valid pixels): a level
  // with fewer would score every pose the same.
  for (const RegistrationView& v : setup_.views) {
    if (v.region.pixels().empty()) continue;
    int blocks = 0;
    for (int r = 0; r + l.bin <= v.window.rows; r += l.bin)
      for (int c = 0; c + l.bin <= v.window.cols; c += l.bin) {
        int in = 0;
        for (int dr = 0; dr < l.bin; ++dr)
          for (int dc = 0; dc < l.bin; ++dc) in += v.region.at(r + dr, c + dc) != 0;
        blocks += 2 * in > l.bin * l.bin;
      }
    if (blocks < Similarity::kMinPixels)
      return invalid_argument("registration: view " + v.view.name + "'s region (roi.mask) leaves " + std::to_string(blocks) +
                              " pixels at binning " + std::to_string(l.bin) + ", fewer than the " +
                              std::to_string(Similarity::kMinPixels) + " a measure needs");
  }
  LevelGeometry g;
  g.level = l;
  for (const RegistrationView& v : setup_.views) {
    const int rows = v.window.rows / l.bin, cols = v.window.cols / l.bin;
    g.views.push_back(l.bin == 1 ? v.view
                                 : v.view.resampled(v.window.row0, v.window.col0, rows * l.bin, cols * l.bin,
                                                    rows, cols));
    g.windows.push_back(l.bin == 1 ? v.window : PixelWindow::full(rows, cols));
  }
  const std::size_t index = levels_.size();
  for (auto& slot : slots_) {
    slot->drr.emplace_back();
    slot->valid.emplace_back();
    slot->highpass.emplace_back();
    slot->both_valid.emplace_back();
    for (std::size_t v = 0; v < g.windows.size(); ++v) {
      const PixelWindow& w = g.windows[v];
      slot->drr[index].emplace_back(w.rows, w.cols, 0.f);
      slot->valid[index].emplace_back(w.rows, w.cols, 0);
      const double hp = highpass_sigma_px(l, setup_.views[v].view);
      auto& filter = slot->highpass[index].emplace_back();
      if (hp > 0) filter.emplace(w.rows, w.cols, BoxHighPass::radius_for_sigma(hp));
      slot->both_valid[index].emplace_back(hp > 0 ? w.rows : 0, hp > 0 ? w.cols : 0, 0);
    }
    // Every measure made so far gets this level's similarities.
    for (std::size_t m = 0; m < slot->similarity.size(); ++m) {
      auto& per_level = slot->similarity[m];
      per_level.emplace_back();
      for (std::size_t v = 0; v < g.windows.size(); ++v) {
        auto made = make_similarity(measure_names_[m], level_similarity_options(g, v));
        if (!made.ok()) return made.status();
        per_level[index].push_back(std::move(made).value());
      }
    }
  }
  references_.emplace_back();
  for (std::size_t v = 0; v < setup_.views.size(); ++v) {
    const XrayView& view = setup_.views[v].view;
    const double pitch = 0.5 * (view.pitch_col_mm + view.pitch_row_mm);
    references_[index].push_back(std::make_unique<ReferenceLevel>(
        g.windows[v].rows, g.windows[v].cols, l.blur_sigma_mm / (pitch * l.bin), highpass_sigma_px(l, view)));
  }
  references_made_.push_back(0);
  for (auto& prepared : level_prepared_) prepared.push_back(0);
  for (auto& times : pass_times_) times.emplace_back();
  levels_.push_back(std::move(g));
  return int(index);
}

Status Registration::set_frames(const std::vector<ImageView<const float>>& frames,
                                const std::vector<ImageView<const unsigned char>>& valid) {
  const std::size_t nv = setup_.views.size();
  if (frames.size() != nv || (!valid.empty() && valid.size() != nv))
    return invalid_argument("registration: expected " + std::to_string(nv) + " frames (and masks)");
  for (std::size_t v = 0; v < nv; ++v) {
    const PixelWindow& w = setup_.views[v].window;
    if (frames[v].rows != w.rows || frames[v].cols != w.cols)
      return invalid_argument("registration: frame " + std::to_string(v) + " is " +
                              std::to_string(frames[v].rows) + " x " + std::to_string(frames[v].cols) +
                              ", its window " + std::to_string(w.rows) + " x " + std::to_string(w.cols));
    if (!valid.empty() && !valid[v].empty() && (valid[v].rows != w.rows || valid[v].cols != w.cols))
      return invalid_argument("registration: mask " + std::to_string(v) + " differs in size from its frame");
  }
  frames_set_ = false;
  for (std::size_t v = 0; v < nv; ++v) {
    const PixelWindow& w = setup_.views[v].window;
    for (int r = 0; r < w.rows; ++r) {
      std::copy(frames[v].row_ptr(r), frames[v].row_ptr(r) + w.cols, frames_[v].view().row_ptr(r));
      unsigned char* mask_row = frame_masks_[v].view().row_ptr(r);
      if (valid.empty() || valid[v].empty())
        std::fill(mask_row, mask_row + w.cols, static_cast<unsigned char>(1));
      else
        std::copy(valid[v].row_ptr(r), valid[v].row_ptr(r) + w.cols, mask_row);
      if (const Image<unsigned char>& region = setup_.views[v].region; !region.pixels().empty()) {
        const unsigned char* in_region = region.view().row_ptr(r);
        for (int c = 0; c < w.cols; ++c) mask_row[c] = static_cast<unsigned char>(mask_row[c] && in_region[c]);
      }
    }
  }
  for (auto& prepared : level_prepared_) std::fill(prepared.begin(), prepared.end(), 0);
  std::fill(references_made_.begin(), references_made_.end(), 0);
  frames_set_ = true;
  return {};
}

SimilarityOptions Registration::level_similarity_options(const LevelGeometry& level, std::size_t view) const {
  SimilarityOptions o = setup_.similarity_options;
  if (level.level.bin == 1) return o;  // the originals' scores are the gate's: the setup's measure
  // A joint histogram wants a few pixels per cell: on a binned level, halve the bins while there
  // are fewer than two pixels per cell, down to 16 (a 4 x 4 binned window of about 3,000 pixels
  // gets 32 of 64; on the lumbar CT that lowered the warm plan's mean TRE and its time).
  const long pixels = long(level.windows[view].rows) * level.windows[view].cols;
  while (o.histogram_bins > 16 && long(o.histogram_bins) * o.histogram_bins > pixels / 2)
    o.histogram_bins = std::max(16, o.histogram_bins / 2);
  return o;
}

Result<int> Registration::measure_index(const std::string& name) {
  const std::string wanted = name.empty() ? setup_.similarity : name;
  for (std::size_t m = 0; m < measure_names_.size(); ++m)
    if (measure_names_[m] == wanted) return int(m);
  // An unknown name is refused before any slot changes.
  if (auto probe = make_similarity(wanted, setup_.similarity_options); !probe.ok()) return probe.status();
  for (auto& slot : slots_) {
    auto& per_level = slot->similarity.emplace_back(levels_.size());
    for (std::size_t l = 0; l < levels_.size(); ++l)
      for (std::size_t v = 0; v < setup_.views.size(); ++v) {
        auto made = make_similarity(wanted, level_similarity_options(levels_[l], v));
        if (!made.ok()) return made.status();
        per_level[l].push_back(std::move(made).value());
      }
  }
  measure_names_.push_back(wanted);
  level_prepared_.emplace_back(levels_.size(), 0);
  pass_times_.emplace_back(levels_.size());
  return int(measure_names_.size() - 1);
}

Status Registration::prepare_level(int measure, int level) {
  char& prepared = level_prepared_[std::size_t(measure)][std::size_t(level)];
  if (prepared != 0) return {};
  // Views (then slots and views) are independent: spread over the pool, whose threads would
  // otherwise wait (a full-resolution level's references and measures take about a millisecond).
  // A failure is kept (one of them, if several fail) and returned.
  const int views = static_cast<int>(setup_.views.size());
  const auto spread = [&](int tasks, const auto& task) -> Status {
    std::mutex failure_mutex;
    Status failure;
    const auto body = [&](int begin, int end) {
      for (int t = begin; t < end; ++t) {
        Status s = task(t);
        if (s.ok()) continue;
        const std::lock_guard lock(failure_mutex);
        if (failure.ok()) failure = std::move(s);
      }
    };
    if (pool_ != nullptr)
      pool_->parallel_for(tasks, 1, body);
    else
      body(0, tasks);
    return failure;
  };
  if (references_made_[std::size_t(level)] == 0) {
    LFTRACK_RETURN_IF_ERROR(spread(views, [&](int v) { return make_reference(level, v); }));
    references_made_[std::size_t(level)] = 1;
  }
  const int slots = static_cast<int>(slots_.size());
  LFTRACK_RETURN_IF_ERROR(spread(slots * views, [&](int t) {
    const ReferenceLevel& ref = *references_[std::size_t(level)][std::size_t(t % views)];
    return slots_[std::size_t(t / views)]->similarity[std::size_t(measure)][std::size_t(level)][std::size_t(t % views)]
        ->prepare(ref.blurred.view(), ref.binned_valid.view());
  }));
  prepared = 1;
  return {};
}

Status Registration::make_reference(int level, int v) {
  const int bin = levels_[std::size_t(level)].level.bin;
  const bool blurred = levels_[std::size_t(level)].level.blur_sigma_mm > 0;
  const ImageView<const float> frame = frames_[std::size_t(v)].view();
  const ImageView<const unsigned char> mask = frame_masks_[std::size_t(v)].view();
  const PixelWindow& lw = levels_[std::size_t(level)].windows[std::size_t(v)];
  ReferenceLevel& ref = *references_[std::size_t(level)][std::size_t(v)];
  if (bin == 1) {  // the originals: usable where the mask says so and the value is finite
    for (int r = 0; r < lw.rows; ++r) {
      const float* in = frame.row_ptr(r);
      const unsigned char* ok = mask.row_ptr(r);
      float* out = ref.binned.view().row_ptr(r);
      unsigned char* out_ok = ref.binned_valid.view().row_ptr(r);
      for (int c = 0; c < lw.cols; ++c) {
        const bool usable = ok[c] != 0 && std::isfinite(in[c]);
        out_ok[c] = usable ? 1 : 0;
        out[c] = usable ? in[c] : 0.f;
      }
    }
  } else {
    // Bin: the mean of the usable pixels of each block; a block is usable if most of it is.
    for (int r = 0; r < lw.rows; ++r) {
      for (int c = 0; c < lw.cols; ++c) {
        double sum = 0;
        int n = 0;
        for (int dr = 0; dr < bin; ++dr)
          for (int dc = 0; dc < bin; ++dc) {
            const int rr = r * bin + dr, cc = c * bin + dc;
            const float value = frame.at(rr, cc);
            if (mask.at(rr, cc) == 0 || !std::isfinite(value)) continue;
            sum += value;
            ++n;
          }
        ref.binned_valid.at(r, c) = 2 * n > bin * bin ? 1 : 0;
        ref.binned.at(r, c) = n > 0 ? static_cast<float>(sum / n) : 0.f;
      }
    }
  }
  if (blurred)
    LFTRACK_RETURN_IF_ERROR(ref.blur.blur(ref.binned.view(), ref.binned_valid.view(), ref.blurred.view()));
  else  // a blur of width 0 is the identity
    ref.blurred.pixels() = ref.binned.pixels();
  if (ref.highpass)
    LFTRACK_RETURN_IF_ERROR(ref.highpass->apply(ref.blurred.view(), ref.binned_valid.view(), ref.blurred.view()));
  return {};
}

const RegistrationView* Registration::view_too_small_for(int bin) const {
  for (const RegistrationView& v : setup_.views)
    if (v.window.rows / bin < 4 || v.window.cols / bin < 4) return &v;
  return nullptr;
}

int Registration::level_index(double blur_sigma_mm, int bin, double highpass_sigma_mm) const {
  for (std::size_t i = 0; i < levels_.size(); ++i)
    if (levels_[i].level.bin == bin && std::abs(levels_[i].level.blur_sigma_mm - blur_sigma_mm) < 1e-9 &&
        std::abs(levels_[i].level.highpass_sigma_mm - highpass_sigma_mm) < 1e-9)
      return static_cast<int>(i);
  return -1;
}

bool Registration::inside_search_region(const Pose& T) const {
  if (setup_.search_translation_mm <= 0 && setup_.search_rotation_deg <= 0) return true;
  const Vector6d d = delta_between(setup_.nominal_T_room_from_ct, T, setup_.origin_room_mm).as_vector();
  if (!d.allFinite()) return false;
  if (setup_.search_translation_mm > 0 && d.head<3>().cwiseAbs().maxCoeff() > setup_.search_translation_mm)
    return false;
  if (setup_.search_rotation_deg > 0 &&
      d.tail<3>().cwiseAbs().maxCoeff() > deg_to_rad(setup_.search_rotation_deg))
    return false;
  return true;
}

double Registration::view_score(int slot_index, int measure, int level, const Pose& T, int v) {
  Slot& slot = *slots_[static_cast<std::size_t>(slot_index)];
  const std::size_t l = static_cast<std::size_t>(level), vi = static_cast<std::size_t>(v);
  const XrayView& view = levels_[l].views[vi];
  const PixelWindow& window = levels_[l].windows[vi];
  RenderExtras extras;
  extras.valid = slot.valid[l][vi].view();
  Similarity& similarity = *slot.similarity[std::size_t(measure)][l][vi];
  if (!renderer_->render(T, view, window, slot.drr[l][vi].view(), &extras).ok())
    return similarity.worst_score();
  const double valid_fraction = 1.0 - double(extras.masked_pixels) / (double(window.rows) * window.cols);
  if (valid_fraction < setup_.min_valid_fraction) return similarity.worst_score();
  if (auto& highpass = slot.highpass[l][vi]; highpass) {
    // Over the pixels usable in both images (the reference's were high-passed over its own).
    const ImageView<const unsigned char> reference_valid = references_[l][vi]->binned_valid.view();
    ImageView<unsigned char> both = slot.both_valid[l][vi].view();
    for (int r = 0; r < window.rows; ++r)
      for (int c = 0; c < window.cols; ++c)
        both.at(r, c) = static_cast<unsigned char>(extras.valid.at(r, c) != 0 && reference_valid.at(r, c) != 0);
    if (!highpass->apply(slot.drr[l][vi].view(), both, slot.drr[l][vi].view()).ok()) return similarity.worst_score();
  }
  return similarity.score(slot.drr[l][vi].view(), extras.valid);
}

double Registration::combine(const Pose& T, const double* view_scores) const {
  double cost = 0;
  for (std::size_t v = 0; v < setup_.views.size(); ++v) cost -= view_scores[v];
  if (fiducial_)
    cost += fiducial_->gamma_per_mm * (T * fiducial_->marker_ct_mm - fiducial_->marker_room_mm).norm();
  return std::isfinite(cost) ? cost : std::numeric_limits<double>::infinity();
}

double Registration::evaluate(int slot_index, int measure, int level, const Pose& T,
                              std::vector<double>* view_scores) {
  if (view_scores == nullptr && !inside_search_region(T)) return std::numeric_limits<double>::infinity();
  std::array<double, 8> scores{};
  for (std::size_t v = 0; v < setup_.views.size() && v < scores.size(); ++v) {
    scores[v] = view_score(slot_index, measure, level, T, int(v));
    if (view_scores != nullptr) (*view_scores)[v] = scores[v];
  }
  return combine(T, scores.data());
}

double Registration::cost_at(const Pose& T, double blur_sigma_mm, int bin, double highpass_sigma_mm) {
  const int level = level_index(blur_sigma_mm, bin, highpass_sigma_mm);
  if (!frames_set_ || level < 0 || !prepare_level(0, level).ok()) return std::numeric_limits<double>::infinity();
  return evaluate(0, 0, level, T, nullptr);
}

}  // namespace lftrack::tracking

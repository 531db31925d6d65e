#pragma once
// Intensity-based 2D-3D registration over one or more X-ray views (PAPERS.md, papers 1-3):
// render DRRs of the ROI windows at a candidate pose, score them against the preprocessed frames
// (sum over views), and let an optimizer move the pose 6-vector about the registration origin.
// An optional fiducial term adds paper 2's hybrid measure: cost = -sum(S_k) + gamma * d.
//
// create() and prepare_plan() allocate, and so does the first run() of a prepared plan (its
// measures size their scratch on their first frames); after that set_frames() and run() with a
// prepared plan allocate nothing (so the real-time cycle may call them once a first registration,
// the loop's ALIGN, has run), and candidates of a batch are evaluated in parallel on the pool.

#include <Eigen/Core>
#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/optimizer.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/similarity.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::tracking {

class ThreadPool;

struct RegistrationView {
  XrayView view;       // room frame, the whole detector
  PixelWindow window;  // the ROI pixels that are registered
  // Where in the window the measures may look (a scene's roi.mask: the target's neighbourhood
  // projected): 1 to use a pixel, 0 to ignore it, the window's size; empty: the whole window.
  // It is fixed on the detector; every frame's own validity mask is and-ed with it.
  Image<unsigned char> region;
};

struct RegistrationSetup {
  std::vector<RegistrationView> views;
  Eigen::Vector3d origin_room_mm = Eigen::Vector3d::Zero();  // registration origin c
  // The ROI box (CT frame) whose projected voxels set the parameter scales, and the pose at
  // which they are measured.
  Eigen::Vector3d roi_centre_ct_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d roi_size_mm{64, 64, 40};
  Pose nominal_T_room_from_ct = Pose::Identity();
  std::string similarity = "mi";
  SimilarityOptions similarity_options;
  // Image levels the passes may ask for: a blur (sigma, mm on the detector) of the reference
  // frames, a detector binning (K x K pixels averaged into one, for frames and DRRs alike), and a
  // high-pass (BoxHighPass of that sigma, mm on the detector; 0: none) applied to frames and DRRs
  // alike, which leaves out what the CT cannot explain because it varies slowly: scatter, soft
  // tissue that moved, a flat-field residue. The originals (0 mm, bin 1, no high-pass) are always
  // available.
  struct Level {
    double blur_sigma_mm = 0;
    int bin = 1;
    double highpass_sigma_mm = 0;
  };
  // Levels made at create(); a plan's passes make the levels they name at prepare_plan().
  std::vector<Level> levels{{1.5, 1, 0}, {1.5, 2, 0}, {0.0, 2, 0}};
  // A candidate whose DRR has fewer valid pixels than this fraction of a window scores the
  // measure's worst value in that view (a pose outside a light field's envelope).
  double min_valid_fraction = 0.9;
  // The search region: candidates whose delta from the nominal pose (about the origin) exceeds
  // these per-axis limits cost +infinity, so no optimizer wanders to where the images barely
  // overlap (where mutual information has spurious maxima) or reports a pose nobody could apply.
  // Non-positive: unbounded.
  double search_translation_mm = 0;
  double search_rotation_deg = 0;
};

// Paper 2's fiducial term: d = |T * marker_ct - marker_room|.
struct FiducialTerm {
  Eigen::Vector3d marker_ct_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d marker_room_mm = Eigen::Vector3d::Zero();  // triangulated from the frames
  double gamma_per_mm = 0.05;
};

struct RegistrationPass {
  std::string optimizer = "best-neighbour";
  double blur_sigma_mm = 0;  // with `bin` and `highpass_sigma_mm`, the pass's image level
  int bin = 1;
  double initial_step_mm = 2.0;
  double final_step_mm = 0.1;
  int max_evaluations = 3000;
  // The measure this pass optimizes (a make_similarity name); empty: the setup's. The result's
  // view_similarity is always the setup's measure on the originals, so a gate's thresholds keep
  // their meaning.
  std::string similarity;
  double highpass_sigma_mm = 0;  // with blur and bin, the level
  // quadratic-neighbour: stop once the parabola jump is this short (projected mm; 0: off, halve
  // down to the final step). OptimizerSettings::tolerance_mm.
  double tolerance_mm = 0;
  // quadratic-neighbour: move the translations only (OptimizerSettings::translations_only).
  bool translations_only = false;
};

struct RegistrationPlan {
  std::string name;
  std::vector<RegistrationPass> passes;
  double max_ms = 1e12;  // wall-time budget of the whole plan
};

// Named plans, in a stable order:
//   papers     best-neighbour on references blurred 1.5 mm, steps 5 -> 0.5 mm, then on the
//              originals, 2 -> 0.1 mm (papers 1 and 2), full resolution throughout
//   decoupled  paper 3's decoupled quadratic-fit optimizer in the same two passes
//   quadratic  quadratic-neighbour in the papers' two passes, the blurred one on 4 x 4 binned
//              images (a 1.5 mm blur leaves nothing for full resolution to add; 4 x 4 bins of
//              0.4 mm pixels still sample it at its sigma). On 2 x 2 bins that pass cost 3-4 times
//              as much, at the same capture and accuracy on 1,440 starts (BENCHMARKS.md, "The
//              cold plan's first pass on 4 x 4 bins")
//   cmaes      CMA-ES on the blurred, binned references (sigma 2.5 -> 0.5 mm) for range, then
//              quadratic-neighbour on the originals 1 -> 0.1 mm
//   warm       tracking from the last pose: quadratic-neighbour on 8 x 8 binned originals
//              1 -> 0.5 mm, on 4 x 4 binned ones 0.5 -> 0.25 mm, then one iteration at full
//              resolution with 0.25 mm probes (the parabola jump lands the result; a second
//              iteration at 0.125 mm, or a 2 x 2 binned first pass, did not lower the mean TRE on
//              the lumbar CT). The 8 x 8 pass does the travelling at a quarter of the 4 x 4 pass's
//              cost a probe: the binned passes took 2.8 instead of 4.3 ms, at the same mean TRE
//              (BENCHMARKS.md, "Tracking at 30 Hz")
//   robust     the translations alone (rotations held) on quadratic's first level high-passed at
//              7 mm with rncc (5 -> 1 mm), then quadratic's first pass with the setup's measure
//              (for range), then robust NCC (rncc:
//              Tukey's biweight on the residual) of frames and DRRs high-passed at 7 mm
//              (BoxHighPass), 2 -> 0.1 mm: what varies slowly across the image (scatter, soft
//              tissue and neighbours that moved, flat-field residue) no longer pulls the pose, nor
//              do the sharp edges the high-pass keeps but the CT cannot explain (the heart and
//              aorta after breathing). On the lumbar CT's clinical frames the high-pass took
//              MI's mean TRE from 0.55 to 0.30 mm; on the thoracic CT with 8 mm breathing rncc
//              halves plain NCC's (0.54 to 0.26 mm), and costs about 30 % more a registration
//              (BENCHMARKS.md, "Follow the target")
//   warm-robust  tracking clinical frames: quadratic-neighbour with robust's high-passed rncc on
//              2 x 2 binned originals (1 -> 0.25 mm), then at full resolution with probes of
//              0.25 and 0.125 mm
//   warm-robust-fast  the same measure on 8 x 8 binned originals (1 -> 0.25 mm), then 0.25 mm
//              probes on 2 x 2 binned ones until they settle: a seventh of warm-robust's time at
//              its mean TRE on the lumbar clinical scene, a larger largest error on the thoracic
//              one; opt-in (its commissioning of the thoracic clinical scene did not generalise)
//   robust-ncc, warm-robust-ncc  the same with plain NCC in the high-passed passes (the plans
//              before rncc): cheaper a probe, pulled by edges that moved
//   pyramid    the cold set-up at half quadratic's time: quadratic-neighbour on 4 x 4 binned
//              references blurred 1.5 mm (5 -> 0.5 mm), on 4 x 4 binned originals (1 -> 0.25 mm),
//              then a single full-resolution iteration (0.25 mm), as warm's last pass
std::vector<std::string> registration_plan_names();
Result<RegistrationPlan> registration_plan(const std::string& name);

// The most passes a plan may have (prepare_plan refuses more).
inline constexpr std::size_t kMaxRegistrationPasses = 8;

// What one pass of a plan did: where a registration's time and evaluations go.
struct RegistrationPassSummary {
  int evaluations = 0;
  double elapsed_ms = 0;  // wall time, with the references of the levels it is the first to use
  OptimizerStop stop = OptimizerStop::kConverged;
};

struct RegistrationResult {
  Pose T_room_from_ct = Pose::Identity();
  PoseDelta delta_from_start;           // about the origin
  double cost = 0;                      // of the last pass (lower is better)
  // The setup's measure on the originals, per view, at the result (the last pass's best candidate's
  // scores when that pass ran there: the result before re-orthonormalisation, which moves it by
  // rounding only).
  std::vector<double> view_similarity;
  double fiducial_distance_mm = -1;     // with a fiducial term
  int evaluations = 0;
  double elapsed_ms = 0;
  OptimizerStop stop = OptimizerStop::kConverged;
  std::vector<OptimizerTracePoint> trace;  // x: delta from the start pose
  // Per pass of the plan, in order (a pass after one stopped by the time budget or a non-finite
  // cost has none); room for kMaxRegistrationPasses is reserved on a result's first run.
  std::vector<RegistrationPassSummary> passes;
};

// A plan with its optimizers made and its image levels resolved, for one Registration.
struct PreparedPlan {
  RegistrationPlan plan;
  std::vector<std::unique_ptr<Optimizer>> optimizers;  // per pass
  std::vector<int> levels;                             // per pass
  std::vector<int> measures;                           // per pass: index into the measures made
  bool record_trace = false;
  const class Registration* owner = nullptr;           // the indices above are this one's
};

class Registration {
 public:
  ~Registration();
  static Result<std::unique_ptr<Registration>> create(std::shared_ptr<const DrrRenderer> renderer,
                                                      RegistrationSetup setup, ThreadPool* pool);

  const RegistrationSetup& setup() const { return setup_; }
  // Parameter scales: the change of each delta component that moves the ROI's projected voxels
  // by 1 mm on the detectors, averaged over points and views.
  const Vector6d& parameter_scales() const { return scales_; }

  // The preprocessed frames of the views' windows (line integrals) and their masks (empty:
  // all valid), copied; the binned and blurred references of a level are made when a run first
  // needs it (their time is the run's).
  Status set_frames(const std::vector<ImageView<const float>>& frames,
                    const std::vector<ImageView<const unsigned char>>& valid);
  void set_fiducial(const std::optional<FiducialTerm>& term) { fiducial_ = term; }

  // Registers from `start`. Fails before set_frames(), for an unknown optimizer or measure, or a
  // level out of range (levels the set-up did not name are made here).
  Result<RegistrationResult> run(const Pose& start_T_room_from_ct, const RegistrationPlan& plan,
                                 bool record_trace = false);

  // Makes the plan's optimizers and the similarity measures its passes name, and checks its
  // levels, once, outside the cycle (not while a run is under way).
  Result<PreparedPlan> prepare_plan(const RegistrationPlan& plan, bool record_trace = false);
  // Registers from `start` within `max_ms` (and the plan's own budget) into `result`. Allocates
  // nothing when the plan records no trace and `result` has held a result of this registration
  // before (its per-view vector keeps its capacity). The budget and every time in the result are
  // counted on `clock` (null: the steady clock; a test's virtual clock must outlive the run).
  Status run(const Pose& start_T_room_from_ct, const PreparedPlan& plan, double max_ms,
             RegistrationResult* result, const BudgetClock* clock = nullptr);

  // The cost of one pose at an image level (for tests and plots); +infinity for a level that
  // was not prepared.
  double cost_at(const Pose& T_room_from_ct, double blur_sigma_mm = 0, int bin = 1,
                 double highpass_sigma_mm = 0);

 private:
  class Cost;
  struct Slot;
  struct ReferenceLevel;
  Registration() = default;
  int level_index(double blur_sigma_mm, int bin, double highpass_sigma_mm) const;
  // The first view whose window binned by `bin` has fewer than 4 x 4 pixels (null: none).
  const RegistrationView* view_too_small_for(int bin) const;
  bool inside_search_region(const Pose& T) const;
  // Cost of T at `level` under measure `measure` (0: the setup's).
  double evaluate(int slot, int measure, int level, const Pose& T, std::vector<double>* view_scores);
  // Similarity of view v at T (worst score where the DRR fails or is mostly masked).
  double view_score(int slot, int measure, int level, const Pose& T, int v);
  // The index of measure `name` among those made (empty: 0, the setup's), making it for every
  // slot, level and view if it is new.
  Result<int> measure_index(const std::string& name);
  // The index of level `l`, making its geometry, scratch and references if it is new.
  Result<int> level_for(const RegistrationSetup::Level& l);
  // Cost from the per-view scores: minus their sum, plus the fiducial term.
  double combine(const Pose& T, const double* view_scores) const;

  std::shared_ptr<const DrrRenderer> renderer_;
  RegistrationSetup setup_;
  ThreadPool* pool_ = nullptr;
  Vector6d scales_ = Vector6d::Ones();
  // Per level: its blur and binning, and the views and windows its DRRs are rendered for
  // (binned views cover the same detector area with fewer, larger pixels). Level 0: originals.
  struct LevelGeometry {
    RegistrationSetup::Level level;
    std::vector<XrayView> views;
    std::vector<PixelWindow> windows;
  };
  std::vector<LevelGeometry> levels_;
  std::vector<std::unique_ptr<Slot>> slots_;
  // Per level and view: the reference frame binned and blurred, and the blur that makes it.
  std::vector<std::vector<std::unique_ptr<ReferenceLevel>>> references_;
  // The frames of set_frames(), per view, kept until the next call; a level's references are
  // made from them when a run first needs that level (a tracking plan never pays for the
  // alignment plan's blurred levels).
  std::vector<Image<float>> frames_;
  std::vector<Image<unsigned char>> frame_masks_;
  // The measures' names (0: the setup's) and, per measure and level, whether its similarities
  // hold the current frames.
  std::vector<std::string> measure_names_;
  std::vector<std::vector<char>> level_prepared_;  // [measure][level]
  std::vector<char> references_made_;              // [level]
  // The last five positive finite values added, and their median (the lower of two middles; 0
  // before the first).
  class RecentMedian {
   public:
    void add(double value);
    double median() const;

   private:
    std::array<double, 5> values_{};
    int count_ = 0, next_ = 0;
  };
  // Per measure and level, what its last five passes that timed a batch after their first measured
  // (OptimizerResult): the time per evaluation of those batches (ms), and its ratio to their first
  // batch's. Their medians are the next such pass's priors (OptimizerBudget), so a pass does not
  // start a batch that would run past the budget before it has timed one of its own, one slow pass
  // does not cut short the next registration, and a time from a slower spell gives way as soon as
  // a pass's first batch runs faster. Kept across frames: the times depend on the level, not on
  // the images.
  struct PassTimes {
    RecentMedian ms_per_evaluation, later_to_first_batch;
  };
  std::vector<std::vector<PassTimes>> pass_times_;  // [measure][level]
  Status prepare_level(int measure, int level);
  // The setup's measure options for a level's view (fewer histogram bins for few pixels).
  SimilarityOptions level_similarity_options(const LevelGeometry& level, std::size_t view) const;
  Status make_reference(int level, int view);  // bins and blurs view's frame for `level`
  std::optional<FiducialTerm> fiducial_;
  bool frames_set_ = false;
};

}  // namespace lftrack::tracking

#pragma once
// `lftrack study trade`: speed against accuracy, measured end to end on one scene.
//
// An operating point is one setting of the knobs users turn (renderer and its storage or pivot,
// light-field resolution and envelope, detector binning, similarity, plan, final step, time
// budget). The points are the scene's baseline and, from it, one knob turned at a time, plus the
// combinations that make sense (a coarse field with coarse binning, a tight budget with a coarse
// final step). Every point registers the same problems: gold poses drawn within 0.4 x the scene's
// envelope, each with its own noisy synthetic frames (Siddon on the scene's anatomy), and a start
// at an initial mean TRE drawn uniformly in [1, 4] mm (a tracking step). A point records the
// registration time (median, p95), TRE (mean, p95, over all problems), success rate (final
// mean TRE < 2 mm, paper 1; a registration that returned an error is never a success), memory (the renderer's data: fields, tree or volume), precompute
// time (building the fields or the tree, in this run), and the DRR fidelity against Siddon at
// the gold poses. Every result is also judged by the registration verdict the loop and `register`
// use, with the scene's limits for the point's measure (scene_verdict_limits) and the check NCC
// against the point's own renderer, as `study capture-range` judges its runs; a point records the
// four outcomes against the truth (verdict_outcomes.hpp; right: final mean TRE under the scene's
// safety.beam_tolerance_mm): accepted and right, false accepts, false rejects, rejected and wrong.
//
// The study is sharded for a cluster's job array: shard k of n runs the points whose index is
// k-1 modulo n (every shard makes the same problems); `lftrack study merge` joins the shards'
// CSVs and writes the plots and the summary. Shards of several scenes (one per patient) are
// merged per scene and pooled over the problems of every scene (pool_trade_studies).
//
// The float light fields the points need (one set per resolution and envelope) are built in the
// run, or, with `field_dir`, loaded from a folder that build_trade_fields filled once: a job
// array's tasks then map the same files read-only and report the precompute time measured when
// the fields were built.

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "lftrack/session/scene.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/studies/verdict_outcomes.hpp"

namespace lftrack::studies {

struct TradePoint {
  std::string id;                       // unique, stable (also the label on plots)
  std::string renderer = "lightfield";  // siddon, trilinear, lightfield, octree
  std::string storage = "float";        // lightfield: float, fixed16, vq
  int vq_codebook = 0;                  // vq only
  std::array<int, 4> lf_resolution{};   // lightfield: (u, v, s, t)
  double envelope_scale = 1;            // lightfield: x the scene's envelope
  double octree_pivot = 0;              // octree only
  int bin = 1;                          // detector binning factor on top of the plan's levels
  std::string similarity = "mi";
  std::string plan = "warm";
  double final_step_mm = 0.1;  // of the plan's last pass
  double budget_ms = 0;        // per registration; 0: none
};

struct TradeOptions {
  bool quick = false;         // fewer points and problems, a coarser baseline field (minutes, not hours)
  int problems = 0;           // 0: 6 quick, 24 full
  int shard = 1, shards = 1;  // run points with index % shards == shard - 1
  std::uint64_t seed = 1;
  std::vector<std::string> only;  // non-empty: just these points (by id), in the study's order
  std::filesystem::path field_dir;  // non-empty: float fields from here (built and saved if missing)
  bool fields_prebuilt = false;     // with field_dir: refuse to build a missing field set
  // What the problems' frames carry (issue 21): ideal (DRRs of the planning CT with noise) or
  // realistic physics, rendered from the simulated patient (4 anatomy draws, shared in turn).
  sim_spec::XrayPhysicsSpec physics;
  std::string physics_name = "ideal";
};

struct TradeResult {
  TradePoint point;
  int runs = 0;
  double median_ms = 0, p95_ms = 0;
  double mean_tre_mm = 0, p95_tre_mm = 0;
  double success_rate = 0;
  double memory_bytes = 0;
  double precompute_s = 0;
  double ncc_vs_siddon = 0;      // mean over problems and views, at the gold poses
  double psnr_db_vs_siddon = 0;  // mean (infinite for an exact renderer)
  // Per problem, in the problems' order (runs.csv): final mean TRE, and the registration time
  // (NaN where the registration failed). Empty for results read from a folder without runs.csv.
  std::vector<double> problem_tre_mm, problem_ms;
  // Registrations that returned an error instead of a pose (a setting the registration refuses,
  // such as a binning beyond its levels): none is a success, their times are in neither median
  // nor p95 (NaN when every one failed), and their TRE is the start's. A point with any is
  // failed: on no front, never recommended, and reported as failed with `failure`.
  int failed_runs = 0;
  std::string failure;  // the first failed registration's reason (empty: not recorded)
  bool failed() const { return failed_runs > 0; }
  // The registration verdict on every problem's result (a failed registration: rejected, reason
  // kNoResult, never right), counted against right = final mean TRE < the study's
  // verdict_tolerance_mm. Per problem, in the problems' order (runs.csv): whether the verdict
  // accepted it and VerdictReason's value (0: accepted). All empty and zero for a point not
  // judged (read from a folder written before the verdict was recorded).
  std::vector<int> problem_accepted, problem_verdict_reason;
  VerdictOutcomes verdict;
  bool judged() const { return verdict.total() > 0; }
};

struct TradeStudy {
  std::string scene;
  std::string fingerprint;  // study_scene_fingerprint of the scene; pooled: empty
  std::uint64_t seed = 1;
  int problems = 0;
  bool quick = false;
  int shard = 1, shards = 1;
  int points_total = 0;  // in the whole study, over every shard
  std::string physics = "ideal";    // the frames' physics (TradeOptions::physics_name)
  std::string physics_description;  // sim_spec::describe of it
  // Right for the verdict's tally: final mean TRE under this (the scene's
  // safety.beam_tolerance_mm). Pooled over scenes of different tolerances: 0, each scene's own.
  double verdict_tolerance_mm = 2.0;
  std::vector<TradeResult> results;
};

// A point's verdict tally from its per-problem rows, right meaning a registration that ran
// (finite time) and ended under `tolerance_mm`; zero when the rows carry no verdict.
VerdictOutcomes tally_trade_verdict(const TradeResult& result, double tolerance_mm);

// The operating points of the study on `scene`, in a stable order.
std::vector<TradePoint> trade_points(const session::PreparedScene& scene, bool quick);

// The problems each point registers: options.problems, or 6 quick and 24 full.
int trade_problem_count(const TradeOptions& options);

// The points shard `options.shard` of `options.shards` runs (after `options.only`), and in
// `points_total` the number in the whole study.
Result<std::vector<TradePoint>> trade_shard_points(const session::PreparedScene& scene,
                                                   const TradeOptions& options, int* points_total = nullptr);

// Builds and saves into `options.field_dir` every float field set the points of the whole study
// (after `options.only`, every shard) need, skipping sets already there and valid. `progress`
// gets a line per set.
Status build_trade_fields(const session::PreparedScene& scene, const TradeOptions& options,
                          tracking::ThreadPool* pool,
                          const std::function<void(const std::string&)>& progress = {});

// Runs this shard's points. `progress` gets the fraction done and the point being run.
Result<TradeStudy> run_trade_study(const session::PreparedScene& scene, const TradeOptions& options,
                                   tracking::ThreadPool* pool,
                                   const std::function<void(double, const std::string&)>& progress = {});

// The Pareto front of mean TRE against median time: points no other point beats on both (ties
// kept), sorted by time. Failed points and points that never succeed are left out, and beat no
// other point.
std::vector<TradeResult> pareto_front(const std::vector<TradeResult>& results);

// The recommended defaults, each the best point under its condition (empty id if none meets it):
// fastest median time within mean TRE 1 mm, most accurate within p95 time 100 ms, least memory
// within mean TRE 0.5 mm; each also needs a success rate of at least 95 % and no failed
// registration.
struct TradeRecommendations {
  TradeResult fastest_within_1mm, most_accurate_within_100ms, least_memory_within_half_mm;
  bool has_fastest = false, has_accurate = false, has_least_memory = false;
};
TradeRecommendations recommend(const std::vector<TradeResult>& results);

// points.csv and study.json (the shard's description) in `dir`.
Status write_trade_shard(const TradeStudy& study, const std::filesystem::path& dir);
// Reads what write_trade_shard wrote.
Result<TradeStudy> read_trade_shard(const std::filesystem::path& dir);
// OK when `dir` holds the complete result of the shard `expected` describes (scene, seed,
// problems, quick, shard k/n, points total) with exactly the points `ids` and every problem's
// row; otherwise why not. A task that finds its shard complete has nothing to do.
Status check_trade_shard_complete(const std::filesystem::path& dir, const TradeStudy& expected,
                                  const std::vector<std::string>& ids);
// Joins shards of one study: refuses shards of another scene, seed or problem count, a shard
// missing or given twice, and a point measured twice.
Result<TradeStudy> merge_trade_shards(const std::vector<TradeStudy>& shards);
// One study over several scenes (patients), each merged: the points every scene has, each with
// the problems of every scene together (times, TREs and success recomputed from runs.csv;
// memory, precompute and fidelity averaged over the scenes). Refuses scenes given twice or
// studies of different seeds, problem counts or sizes, and results without per-problem rows.
// `left_out` (may be null) gets the ids some scene lacks.
Result<TradeStudy> pool_trade_studies(const std::vector<TradeStudy>& scenes,
                                      std::vector<std::string>* left_out = nullptr);
// points.csv, runs.csv, study.json, summary.json, tre_vs_time.png, memory_vs_fidelity.png,
// verdict.png (the verdict's four outcomes per point, 95 % intervals; + their .dat/.gp) and
// summary.md in `dir`.
Status write_trade_outputs(const TradeStudy& study, const std::filesystem::path& dir);

}  // namespace lftrack::studies

#pragma once
// The lftrack program's subcommands. Each registers its options on a CLI11 app and returns a
// callback that runs it; the callbacks report errors as a Status (main prints and exits 1).

#include <CLI/CLI.hpp>
#include <functional>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::chaos {
struct ChaosOptions;
}  // namespace lftrack::chaos
namespace lftrack::studies {
struct TradeStudy;
struct RealismReport;
}  // namespace lftrack::studies

namespace lftrack::cli {

using Command = std::function<Status()>;

// A check of a number's text at parse time: a finite number in [lo, hi] (lo excluded with
// `lo_open`, hi with `hi_open`). NaN, infinities and text that is not a number are refused, which
// CLI11's Range and PositiveNumber let through for NaN. A value out of range is a usage error
// (exit 2), never a refusal found after parsing (exit 1): check numbers here, not in the command.
CLI::Validator finite_in(double lo, double hi, bool lo_open = false, bool hi_open = false);
// Refuses an empty value (`--out ""`), which would otherwise read as "not given".
CLI::Validator not_empty();
// A seed: decimal digits only, 0 to 18446744073709551615 (CLI11 took -1 and 2^64 as the largest
// seed without a word; issue 50 probe).
CLI::Validator seed_value();

// Options every command that needs a scene shares.
struct SceneOptions {
  std::string scene = "builtin:phantom";
  std::string ct;   // overrides the scene's CT
  int threads = 0;  // 0: all cores
};
void add_scene_options(CLI::App* app, SceneOptions* options);
// Loads the scene named in `options` and prepares it (CT read, ROI resolved) on `pool`.
Result<session::PreparedScene> load_prepared_scene(const SceneOptions& options, tracking::ThreadPool* pool);
// "--shard k/n" of a sharded study: (k, n) with 1 <= k <= n.
Result<std::pair<int, int>> parse_shard(const std::string& text);
// "--physics ideal|clinical|scene" of a study: the physics its frames carry and its name. `scene`
// takes the scene's sim.physics; pass null to only check the name (before the scene is read).
struct StudyPhysics {
  sim_spec::XrayPhysicsSpec physics;
  std::string name = "ideal";
};
Result<StudyPhysics> study_physics(const std::string& option, const session::PreparedScene* scene);

// A sharded study's light fields (capture-range and realism): `build` (a job array's field job)
// loads or builds them into `lf_dir` and says so; `prebuilt` (a shard task) refuses to build
// them, naming the field job's command. True when the command's work is done (the field job).
// Renderers other than the light field need no fields: nothing to do.
Result<bool> study_light_fields(const session::PreparedScene& scene, const std::string& study,
                                const std::string& renderer, const std::string& lf_dir, bool build,
                                bool prebuilt, tracking::ThreadPool* pool);

// Loads or builds the scene's light fields into `out_dir` ("": its default folder), saying which
// were built and which were up to date (`lftrack precompute`, `lftrack scene new --precompute`).
Status precompute_light_fields(const session::PreparedScene& scene, const std::string& out_dir,
                               tracking::ThreadPool* pool);
// The simulator's frame fields (<out_dir>/sim-frames) where the scene's frames are simulated from
// light fields; nothing otherwise.
Status precompute_sim_frame_fields(const session::PreparedScene& scene, const std::string& out_dir,
                                   tracking::ThreadPool* pool);

// The tables a study prints when it is whole (its own command, or `study merge`).
void print_trade_front(const studies::TradeStudy& study);
void print_realism_table(const studies::RealismReport& report);

// `lftrack sim --chaos SEED` (cmd_chaos.cpp).
Status run_chaos_command(const SceneOptions& scene, const chaos::ChaosOptions& options, bool json);

Command add_info_command(CLI::App* parent);
Command add_drr_command(CLI::App* parent);
Command add_precompute_command(CLI::App* parent);
Command add_qa_daily_command(CLI::App* parent);  // under `lftrack qa`
Command add_qa_e2e_command(CLI::App* parent);    // under `lftrack qa`
Command add_qa_detector_command(CLI::App* parent);  // under `lftrack qa`
Command add_scene_new_command(CLI::App* parent, int argc, char** argv);
Command add_bench_drr_command(CLI::App* parent);
Command add_register_command(CLI::App* parent);
Command add_bench_register_command(CLI::App* parent);
Command add_bench_octree_command(CLI::App* parent);
Command add_bench_frames_command(CLI::App* parent);
Command add_journal_command(CLI::App* parent);
Command add_study_capture_range_command(CLI::App* parent);
Command add_study_sensitivity_command(CLI::App* parent);
Command add_study_trade_command(CLI::App* parent);
Command add_study_realism_command(CLI::App* parent);
Command add_study_latency_command(CLI::App* parent);
Command add_study_surrogate_command(CLI::App* parent);
Command add_study_merge_command(CLI::App* parent);
Command add_study_submit_command(CLI::App* parent);
Command add_study_status_command(CLI::App* parent);
Command add_sim_command(CLI::App* parent);
Command add_run_command(CLI::App* parent);
Command add_replay_command(CLI::App* parent);
Command add_serve_couch_command(CLI::App* parent);
Command add_serve_robot_command(CLI::App* parent);
Command add_serve_detectors_command(CLI::App* parent);
Command add_serve_tracker_command(CLI::App* parent);
Command add_calibrate_views_command(CLI::App* parent);
Command add_calibrate_couch_command(CLI::App* parent);
Command add_calibrate_detector_command(CLI::App* parent);
Command add_rt_check_command(CLI::App* parent);
// `lftrack commission` records its own command line in the file it writes.
Command add_commission_command(CLI::App* parent, int argc, char** argv);

}  // namespace lftrack::cli

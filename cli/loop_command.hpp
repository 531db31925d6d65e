#pragma once
// `lftrack sim`, `run` and `replay`: one loop command in three modes, built as a library of its
// own (lftrack_cli_loop) that links the session and the QA's report and never the simulator: the
// top-level CMakeLists refuses the configure if it does (issue 55). The simulator reaches it only
// as the RoomSimulator passed to LoopCommand::run. `replay` is made here and runs with none, so a
// simulated device is refused there before any light field is built or record made; the program
// that links this library links lftrack_allocation_counter too (the global operator new whose
// count the summary reports: a program's choice, not a library's). `run` is made here too and runs
// with none: its code path reaches no simulator code. The program (cmd_sim.cpp) makes `sim` (with
// the chaos soak's options) and gives it sim_devices::room_simulator().
//   sim     the simulated closed loop on a scene (the main job; `make demo` runs it on the
//           built-in scene); `sim --room`: the scene's own devices as `run` drives them, its
//           simulated detectors the simulator's (a room of served twins, the QA phantom's room)
//   run     the same loop on the scene's own devices, after the start-up checks; no simulator
//   replay  the same loop on an archived frame sequence (no actuator: track and report)

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "cli_commands.hpp"
#include "lftrack/session/room_simulator.hpp"

namespace lftrack::cli {

enum class LoopMode { kSim, kRun, kReplay };

struct LoopCommandOptions {
  SceneOptions scene;
  std::int64_t cycles = 300;
  bool json = false;
  bool fast = false;
  // The journal: by default a new time-stamped file in journal_folder; `--journal FILE` names it
  // (refused when it exists, unless --overwrite); `--journal ''` writes none.
  std::string journal_folder = "out/sim";
  std::string journal;
  bool journal_named = false;
  bool overwrite = false;
  std::string control;
  std::optional<double> auto_resume_s;
  std::string rt;  // enforce / ignore; empty: the scene's
  std::string lf_dir;
  std::string archive;   // frames archived here
  std::string sequence;  // `lftrack replay`: the archived sequence
  std::string hil;       // `lftrack sim --hil modbus`: actuators through their real drivers
  bool check = false;    // `lftrack run --check`, `sim --room --check`: the start-up checks only
  bool room = false;     // `lftrack sim --room`: the scene's devices, as `run` drives them
  std::string monitor;   // --monitor [ADDRESS:]PORT: the operator's page
  std::vector<std::string> monitor_origins;
  std::string monitor_token_file;
  bool monitor_token_quiet = false;  // the token in its file only, not on standard output
  std::string igtl;                  // --igtl [ADDRESS:]PORT: the OpenIGTLink server
  // `lftrack sim --imaging MODE --xray-hz HZ --period-ms MS`: the scene's tracking.imaging and
  // loop period, overridden (to compare imaging every cycle with a model on one scene).
  std::string imaging;
  std::optional<double> xray_hz, period_ms;
  LoopMode mode = LoopMode::kSim;
};

struct LoopCommand {
  CLI::App* app = nullptr;
  std::shared_ptr<LoopCommandOptions> options;  // as parsed, once the command line is
  // Runs the command with `simulator` making whatever is simulated (null: nothing may be).
  std::function<Status(const session::RoomSimulator* simulator)> run;
};

// Registers `name` under `parent` with the options of `mode`.
LoopCommand add_loop_command(CLI::App* parent, const char* name, const char* description, LoopMode mode);

}  // namespace lftrack::cli

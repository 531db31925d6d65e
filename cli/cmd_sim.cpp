// `lftrack sim` (loop_command.hpp), run with the program's simulator
// (sim_devices::room_simulator()), and the chaos soak (`sim --chaos SEED`, cmd_chaos.cpp) in the
// loop's place when asked. The loop command itself links no simulator; this file gives `sim` one.
// `run` has none (loop_command.cpp).

#include <cstdint>
#include <memory>
#include <optional>

#include "cli_commands.hpp"
#include "lftrack/chaos/chaos_soak.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "loop_command.hpp"

namespace lftrack::cli {

namespace {

struct ChaosCommandOptions {
  std::optional<std::uint64_t> seed;  // `lftrack sim --chaos SEED`: the chaos soak instead of the loop
  chaos::ChaosOptions options;
};

}  // namespace

Command add_sim_command(CLI::App* parent) {
  LoopCommand sim = add_loop_command(
      parent, "sim", "The simulated closed loop: patient motion, synthetic frames, a virtual couch",
      LoopMode::kSim);
  auto c = std::make_shared<ChaosCommandOptions>();
  CLI::Option* chaos =
      sim.app
          ->add_option("--chaos", c->seed,
                       "Chaos soak: faults from the whole catalogue at random moments drawn from SEED, the "
                       "safety invariants checked every cycle, in segments on a simulated clock (--cycles: "
                       "in all, default 20000, 0 until Ctrl-C); exit 1 on any violation. The faults drawn "
                       "follow from SEED; the states they lead to are not bit-for-bit reproducible (the "
                       "Modbus time-outs, CAN heartbeats and injected stalls run on the real clock)")
          ->check(CLI::Validator(
              [](const std::string& text) {
                const bool digits = !text.empty() && text.size() <= 18 &&
                                    text.find_first_not_of("0123456789") == std::string::npos;
                return digits ? std::string()
                              : "'" + text + "' is not a seed (a whole number, 0 to 18 digits)";
              },
              "SEED"));
  sim.app->add_option("--chaos-rate", c->options.fault_rate, "Chaos: the chance of a fault per cycle")
      ->capture_default_str()
      ->check(finite_in(0, 0.5))
      ->needs(chaos);
  sim.app
      ->add_option("--chaos-segment", c->options.segment_cycles,
                   "Chaos: cycles per segment (a fresh loop, journal and patient)")
      ->capture_default_str()
      ->check(CLI::Range(std::int64_t(10), std::int64_t(1000000)))
      ->needs(chaos);
  sim.app
      ->add_option(
          "--chaos-out", c->options.journal_dir,
          "Chaos: the segments' journals go to a new folder DIR/chaos-SEED-N (default DIR out/chaos)")
      ->check(CLI::Validator(
          [](const std::string& t) {
            return t.empty() ? std::string("an empty folder name") : std::string();
          },
          "DIR"))
      ->needs(chaos);
  // The soak makes its own devices, operator and journals.
  for (const char* other : {"--hil", "--archive", "--journal", "--overwrite", "--control", "--auto-resume",
                            "--rt", "--monitor", "--igtl", "--room"})
    chaos->excludes(sim.app->get_option(other));
  CLI::Option* cycles = sim.app->get_option("--cycles");
  return [sim, c, chaos, cycles] {
    if (chaos->count() > 0) {
      const LoopCommandOptions& o = *sim.options;
      c->options.seed = *c->seed;
      c->options.cycles = cycles->count() > 0 ? o.cycles : 20000;
      if (c->options.journal_dir.empty()) c->options.journal_dir = "out/chaos";
      c->options.light_field_dir = o.lf_dir;
      return run_chaos_command(o.scene, c->options, o.json);
    }
    return sim.run(sim_devices::room_simulator());
  };
}

}  // namespace lftrack::cli

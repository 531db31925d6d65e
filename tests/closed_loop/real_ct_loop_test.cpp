// Every shipped real-CT scene in the closed loop (issue 51): the scene file as it ships (the
// clinical presets' frames rendered exactly, below), with its light fields (built once into the
// test cache, where content-keyed names keep scenes apart), on the simulated clock. The patient is set up 3-4 mm and 1 degree off the plan, then drifts and
// breathes; the loop must align, move the couch, and track every cycle, never holding, with the
// true residual small while the beam is on, and allocate nothing in its steady-state cycles.

#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "lftrack/loop/allocation_counter.hpp"
#include "lftrack/records/journal_reader.hpp"
#include "lftrack/records/loop_json.hpp"
#include "lftrack/session/loop_session.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using loop::JournalRecord;
using loop::process_allocation_count;
using loop::TrackingState;

using records::read_journal;
using records::to_json;
namespace {

namespace fs = std::filesystem;

struct RealCtScene {
  const char* file;
  bool thoracic;
  // The largest p95 of the true residual over the cycles with the beam on that the scene tracks
  // within (mm): issue 51 asks 0.5 for ideal frames and 0.8 for the clinical preset.
  double beam_on_p95_mm;
};

void PrintTo(const RealCtScene& s, std::ostream* os) { *os << s.file; }

class RealCtLoop : public ::testing::TestWithParam<RealCtScene> {};

constexpr std::int64_t kCycles = 60;

TEST_P(RealCtLoop, AlignsThenTracksEveryCycleWithTheBeamOnTheTarget) {
  const RealCtScene s = GetParam();
  LFTRACK_REQUIRE_SHARED_DATA(s.thoracic ? test::totalseg_aorta() : test::pancreas_dicom());
  auto scene = load_scene((fs::path(LFTRACK_SOURCE_DIR) / "scenes" / s.file).string());
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->renderer, "lightfield") << "a patient's scene registers with light fields";
  EXPECT_EQ(scene->sim.renderer, "lightfield") << "a patient's scene runs its simulated detectors at 10 Hz";
  // The clinical presets' frames are rendered exactly here (Siddon through the day's water and
  // bone), so what is asserted is the tracker's accuracy, not the frame renderer's: their p95 sits
  // below the 0.8 mm (0.61 and 0.78 mm on Siddon frames with the robust NCC of 2026-11-30;
  // 0.75 and 0.79 before it), and a light field's kernels are chosen per CPU (AVX2, AVX-512), so its
  // frames, and the photon draws that follow from them, need not be the same bit for bit on
  // another host. The light-field frames are held to Siddon's by SimulatedPatient.* and
  // BenchFramesCli.*, and run the loop on the real clock in scripts/real-clock-scenes.sh.
  if (!scene->sim.physics.ideal()) scene->sim.renderer = "siddon";
  tracking::ThreadPool pool(2);
  auto prepared = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(prepared.ok()) << prepared.status().message();
  test::TempDir dir;
  LoopSessionOptions options;
  options.simulator = sim_devices::room_simulator();
  options.cycles = kCycles;
  options.simulated_clock = true;
  options.light_field_dir = test::test_cache_dir() / "real-ct-light-fields";
  options.journal = dir.path() / "run.lfj";
  options.allocation_count = &process_allocation_count;
  auto session = LoopSession::create(*prepared, options, &pool);
  ASSERT_TRUE(session.ok()) << session.status().message();
  auto summary = (*session)->run();
  ASSERT_TRUE(summary.ok()) << summary.status().message();
  SCOPED_TRACE(to_json(*summary).dump());
  EXPECT_TRUE(summary->aligned);
  EXPECT_EQ(summary->states[std::size_t(TrackingState::kTrack)], kCycles) << "every cycle in TRACK";
  EXPECT_EQ(summary->holds, 0);
  EXPECT_EQ(summary->faults, 0);
  // The scene ships commissioned (issue 52): the verdict judges every tracking cycle, the NCC
  // check included, and accepts them (no hold above).
  EXPECT_GE(summary->verdict_checks, kCycles - 3) << "tracking cycles whose frames the verdict checked";
  ASSERT_TRUE(summary->allocations_per_cycle.has_value());
  EXPECT_EQ(*summary->allocations_per_cycle, 0.0) << "steady-state cycles allocate nothing";
  auto journal = read_journal(options.journal);
  ASSERT_TRUE(journal.ok()) << journal.status().message();
  ASSERT_EQ(journal->records.size(), std::size_t(kCycles));
  // The beam comes on once the couch has made the set-up move, and stays on; the true residual
  // while it is on is what the patient receives.
  std::vector<double> beam_on_mm;
  std::int64_t first_beam = -1;
  for (const JournalRecord& r : journal->records) {
    if (r.beam_permit == 0) {
      EXPECT_EQ(first_beam, -1) << "the beam went off again at cycle " << r.cycle;
      continue;
    }
    if (first_beam < 0) first_beam = std::int64_t(r.cycle);
    beam_on_mm.push_back(r.true_residual_mm);
  }
  ASSERT_GE(first_beam, 0) << "the beam never came on";
  EXPECT_LE(first_beam, 10) << "the set-up move took more than a second";
  std::sort(beam_on_mm.begin(), beam_on_mm.end());
  const double p95 = beam_on_mm[std::size_t(0.95 * double(beam_on_mm.size() - 1))];
  EXPECT_LE(p95, s.beam_on_p95_mm) << "true residual with the beam on, p95 (mm)";
  std::printf("%s: beam on from cycle %lld, true residual with the beam on: p95 %.3f mm, max %.3f mm\n", s.file,
              static_cast<long long>(first_beam), p95, beam_on_mm.back());
  // The clinic's figures (tracking_accuracy.hpp): no treating cycle has the target 2 mm away.
  ASSERT_TRUE(summary->target_residual.has_value());
  EXPECT_EQ(summary->target_residual->cycles, kCycles);
  EXPECT_EQ(summary->target_residual->beam_on_cycles, std::int64_t(beam_on_mm.size()));
  EXPECT_EQ(summary->target_residual->beam_on_share_over_2mm, 0.0);
  ASSERT_TRUE(summary->command_latency.has_value());
  std::printf("%s: %s\n%s\n", s.file, to_json(*summary->target_residual).dump().c_str(),
              to_json(*summary->command_latency).dump().c_str());
}

INSTANTIATE_TEST_SUITE_P(ShippedScenes, RealCtLoop,
                         ::testing::Values(RealCtScene{"lumbar-ct.yaml", false, 0.5},
                                           RealCtScene{"lumbar-ct-clinical.yaml", false, 0.8},
                                           RealCtScene{"thoracic-ct.yaml", true, 0.5},
                                           RealCtScene{"thoracic-ct-clinical.yaml", true, 0.8}),
                         [](const ::testing::TestParamInfo<RealCtScene>& param) {
                           return test::scene_test_name(param.param.file);
                         });

}  // namespace
}  // namespace lftrack::session

// `lftrack journal export` as a user runs it: every record of a journal with a torn tail (warned
// of), past damage in the middle (each problem warned of, the exit status says so), and records
// whose codes this build does not know (a newer build's journal, or damage its checksums did not
// catch): each is named "unknown N", never a bare "?", in the CSV and in the JSON lines, and the
// known ones keep their names.

#include <gtest/gtest.h>

#include <string>

#include <nlohmann/json.hpp>

#include "cli_text.hpp"
#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;

using loop::BeamWithheld;
using loop::GateDecision;
using loop::GateReason;
using loop::JournalRecord;
using loop::JournalWriter;
using loop::OperatorCommand;
using loop::OperatorRefusal;
namespace {

using test::lftrack_bin;

TEST(JournalExport, CodesThisBuildDoesNotKnowAreNamedByNumber) {
  test::TempDir dir;
  const auto file = dir.path() / "codes.journal";
  {
    auto w = JournalWriter::open(file);
    ASSERT_TRUE(w.ok()) << w.status().message();
    JournalRecord known;
    known.cycle = 0;
    known.state = 2;  // TRACK
    known.gate_decision = std::uint8_t(GateDecision::kHold);
    known.gate_reason = std::uint8_t(GateReason::kNotInPlace);
    (*w)->append(known);
    JournalRecord unknown;
    unknown.cycle = 1;
    unknown.state = 200;
    unknown.previous_state = 201;
    unknown.gate_decision = 202;
    unknown.gate_reason = 203;
    unknown.event = 204;
    unknown.operator_command = 205;
    unknown.operator_refusal = 206;
    unknown.beam_withheld = 207;
    (*w)->append(unknown);
    ASSERT_TRUE((*w)->close().ok());
  }
  std::string csv, json;
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", file.string(), "--csv"}, &csv).ok())
      << csv;
  EXPECT_NE(csv.find("\n0,0,0,0,TRACK,IDLE,HOLD,\"patient not in place: the beam withheld too long\""),
            std::string::npos)
      << csv;
  EXPECT_NE(csv.find("\n1,0,0,0,unknown 200,unknown 201,unknown 202,\"unknown 203\""), std::string::npos) << csv;
  for (const char* name : {"\"unknown 204\"", "\"unknown 205\"", "\"unknown 206\"", "\"unknown 207\""})
    EXPECT_NE(csv.find(name), std::string::npos) << name << "\n" << csv;
  EXPECT_EQ(csv.find("?"), std::string::npos) << csv;
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", file.string()}, &json).ok()) << json;
  for (const char* pair : {"\"state\":\"unknown 200\"", "\"previous_state\":\"unknown 201\"", "\"gate\":\"unknown 202\"",
                           "\"reason\":\"unknown 203\"", "\"event\":\"unknown 204\"",
                           "\"operator_command\":\"unknown 205\"", "\"operator_refusal\":\"unknown 206\"",
                           "\"beam_withheld\":\"unknown 207\"", "\"reason\":\"patient not in place"})
    EXPECT_NE(json.find(pair), std::string::npos) << pair << "\n" << json;
  EXPECT_EQ(json.find("?"), std::string::npos) << json;
}

// Every refusal of a cycle by reason, with the first and the last; poses in mm and degrees with the
// unit in every key and column (an outside probe found degrees in `register --json` and radians in
// the journal's JSON, with no unit named).
TEST(JournalExport, RefusalsByReasonAndPosesWithTheirUnits) {
  test::TempDir dir;
  const auto file = dir.path() / "refusals.journal";
  {
    auto w = JournalWriter::open(file);
    ASSERT_TRUE(w.ok()) << w.status().message();
    JournalRecord r;
    r.cycle = 0;
    r.state = 3;  // HOLD
    r.pose_delta[0] = 1.5;
    r.pose_delta[5] = 0.5 * 3.14159265358979323846 / 180;  // 0.5 degrees
    r.command[2] = -2.0;
    r.command[3] = 3.14159265358979323846 / 180;  // 1 degree
    r.operator_refused = 17;
    r.operator_first_refusal = std::uint8_t(OperatorRefusal::kBadToken);
    r.operator_refusal = std::uint8_t(OperatorRefusal::kReplayed);
    r.operator_refused_by_reason[std::size_t(OperatorRefusal::kBadToken)] = 15;
    r.operator_refused_by_reason[std::size_t(OperatorRefusal::kReplayed)] = 2;
    (*w)->append(r);
    ASSERT_TRUE((*w)->close().ok());
  }
  std::string csv, json;
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", file.string(), "--csv"}, &csv).ok()) << csv;
  EXPECT_NE(csv.find("tx_mm,ty_mm,tz_mm,rx_deg,ry_deg,rz_deg,"), std::string::npos) << csv;
  EXPECT_NE(csv.find(",imaging,surrogate_fault,surrogate_time_ns,"), std::string::npos)
      << "format 6's columns\n"
      << csv;
  EXPECT_NE(csv.find(",1.5,0,0,0,0,0.5,"), std::string::npos) << "the pose in mm and degrees\n" << csv;
  EXPECT_NE(csv.find(",0,0,-2,1,0,0,"), std::string::npos) << "the command in mm and degrees\n" << csv;
  EXPECT_NE(
      csv.find(",\"no operator token, or a wrong one\",\"15 no operator token, or a wrong one; 2 replayed or "
               "stale request\",0,0,0,0,0,0,0,0,0,0,0,0,0,0,\"\",\"ok\",0,"),
      std::string::npos)
      << csv;
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", file.string()}, &json).ok()) << json;
  const auto j = nlohmann::json::parse(json);
  EXPECT_NEAR(j["pose_delta"]["translation_mm"][0].get<double>(), 1.5, 1e-12);
  EXPECT_NEAR(j["pose_delta"]["rotation_deg"][2].get<double>(), 0.5, 1e-9);
  EXPECT_NEAR(j["command"]["rotation_deg"][0].get<double>(), 1.0, 1e-9);
  EXPECT_EQ(j["operator_refused"], 17);
  EXPECT_EQ(j["operator_first_refusal"], "no operator token, or a wrong one");
  EXPECT_EQ(j["operator_refusal"], "replayed or stale request");
  EXPECT_EQ(j["operator_refusals"]["no operator token, or a wrong one"], 15);
  EXPECT_EQ(j["operator_refusals"]["replayed or stale request"], 2);
}

TEST(Cli, JournalExportPrintsEveryRecordAndWarnsOfATornTail) {
  test::TempDir dir;
  const auto file = dir.path() / "cycles.journal";
  {
    auto w = JournalWriter::open(file);
    ASSERT_TRUE(w.ok());
    for (std::uint64_t i = 0; i < 5; ++i) {
      JournalRecord r;
      r.cycle = i;
      r.state = 2;
      (*w)->append(r);
    }
  }
  std::filesystem::resize_file(file, std::filesystem::file_size(file) - 3);
  std::string csv, json;
  ASSERT_TRUE(run_process({lftrack_bin(), "journal", "export", file.string(), "--csv"}, &csv).ok()) << csv;
  EXPECT_NE(csv.find("torn tail"), std::string::npos) << csv;
  EXPECT_NE(csv.find("\n3,0,0,0,TRACK,IDLE,APPLY"), std::string::npos) << csv;
  EXPECT_EQ(csv.find("\n4,"), std::string::npos) << "the torn record is not printed";
  ASSERT_TRUE(run_process({lftrack_bin(), "-q", "journal", "export", file.string()}, &json).ok()) << json;
  int objects = 0;
  for (std::size_t pos = json.find("{\"beam_permit\""); pos != std::string::npos;
       pos = json.find("{\"beam_permit\"", pos + 1))
    ++objects;
  EXPECT_EQ(objects, 4) << json;
  EXPECT_FALSE(run_process({lftrack_bin(), "journal", "export", (dir.path() / "none").string()}, &json).ok());
}

// A flipped bit in the middle: every other record is exported, each problem is warned about, and
// the exit status says the journal is damaged.
TEST(Cli, JournalExportRecoversPastDamageWarnsOfEachProblemAndFails) {
  test::TempDir dir;
  const auto file = dir.path() / "cycles.journal";
  {
    auto w = JournalWriter::open(file);
    ASSERT_TRUE(w.ok());
    for (std::uint64_t i = 0; i < 20; ++i) {
      JournalRecord r;
      r.cycle = i;
      r.state = 2;
      r.hold_id = i == 7 ? 3 : 0;
      r.operator_command = i == 7 ? 1 + static_cast<std::uint8_t>(OperatorCommand::kResume) : 0;
      r.beam_withheld = i == 7 ? static_cast<std::uint8_t>(BeamWithheld::kApprovedStep) : 0;
      (*w)->append(r);
    }
  }
  const std::size_t frame = 8 + sizeof(JournalRecord) + 4;
  const std::size_t damaged_at = 32 + 10 * frame;
  {
    std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(static_cast<std::streamoff>(damaged_at + 30));
    f.put('\x5a');
  }
  std::string csv;
  EXPECT_FALSE(run_process({lftrack_bin(), "journal", "export", file.string(), "--csv"}, &csv).ok())
      << "damage is an error, for scripts";
  EXPECT_NE(
      csv.find(
          ",hold_id,operator_command,operator_refused,operator_refusal,beam_withheld,"
          "operator_first_refusal,operator_refusals,target_tx_mm,target_ty_mm,target_tz_mm,target_rx_deg,"
          "target_ry_deg,target_rz_deg,command_acked_ns,frame_time_a_ns,frame_time_b_ns,frames_arrived_ns,"
          "preprocessed_ns,registered_ns,gated_ns,command_written_ns,imaging,"),
      std::string::npos)
      << csv;
  EXPECT_NE(csv.find(",3,\"resume\",0,\"\",\"approved step beyond the step "
                     "limit\",\"\",\"\",0,0,0,0,0,0,0,0,0,0,0,0,0,0,\""),
            std::string::npos)
      << csv;
  EXPECT_NE(csv.find(",0,\"\",0,\"\",\"\",\"\",\"\",0,0,0,0,0,0,0,0,0,0,0,0,0,0,\""), std::string::npos)
      << "no beam withheld: an empty field" << csv;
  for (int i = 0; i < 20; ++i) {
    const std::string row = std::string("\n") + std::to_string(i) + ",0,0,0,TRACK";
    EXPECT_EQ(csv.find(row) == std::string::npos, i == 10) << i << csv;
  }
  const std::string frame_bytes = std::to_string(frame);
  const std::string span = std::string("bad span at byte ") + std::to_string(damaged_at) + ", " +
                           frame_bytes + " bytes: checksum mismatch";
  EXPECT_NE(csv.find(span), std::string::npos) << csv;
  EXPECT_NE(csv.find("gap: cycle 11 (record 10) follows cycle 9, 1 cycles missing"), std::string::npos)
      << csv;
  const std::string summary = std::string("journal damaged: 1 bad spans (") + frame_bytes +
                              " bytes), 1 gaps (1 cycles missing), 0 repeated cycles; 19 records recovered";
  EXPECT_NE(csv.find(summary), std::string::npos) << csv;
}

}  // namespace
}  // namespace lftrack::session

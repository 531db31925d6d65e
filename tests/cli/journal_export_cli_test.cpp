// `lftrack journal export` on records whose codes this build does not know (a newer build's
// journal, or damage its checksums did not catch): each is named "unknown N", never a bare "?",
// in the CSV and in the JSON lines, and the known ones keep their names.

#include <gtest/gtest.h>

#include <string>

#include <nlohmann/json.hpp>

#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;

using loop::GateDecision;
using loop::GateReason;
using loop::JournalRecord;
using loop::JournalWriter;
using loop::OperatorRefusal;
namespace {

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

}  // namespace
}  // namespace lftrack::session

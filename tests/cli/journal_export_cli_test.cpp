// `lftrack journal export` on records whose codes this build does not know (a newer build's
// journal, or damage its checksums did not catch): each is named "unknown N", never a bare "?",
// in the CSV and in the JSON lines, and the known ones keep their names.

#include <gtest/gtest.h>

#include <string>

#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "test_data.hpp"

namespace lftrack::host {
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

}  // namespace
}  // namespace lftrack::host

#pragma once
// What a daily QA, an end-to-end test or a detector check found (issue 59): the report that
// run_daily_qa and its kin (daily_qa.hpp) make and qa_report.hpp writes and finds again. Data
// only: a program that reads the reports (`lftrack run` looks for today's) links none of the
// runs that make them.

#include <Eigen/Core>
#include <string>
#include <vector>

#include "lftrack/tracking/pose.hpp"

namespace lftrack::qa {

struct OffsetResult {
  tracking::Vector6d shift = tracking::Vector6d::Zero();        // known (mm, rad)
  tracking::Vector6d registered = tracking::Vector6d::Zero();   // the alignment's result
  tracking::Vector6d couch_moved = tracking::Vector6d::Zero();  // the read-back's change, as a shift
  double registration_error_mm = 0, registration_error_deg = 0;
  double couch_error_mm = 0, couch_error_deg = 0;
  double final_offset_mm = 0;  // the last registration's translation (the phantom back in place)
  bool aligned = false;
  bool passed = false;
  std::string why;  // the first tolerance missed, or what stopped the run
};

struct QaCheck {
  std::string name;  // offset, beam, latency
  bool passed = false;
  std::string tolerance;  // what it is judged against, in words with units
  std::string measured;   // what it found
  std::string why;        // failed: the reason; passed: empty
};

struct DailyQaReport {
  std::string kind = "daily";  // "daily" (run_daily_qa), "e2e" (run_end_to_end_qa), "detector"
  std::string scene_name, scene_source;
  std::string room_fingerprint;  // session::room_fingerprint, hex: whose room this QA was of
  std::string started_utc;       // ISO 8601
  std::string started_local;     // ISO 8601 with the host's UTC offset
  std::string date;              // YYYY-MM-DD, the host's local date: the clinic's day it counts for
  double tolerance_mm = 0, tolerance_deg = 0;
  // The standard QA: the default shifts, at least half of TG-135's 10 mm and 1 degree (a small
  // envelope scales them down), tolerances no looser than the defaults (0.5 mm, 0.2 degree, the
  // detector check's), the latency chain run (at least 50 cycles) within the scene's period. Only
  // a standard daily QA that passed counts for `lftrack run`.
  bool standard = false;
  bool interrupted = false;  // ended early by the operator (DailyQaOptions::interrupted): never standard
  std::vector<OffsetResult> offsets;
  std::vector<QaCheck> checks;
  // What a daily QA asks for and this one does not check: said in the report, never counted as
  // passed.
  std::vector<std::string> not_checked;
  // e2e: where the hidden marker is (from the registration origin, room frame) and its error in
  // each beam-on cycle (mm), for the report's picture.
  Eigen::Vector3d marker_offset_room_mm = Eigen::Vector3d::Zero();
  std::vector<double> marker_error_mm;
  bool passed() const;
};

}  // namespace lftrack::qa

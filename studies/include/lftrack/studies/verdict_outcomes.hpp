#pragma once
// The registration verdict against the truth, as the studies count it (capture range, realism,
// trade, sensitivity): every result judged by the verdict the loop and `register` use
// (registration_verdict.hpp, with the scene's limits for the result's measure), accepted or
// rejected, against whether it was right (its final mean TRE under the study's tolerance). A
// registration that returned an error is rejected (VerdictReason::kNoResult) and never right.

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "lftrack/studies/plot.hpp"

namespace lftrack::studies {

struct VerdictOutcomes {
  int accepted_right = 0;  // accepted and right
  int accepted_wrong = 0;  // accepted but wrong: false accepts
  int rejected_right = 0;  // rejected but right: false rejects
  int rejected_wrong = 0;  // rejected and wrong
  void add(bool accepted, bool right) {
    (accepted ? (right ? accepted_right : accepted_wrong) : (right ? rejected_right : rejected_wrong))++;
  }
  int total() const { return accepted_right + accepted_wrong + rejected_right + rejected_wrong; }
  VerdictOutcomes& operator+=(const VerdictOutcomes& o) {
    accepted_right += o.accepted_right;
    accepted_wrong += o.accepted_wrong;
    rejected_right += o.rejected_right;
    rejected_wrong += o.rejected_wrong;
    return *this;
  }
  bool operator==(const VerdictOutcomes&) const = default;
};

// The counts as summary.json gives them: {"accepted_right", "false_accepts", "false_rejects",
// "rejected_wrong"}.
nlohmann::json verdict_outcomes_json(const VerdictOutcomes& outcomes);

// One group of the verdict chart: a method, an operating point, a factor.
struct VerdictGroup {
  std::string name;
  VerdictOutcomes outcomes;
};

// The four outcomes per group as grouped bars: each outcome's share of the group's results in
// per cent (an axis of rates alone, 0-105 %) with its 95 % Wilson interval, the group's count n
// in its name. Draw it with draw_grouped_bars.
GroupedBarChart verdict_outcome_chart(const std::string& title, const std::vector<VerdictGroup>& groups);

}  // namespace lftrack::studies

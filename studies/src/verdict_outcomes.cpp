#include "lftrack/studies/verdict_outcomes.hpp"

#include <iterator>

namespace lftrack::studies {

nlohmann::json verdict_outcomes_json(const VerdictOutcomes& v) {
  return {{"accepted_right", v.accepted_right},
          {"false_accepts", v.accepted_wrong},
          {"false_rejects", v.rejected_right},
          {"rejected_wrong", v.rejected_wrong}};
}

GroupedBarChart verdict_outcome_chart(const std::string& title, const std::vector<VerdictGroup>& groups) {
  GroupedBarChart chart;
  chart.title = title;
  chart.y_label = "runs (%)";
  chart.y_min = 0;
  chart.y_max = 105;
  BarSeries outcomes[4] = {{"accepted, right", {}, {}, {}},
                           {"accepted, wrong (false accept)", {}, {}, {}},
                           {"rejected, right (false reject)", {}, {}, {}},
                           {"rejected, wrong", {}, {}, {}}};
  for (const VerdictGroup& g : groups) {
    const VerdictOutcomes& o = g.outcomes;
    const int counts[4] = {o.accepted_right, o.accepted_wrong, o.rejected_right, o.rejected_wrong};
    const int n = o.total();
    chart.categories.push_back(g.name + " (n=" + std::to_string(n) + ")");
    for (int k = 0; k < 4; ++k) {
      const auto [lo, hi] = wilson_interval(counts[k], n);
      outcomes[k].value.push_back(n ? 100.0 * counts[k] / n : 0);
      outcomes[k].low.push_back(100 * lo);
      outcomes[k].high.push_back(100 * hi);
    }
  }
  chart.series.assign(std::begin(outcomes), std::end(outcomes));
  return chart;
}

}  // namespace lftrack::studies

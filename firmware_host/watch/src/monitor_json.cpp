#include "monitor_json.hpp"

#include <openssl/evp.h>

#include "lftrack/loop/latency_chain.hpp"
#include "lftrack/loop/loop_summary.hpp"
#include "lftrack/loop/operator_input.hpp"
#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/records/loop_json.hpp"

namespace lftrack::watch {

using loop::BeamWithheld;
using loop::GateDecision;
using loop::GateReason;
using loop::JournalRecord;
using loop::key_of;
using loop::kLatencyLinks;
using loop::latency_links_ms;
using loop::LatencyLink;
using loop::OperatorRefusal;
using loop::refusals_text;
using loop::total_ms;
using loop::TrackingState;

using records::pose_delta_json;
namespace {

std::string base64(const std::vector<std::uint8_t>& bytes) {
  std::string out(4 * ((bytes.size() + 2) / 3) + 1, '\0');
  const int n = EVP_EncodeBlock(reinterpret_cast<unsigned char*>(out.data()), bytes.data(), static_cast<int>(bytes.size()));
  out.resize(std::size_t(std::max(0, n)));
  return out;
}

nlohmann::json grey_json(const GreyImage& image) {
  return {{"rows", image.rows}, {"cols", image.cols}, {"pixels", base64(image.pixels)}};
}

// The gate's line as a person reads it: in HOLD or FAULT the gate still judges each registration,
// but an APPLY there moves nothing (only an operator's resume or reset leaves the state), so it is
// not shown as one.
nlohmann::json gate_json(const JournalRecord& r) {
  const auto state = static_cast<TrackingState>(r.state);
  const auto decision = static_cast<GateDecision>(r.gate_decision);
  const bool stopped = state == TrackingState::kHold || state == TrackingState::kFault;
  std::string shown = to_string(decision), why = to_string(static_cast<GateReason>(r.gate_reason));
  if (stopped && decision == GateDecision::kApply) {
    shown = std::string("none (") + to_string(state) + ")";
    why = std::string("nothing is sent in ") + to_string(state) + "; the registration would pass";
  }
  return {{"decision", to_string(decision)},
          {"reason", to_string(static_cast<GateReason>(r.gate_reason))},
          {"applied", decision == GateDecision::kApply && (state == TrackingState::kTrack || state == TrackingState::kAlign)},
          {"shown", shown},
          {"shown_reason", why}};
}

// Why the loop is in its state: the reason of the transition into it ("" before any).
std::string state_reason(const HubStatus& s) {
  const auto state = static_cast<TrackingState>(s.last.record.state);
  for (auto t = s.transitions.rbegin(); t != s.transitions.rend(); ++t)
    if (t->to == state) return t->reason;
  return "";
}

// The last cycle's command, link by link from the exposure to the acknowledgement (ms), with the
// total; null where the cycle sent none, or has no chain (the simulated clock).
nlohmann::json latency_chain_json(const JournalRecord& r) {
  const auto links = latency_links_ms(r);
  if (!links) return nullptr;
  nlohmann::json j;
  for (int i = 0; i < kLatencyLinks; ++i) j[key_of(static_cast<LatencyLink>(i))] = (*links)[std::size_t(i)];
  j["total"] = total_ms(*links);
  return j;
}

}  // namespace

nlohmann::json state_json(const HubStatus& s, const HubOptions& options) {
  const JournalRecord& r = s.last.record;
  nlohmann::json views = nlohmann::json::array();
  for (const auto& v : options.views) views.push_back(v.name);
  nlohmann::json j = {{"scene", options.scene}, {"period_ms", options.period_ms}, {"views", views},
                      {"started", s.started}, {"seq", s.seq}, {"images_seq", s.images_seq}};
  if (!s.started) return j;
  nlohmann::json transitions = nlohmann::json::array();
  for (const HubTransition& t : s.transitions)
    transitions.push_back({{"cycle", t.cycle}, {"from", to_string(t.from)}, {"to", to_string(t.to)},
                           {"reason", t.reason}, {"hold_id", t.hold_id}});
  nlohmann::json similarity = nlohmann::json::array();
  for (std::size_t v = 0; v < options.views.size(); ++v) similarity.push_back(r.similarity[v]);
  j.update({{"cycle", r.cycle},
            {"state", to_string(static_cast<TrackingState>(r.state))},
            {"hold_id", r.hold_id},
            {"state_reason", state_reason(s)},
            {"beam_permit", r.beam_permit != 0},
            {"beam_withheld", to_string(static_cast<BeamWithheld>(r.beam_withheld))},
            {"gate", gate_json(r)},
            {"registered", s.last.registered},
            {"offset", pose_delta_json(r.pose_delta)},
            {"command_sent", r.command_sent != 0},
            {"correction", pose_delta_json(r.command)},
            {"similarity", similarity},
            {"registration_ms", r.registration_ms},
            {"latency_chain_ms", latency_chain_json(r)},
            {"true_residual_mm", r.true_residual_mm},
            {"operator",
             {{"refused", r.operator_refused},
              {"first_refusal", to_string(static_cast<OperatorRefusal>(r.operator_first_refusal))},
              {"last_refusal", to_string(static_cast<OperatorRefusal>(r.operator_refusal))},
              {"refusals", refusals_text(r.operator_refused_by_reason)}}},
            {"counts",
             {{"cycles", s.counts.cycles},
              {"holds", s.counts.holds},
              {"faults", s.counts.faults},
              {"overruns", s.counts.overruns},
              {"skipped_periods", s.counts.skipped_periods},
              {"commands", s.counts.commands},
              {"operator_refused", s.counts.operator_refused},
              {"records_dropped", s.counts.records_dropped}}},
            {"transitions", transitions}});
  return j;
}

nlohmann::json trace_json(const std::vector<TracePoint>& points) {
  nlohmann::json rows = nlohmann::json::array();
  for (const TracePoint& p : points)
    rows.push_back({p.cycle, p.registered ? 1 : 0, p.offset[0], p.offset[1], p.offset[2], p.offset[3], p.offset[4],
                    p.offset[5], p.true_residual_mm, p.similarity[0], p.similarity[1], p.registration_ms, p.state,
                    p.command_sent ? 1 : 0});
  return rows;
}

nlohmann::json images_json(const DisplayImages& images) {
  nlohmann::json views = nlohmann::json::array();
  for (const DisplayView& v : images.views)
    views.push_back({{"name", v.name},
                     {"bin", v.bin},
                     {"roi", grey_json(v.roi)},
                     {"drr", grey_json(v.drr)},
                     {"thumbnail", grey_json(v.thumbnail)},
                     {"roi_in_thumbnail", v.roi_in_thumbnail}});
  return {{"seq", images.seq}, {"cycle", images.cycle}, {"registered", images.registered},
          {"render_ms", images.render_ms}, {"views", views}};
}

}  // namespace lftrack::watch

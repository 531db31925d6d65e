#include "lftrack/loop/latency_chain.hpp"

#include <algorithm>

namespace lftrack::loop {

namespace {
// Each link's name (tables, plots) and key (JSON, CSV), in LatencyLink's order.
struct LinkNames {
  const char* name;
  const char* key;
};
constexpr LinkNames kLinkNames[kLatencyLinks] = {{"exposure to arrival", "arrive"},
                                                 {"preprocess", "preprocess"},
                                                 {"register", "register"},
                                                 {"gate", "gate"},
                                                 {"write", "write"},
                                                 {"acknowledge", "acknowledge"}};
bool known(LatencyLink link) {
  return static_cast<int>(link) >= 0 && static_cast<int>(link) < kLatencyLinks;
}
}  // namespace

const char* to_string(LatencyLink link) {
  return known(link) ? kLinkNames[static_cast<int>(link)].name : "?";
}

const char* key_of(LatencyLink link) {
  return known(link) ? kLinkNames[static_cast<int>(link)].key : "?";
}

double total_ms(const std::array<double, kLatencyLinks>& links_ms) {
  double total = 0;
  for (double v : links_ms) total += v;
  return total;
}

const char* to_string(NoChain why) {
  switch (why) {
    case NoChain::kNoCommand:
      return "no command sent";
    case NoChain::kNotTimed:
      return "a link not timed (the simulated clock, a journal before format 5, or a link not reached)";
    case NoChain::kOutOfOrder:
      return "a link runs backwards (damage: one monotonic clock never does)";
    case NoChain::kImplausible:
      return "a link over a minute (damage)";
  }
  return "?";
}

std::int64_t exposure_ns(const JournalRecord& r) {
  const std::int64_t a = r.frame_time_ns[0], b = r.frame_time_ns[1];
  if (a <= 0 || b <= 0) return std::max<std::int64_t>(std::max(a, b), 0);  // one detector (or none)
  return std::min(a, b);
}

std::optional<std::array<double, kLatencyLinks>> latency_links_ms(const JournalRecord& r, NoChain* why) {
  auto none = [&](NoChain reason) -> std::optional<std::array<double, kLatencyLinks>> {
    if (why != nullptr) *why = reason;
    return std::nullopt;
  };
  if (r.command_sent == 0) return none(NoChain::kNoCommand);
  const std::int64_t exposed = exposure_ns(r);
  const std::int64_t times[kLatencyLinks + 1] = {exposed,           r.frames_arrived_ns, r.preprocessed_ns,
                                                 r.registered_ns,   r.gated_ns,          r.command_written_ns,
                                                 r.command_acked_ns};
  for (std::int64_t t : times)
    if (t <= 0) return none(NoChain::kNotTimed);
  std::array<double, kLatencyLinks> links{};
  for (int i = 0; i < kLatencyLinks; ++i) {
    if (times[i + 1] < times[i]) return none(NoChain::kOutOfOrder);
    // A difference of two positive int64 values cannot overflow.
    links[std::size_t(i)] = 1e-6 * double(times[i + 1] - times[i]);
    if (links[std::size_t(i)] > kMaxLinkMs) return none(NoChain::kImplausible);
  }
  return links;
}

void LatencyChain::add(const JournalRecord& r) {
  const auto links = latency_links_ms(r);
  if (!links) return;
  for (std::size_t i = 0; i < links->size(); ++i) links_[i].add((*links)[i]);
  total_.add(total_ms(*links));
}

namespace {
LinkLatency of(const Histogram& h) {
  return {h.quantile(0.50), h.quantile(0.95), h.quantile(0.99), h.max()};
}
}  // namespace

std::optional<LatencyChainReport> LatencyChain::report() const {
  if (total_.count() == 0) return std::nullopt;
  LatencyChainReport out;
  out.commands = static_cast<std::int64_t>(total_.count());
  for (std::size_t i = 0; i < links_.size(); ++i) out.links[i] = of(links_[i]);
  out.total = of(total_);
  return out;
}

}  // namespace lftrack::loop

#include "lftrack/watch/page_operator.hpp"

#include <algorithm>

namespace lftrack::watch {

using loop::judge_operator_request;
using loop::OperatorCommand;
using loop::OperatorPoll;
using loop::OperatorRefusal;
using loop::OperatorRequest;
using loop::OperatorView;

int PageOperator::refusal_index(OperatorRefusal why) {
  switch (why) {
    case OperatorRefusal::kBadToken:
      return 0;
    case OperatorRefusal::kReplayed:
      return 1;
    case OperatorRefusal::kOrigin:
      return 2;
    default:
      return 3;  // kMalformed and anything else the page refused
  }
}

void PageOperator::refused_before_loop(OperatorRefusal why) {
  refused_[std::size_t(refusal_index(why))].fetch_add(1, std::memory_order_relaxed);
}

PageOperator::Verdict PageOperator::submit(const OperatorRequest& request, std::chrono::milliseconds wait) {
  std::unique_lock<std::mutex> lock(mutex_);
  Slot* slot = nullptr;
  for (Slot& s : slots_)
    if (s.state == SlotState::kFree) {
      slot = &s;
      break;
    }
  if (slot == nullptr) return {Verdict::Outcome::kBusy, OperatorRefusal::kNone};
  slot->state = SlotState::kWaiting;
  slot->request = request;
  slot->epoch = hold_epoch_.load(std::memory_order_acquire);
  slot->verdict = {};
  decided_.wait_for(lock, wait, [&] { return slot->state == SlotState::kDecided; });
  const Verdict verdict = slot->state == SlotState::kDecided ? slot->verdict : Verdict{};
  slot->state = SlotState::kFree;  // decided or withdrawn: it never acts later
  return verdict;
}

int PageOperator::waiting() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<int>(std::count_if(slots_.begin(), slots_.end(),
                                        [](const Slot& s) { return s.state == SlotState::kWaiting; }));
}

void PageOperator::poll(const OperatorView& view, OperatorPoll* out) {
  static const OperatorRefusal kinds[kRefusalKinds] = {OperatorRefusal::kBadToken, OperatorRefusal::kReplayed,
                                                      OperatorRefusal::kOrigin, OperatorRefusal::kMalformed};
  for (int k = 0; k < kRefusalKinds; ++k)
    out->refuse(kinds[k], refused_[std::size_t(k)].exchange(0, std::memory_order_relaxed));
  std::unique_lock<std::mutex> lock(mutex_, std::try_to_lock);
  if (!lock.owns_lock()) return;  // a server thread is queueing: next cycle
  const std::uint64_t epoch = hold_epoch_.load(std::memory_order_acquire);
  bool any = false;
  for (Slot& s : slots_) {
    if (s.state != SlotState::kWaiting) continue;
    const bool before_hold = s.epoch != epoch &&
                             (s.request.command == OperatorCommand::kResume || s.request.command == OperatorCommand::kReset);
    const OperatorRefusal why = before_hold ? OperatorRefusal::kBeforeHold
                                            : judge_operator_request(s.request, view, /*id_required=*/true);
    if (why == OperatorRefusal::kNone) {
      out->accept(s.request.command);
      s.verdict = {Verdict::Outcome::kAccepted, OperatorRefusal::kNone};
    } else {
      out->refuse(why);
      s.verdict = {Verdict::Outcome::kRefused, why};
    }
    s.state = SlotState::kDecided;
    any = true;
  }
  lock.unlock();
  if (any) decided_.notify_all();
}

void PageOperator::on_hold(const OperatorView& view, OperatorPoll* out) {
  (void)view;
  (void)out;
  // Every resume or reset queued until now answers no HOLD the operator saw: poll() discards it
  // (kBeforeHold) by its epoch. A stop waiting in a slot stays and is accepted at the next poll.
  hold_epoch_.fetch_add(1, std::memory_order_acq_rel);
}

}  // namespace lftrack::watch

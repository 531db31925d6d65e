#pragma once
// The monitor page's operator actions as an OperatorInput (operator_input.hpp): the HTTP server's
// threads submit requests, the loop judges them at its next poll exactly as it judges the control
// socket's (a resume or reset must name the HOLD or FAULT it answers, counts only once that HOLD
// has been shown for kMinHoldBeforeResumeS, and one sent before the loop entered its HOLD is
// discarded), and each submitter waits, with a deadline, for the verdict to answer its request.
//
// Requests the page's own checks refused (no token or a wrong one, a replayed nonce, another
// origin; monitor_server.hpp) never reach a slot: they are counted by kind and journaled at the
// next poll as refusals, so a flood of them costs the loop one counter read per kind.
//
// The loop's side never blocks: poll() and on_hold() take the slots' mutex with try_lock (the
// server's threads hold it for microseconds); when it is busy, the requests wait for the next
// cycle. A request submitted before an entry into HOLD or FAULT is told apart by the hold epoch
// on_hold() advances (an atomic), so it is discarded even when on_hold() could not take the lock.

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <mutex>

#include "lftrack/loop/operator_input.hpp"

namespace lftrack::watch {

class PageOperator final : public loop::OperatorInput {
 public:
  static constexpr int kSlots = 16;

  struct Verdict {
    enum class Outcome { kAccepted, kRefused, kBusy, kNoAnswer } outcome = Outcome::kNoAnswer;
    loop::OperatorRefusal refusal = loop::OperatorRefusal::kNone;  // when refused
  };

  // The server's threads. Queues `request` for the loop and waits up to `wait` for its verdict;
  // kBusy when kSlots requests are already waiting, kNoAnswer when the loop did not poll in time
  // (the request is then withdrawn: it never acts later).
  Verdict submit(const loop::OperatorRequest& request, std::chrono::milliseconds wait);
  // A request the page's checks refused (kBadToken, kReplayed, kOrigin, kMalformed): journaled at
  // the next poll.
  void refused_before_loop(loop::OperatorRefusal why);
  // Any thread: requests queued and not yet decided by the loop.
  int waiting() const;

  // The loop's thread.
  void poll(const loop::OperatorView& view, loop::OperatorPoll* out) override;
  void on_hold(const loop::OperatorView& view, loop::OperatorPoll* out) override;

 private:
  enum class SlotState : std::uint8_t { kFree, kWaiting, kDecided };
  struct Slot {
    SlotState state = SlotState::kFree;
    loop::OperatorRequest request;
    std::uint64_t epoch = 0;  // hold_epoch_ when submitted
    Verdict verdict;
  };
  static constexpr int kRefusalKinds = 4;
  static int refusal_index(loop::OperatorRefusal why);

  mutable std::mutex mutex_;
  std::condition_variable decided_;
  std::array<Slot, kSlots> slots_{};
  std::atomic<std::uint64_t> hold_epoch_{0};
  std::array<std::atomic<std::uint32_t>, kRefusalKinds> refused_{};
};

}  // namespace lftrack::watch

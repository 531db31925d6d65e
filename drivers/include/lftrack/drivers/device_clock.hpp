#pragma once
// A camera's clock on the host's CLOCK_MONOTONIC, from timestamp latches.
//
// A latch (GigE Vision: write 2 to the timestamp control register 0x0944, then read the latched
// value at 0x0948-0x094F) tells the device's time at some instant between the host's write and
// the device's acknowledgement. Taken with the host's clock read just before the write and just
// after the acknowledgement, it places the device's clock on the host's to within half that
// round trip. DeviceClockMap keeps the offset of the tightest latch of each round (a round:
// several latches in a row, the first ones slowed by anything that delayed the device), so the
// mapping follows a device whose clock runs at a slightly different rate (a crystal's tens of
// ppm, or a clock that NTP slews) as long as rounds come often enough: at 50 ppm, a round a
// second keeps the drift under 50 us.
//
// Thread safety: one thread calls begin_round(), add() and end_round(); any thread may call
// mapping(), valid(), to_host_ns() and uncertainty_ns() at any time (the offset, its uncertainty and its time
// are published together, through one atomic generation count).

#include <atomic>
#include <cstdint>

namespace lftrack::drivers {

// One latch: the host's CLOCK_MONOTONIC before the request and after its acknowledgement, and
// the device's latched time in ns (its ticks at its tick frequency).
struct ClockLatch {
  std::int64_t host_before_ns = 0;
  std::int64_t device_ns = 0;
  std::int64_t host_after_ns = 0;
};

class DeviceClockMap {
 public:
  // A latch whose round trip is longer than this places the device's clock too loosely to time
  // an exposure (half of it is the mapping's uncertainty); a round whose latches are all slower
  // leaves the mapping as it was.
  static constexpr std::int64_t kMaxRoundTripNs = 2'000'000;

  // A round of latches; the tightest one accepted replaces the mapping at end_round().
  void begin_round();
  // False (and the latch is not used) where it is not a latch: the host's times out of order, a
  // device time of 0 or less (a camera without a clock latches 0), or a round trip beyond
  // kMaxRoundTripNs.
  bool add(const ClockLatch& latch);
  // True where the round had a latch to use, and the mapping was replaced.
  bool end_round();

  // The mapping: host = device + offset_ns, good to uncertainty_ns (half the round trip of the
  // latch it comes from) when it was made, at host time at_host_ns (the latch's middle; 0: no
  // mapping), read as one.
  struct Mapping {
    std::int64_t offset_ns = 0;
    std::int64_t uncertainty_ns = 0;
    std::int64_t at_host_ns = 0;
  };
  // The mapping as one. All 0 without one, or where renewals kept changing it through 64 tries
  // to read it (a renewal takes nanoseconds; the caller never spins without end).
  Mapping mapping() const;

  // A mapping is there (some round ended with a latch).
  bool valid() const;
  // The device's time `device_ns` on the host's CLOCK_MONOTONIC. Needs valid().
  std::int64_t to_host_ns(std::int64_t device_ns) const;
  // Half the round trip of the latch the mapping comes from, ns: how far to_host_ns() can be off
  // (besides the drift since). 0 without a mapping.
  std::int64_t uncertainty_ns() const;
  // Rounds that replaced the mapping, and latches refused, since construction.
  std::int64_t rounds() const { return rounds_.load(std::memory_order_relaxed); }
  std::int64_t refused() const { return refused_.load(std::memory_order_relaxed); }

 private:
  // The round being taken (its thread only).
  bool have_best_ = false;
  ClockLatch best_;
  // The published mapping: a seqlock (odd generation: being written).
  std::atomic<std::uint64_t> generation_{0};
  std::atomic<std::int64_t> offset_ns_{0}, uncertainty_ns_{0}, at_host_ns_{0};
  std::atomic<std::int64_t> rounds_{0}, refused_{0};
};

}  // namespace lftrack::drivers

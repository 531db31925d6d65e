#include "lftrack/drivers/device_clock.hpp"

namespace lftrack::drivers {

void DeviceClockMap::begin_round() {
  have_best_ = false;
}

bool DeviceClockMap::add(const ClockLatch& latch) {
  const std::int64_t round_trip = latch.host_after_ns - latch.host_before_ns;
  if (latch.host_before_ns <= 0 || round_trip < 0 || round_trip > kMaxRoundTripNs || latch.device_ns <= 0) {
    refused_.fetch_add(1, std::memory_order_relaxed);
    return false;
  }
  if (!have_best_ || round_trip < best_.host_after_ns - best_.host_before_ns) best_ = latch;
  have_best_ = true;
  return true;
}

bool DeviceClockMap::end_round() {
  if (!have_best_) return false;
  have_best_ = false;
  // The latch fell somewhere in [before, after]: its middle, give or take half the round trip.
  const std::int64_t middle = best_.host_before_ns + (best_.host_after_ns - best_.host_before_ns) / 2;
  const std::uint64_t g = generation_.load(std::memory_order_relaxed);
  generation_.store(g + 1, std::memory_order_relaxed);
  std::atomic_thread_fence(std::memory_order_release);
  offset_ns_.store(middle - best_.device_ns, std::memory_order_relaxed);
  uncertainty_ns_.store((best_.host_after_ns - best_.host_before_ns + 1) / 2, std::memory_order_relaxed);
  at_host_ns_.store(middle, std::memory_order_relaxed);
  generation_.store(g + 2, std::memory_order_release);
  rounds_.fetch_add(1, std::memory_order_relaxed);
  return true;
}

DeviceClockMap::Mapping DeviceClockMap::mapping() const {
  for (int attempt = 0; attempt < 64; ++attempt) {
    const std::uint64_t g = generation_.load(std::memory_order_acquire);
    Mapping m{offset_ns_.load(std::memory_order_relaxed), uncertainty_ns_.load(std::memory_order_relaxed),
              at_host_ns_.load(std::memory_order_relaxed)};
    std::atomic_thread_fence(std::memory_order_acquire);
    if ((g & 1) == 0 && generation_.load(std::memory_order_relaxed) == g) return m;
  }
  return {};
}

bool DeviceClockMap::valid() const {
  return generation_.load(std::memory_order_acquire) >= 2;
}

std::int64_t DeviceClockMap::to_host_ns(std::int64_t device_ns) const {
  return device_ns + mapping().offset_ns;
}

std::int64_t DeviceClockMap::uncertainty_ns() const {
  return valid() ? mapping().uncertainty_ns : 0;
}

}  // namespace lftrack::drivers

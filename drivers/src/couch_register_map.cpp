#include "lftrack/drivers/couch_register_map.hpp"

#include <cmath>
#include <limits>

namespace lftrack::drivers::couch_registers {

namespace {
constexpr double kUnitsPerMm = 1000.0;  // micrometres
constexpr double kUnitsPerRad = 1.0e6;  // microradians
double scale(int axis) {
  return axis < 3 ? kUnitsPerMm : kUnitsPerRad;
}
}  // namespace

bool encode_travel(const tracking::Vector6d& travel, std::uint16_t* registers) {
  std::array<std::int32_t, 6> units{};
  for (int i = 0; i < 6; ++i) {
    const double u = std::round(travel(i) * scale(i));
    if (!std::isfinite(u) || u > std::numeric_limits<std::int32_t>::max() ||
        u < std::numeric_limits<std::int32_t>::min())
      return false;
    units[std::size_t(i)] = static_cast<std::int32_t>(u);
  }
  for (std::size_t i = 0; i < 6; ++i) {
    const auto bits = static_cast<std::uint32_t>(units[i]);
    registers[2 * i] = static_cast<std::uint16_t>(bits >> 16);
    registers[2 * i + 1] = static_cast<std::uint16_t>(bits & 0xFFFFu);
  }
  return true;
}

tracking::Vector6d decode_travel(const std::uint16_t* registers) {
  tracking::Vector6d travel;
  for (int i = 0; i < 6; ++i) {
    const std::uint32_t bits = (std::uint32_t(registers[2 * i]) << 16) | registers[2 * i + 1];
    travel(i) = static_cast<double>(static_cast<std::int32_t>(bits)) / scale(i);
  }
  return travel;
}

}  // namespace lftrack::drivers::couch_registers

#include "lftrack/drivers/can_robot_protocol.hpp"

#include <cmath>
#include <cstring>
#include <limits>

namespace lftrack::drivers::robot_can {

namespace {

template <typename Int>
bool to_int(double value, double unit, Int* out) {
  const double u = std::round(value / unit);
  if (!std::isfinite(u) || u > double(std::numeric_limits<Int>::max()) ||
      u < double(std::numeric_limits<Int>::min()))
    return false;
  *out = static_cast<Int>(u);
  return true;
}

template <typename Int>
void put(std::uint8_t* at, Int v) {
  using U = std::make_unsigned_t<Int>;
  const auto bits = static_cast<U>(v);
  for (std::size_t i = 0; i < sizeof(Int); ++i) at[i] = static_cast<std::uint8_t>(bits >> (8 * i));
}

template <typename Int>
Int get(const std::uint8_t* at) {
  using U = std::make_unsigned_t<Int>;
  U bits = 0;
  for (std::size_t i = 0; i < sizeof(Int); ++i) bits = static_cast<U>(bits | (U(at[i]) << (8 * i)));
  return static_cast<Int>(bits);
}

}  // namespace

can_frame make_frame(canid_t id, int node, std::uint8_t dlc) {
  can_frame f;
  std::memset(&f, 0, sizeof f);
  f.can_id = id + static_cast<canid_t>(node);
  f.can_dlc = dlc;
  return f;
}

bool encode_correction(const tracking::Vector6d& c, int node, std::uint8_t sequence, can_frame* translation,
                       can_frame* rotation) {
  std::int16_t t[3], r[3];
  for (int i = 0; i < 3; ++i)
    if (!to_int(c(i), kTranslationUnitMm, &t[i]) || !to_int(c(3 + i), kRotationUnitRad, &r[i])) return false;
  *translation = make_frame(kCorrectionTranslation, node, 8);
  *rotation = make_frame(kCorrectionRotation, node, 8);
  for (int i = 0; i < 3; ++i) {
    put(translation->data + 2 * i, t[i]);
    put(rotation->data + 2 * i, r[i]);
  }
  translation->data[6] = rotation->data[6] = sequence;
  return true;
}

tracking::Vector6d decode_correction(const can_frame& translation, const can_frame& rotation) {
  tracking::Vector6d c;
  for (int i = 0; i < 3; ++i) {
    c(i) = get<std::int16_t>(translation.data + 2 * i) * kTranslationUnitMm;
    c(3 + i) = get<std::int16_t>(rotation.data + 2 * i) * kRotationUnitRad;
  }
  return c;
}

bool encode_travel(const tracking::Vector6d& travel, canid_t first, int node, can_frame* frames) {
  std::int32_t v[6];
  for (int i = 0; i < 6; ++i)
    if (!to_int(travel(i), i < 3 ? kReadbackUnitMm : kReadbackUnitRad, &v[i])) return false;
  for (int k = 0; k < 3; ++k) {
    frames[k] = make_frame(first + static_cast<canid_t>(k), node, 8);
    put(frames[k].data, v[2 * k]);
    put(frames[k].data + 4, v[2 * k + 1]);
  }
  return true;
}

void decode_travel_frame(const can_frame& frame, int index, tracking::Vector6d* travel) {
  for (int j = 0; j < 2; ++j) {
    const int axis = 2 * index + j;
    (*travel)(axis) = get<std::int32_t>(frame.data + 4 * j) * (axis < 3 ? kReadbackUnitMm : kReadbackUnitRad);
  }
}

}  // namespace lftrack::drivers::robot_can

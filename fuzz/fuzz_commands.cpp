// Operator commands as the control socket receives them (loop/operator_input.hpp), and CAN
// frames as the robot driver decodes them (drivers/can_robot_protocol.hpp): a decoded value is
// finite or refused, never NaN reaching the loop.
#include <linux/can.h>

#include <cmath>
#include <cstring>

#include "fuzz_input.hpp"
#include "lftrack/drivers/can_robot_protocol.hpp"
#include "lftrack/loop/operator_input.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  loop::OperatorRequest request;
  if (loop::parse_operator_request(reinterpret_cast<const char*>(data), size, &request) &&
      request.command == loop::OperatorCommand::kNone)
    std::abort();  // accepted, yet no command
  if (size >= 2 * sizeof(can_frame)) {
    can_frame a{}, b{};
    std::memcpy(&a, data, sizeof a);
    std::memcpy(&b, data + sizeof a, sizeof b);
    a.len = static_cast<std::uint8_t>(a.len % 9);
    b.len = static_cast<std::uint8_t>(b.len % 9);
    const tracking::Vector6d c = drivers::robot_can::decode_correction(a, b);
    tracking::Vector6d travel = tracking::Vector6d::Zero();
    drivers::robot_can::decode_travel_frame(a, 0, &travel);
    drivers::robot_can::decode_travel_frame(b, 1, &travel);
    volatile double sink = c.sum() + travel.sum();
    (void)sink;
  }
  return 0;
}

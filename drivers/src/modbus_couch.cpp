#include "lftrack/drivers/modbus_couch.hpp"

#include <modbus/modbus.h>
#include <poll.h>
#include <sys/socket.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>

#include "lftrack/drivers/couch_register_map.hpp"

namespace lftrack::drivers {

namespace reg = couch_registers;
using Clock = std::chrono::steady_clock;

ModbusCouch::ModbusCouch(ModbusCouchOptions options) : options_(std::move(options)) {}

ModbusCouch::~ModbusCouch() {
  close();
}

std::string ModbusCouch::endpoint() const {
  if (options_.transport == ModbusCouchOptions::Transport::kTcp)
    return "modbus tcp " + options_.host + ":" + std::to_string(options_.port) + " unit " +
           std::to_string(options_.unit_id);
  return "modbus rtu " + options_.serial_device + " " + std::to_string(options_.baud) + " unit " +
         std::to_string(options_.unit_id);
}

ModbusCouchCounters ModbusCouch::counters() const {
  ModbusCouchCounters c;
  c.requests = requests_.load();
  c.timeouts = timeouts_.load();
  c.exceptions = exceptions_.load();
  c.bad_replies = bad_replies_.load();
  c.disconnects = disconnects_.load();
  c.reconnects = reconnects_.load();
  c.last_exception = last_exception_.load();
  return c;
}

Status ModbusCouch::open() {
  if (ctx_ != nullptr) return failed_precondition(endpoint() + ": already open");
  if (options_.unit_id < 1 || options_.unit_id > 247)
    return invalid_argument(endpoint() + ": unit id must be in 1..247");
  if (!(options_.response_timeout_s > 0) || options_.response_timeout_s > 5)
    return invalid_argument(endpoint() + ": response timeout must be in (0, 5] s");
  ctx_ = options_.transport == ModbusCouchOptions::Transport::kTcp
             ? modbus_new_tcp(options_.host.c_str(), options_.port)
             : modbus_new_rtu(options_.serial_device.c_str(), options_.baud, options_.parity,
                              options_.data_bits, options_.stop_bits);
  if (ctx_ == nullptr) return invalid_argument(endpoint() + ": " + modbus_strerror(errno));
  modbus_set_slave(ctx_, options_.unit_id);
  modbus_set_error_recovery(ctx_, MODBUS_ERROR_RECOVERY_NONE);  // no sleeping, no silent retries
  modbus_set_response_timeout(ctx_, 1, 0);                      // connecting and the first read
  if (modbus_connect(ctx_) != 0) {
    const std::string why = modbus_strerror(errno);
    modbus_free(ctx_);
    ctx_ = nullptr;
    return io_error(endpoint() + ": cannot connect: " + why);
  }
  std::uint16_t input[reg::kInputCount];
  if (read_inputs(input) != DeviceStatus::kOk) {
    const std::string why = modbus_strerror(errno);
    modbus_close(ctx_);
    modbus_free(ctx_);
    ctx_ = nullptr;
    return io_error(endpoint() + ": the couch does not answer a status read: " + why);
  }
  commanded_ = reg::decode_travel(input + reg::kAcceptedTarget);
  sequence_ = input[reg::kAcknowledged];
  resync_ = false;
  stopping_ = false;
  connected_.store(true, std::memory_order_release);
  reconnector_ = std::thread([this] { reconnect_thread(); });
  return {};
}

void ModbusCouch::close() {
  if (reconnector_.joinable()) {
    {
      std::lock_guard lock(wake_mutex_);
      stopping_ = true;
    }
    wake_.notify_all();
    reconnector_.join();
  }
  if (ctx_ != nullptr) {
    modbus_close(ctx_);
    modbus_free(ctx_);
    ctx_ = nullptr;
  }
  connected_ = false;
}

bool ModbusCouch::set_timeout(Deadline deadline, bool drain) {
  if (flush_before_next_) {
    // A reply that came after its timeout must not answer the next request.
    if (options_.transport == ModbusCouchOptions::Transport::kRtu) {
      if (!drain) {
        modbus_flush(ctx_);  // what has come so far; the next request drains the line
        return set_response_timeout(deadline);
      }
      if (!drain_line(deadline)) return false;
    } else {
      modbus_flush(ctx_);  // TCP: a stale reply left over is also refused by its transaction id
    }
    flush_before_next_ = false;
  }
  return set_response_timeout(deadline);
}

bool ModbusCouch::set_response_timeout(Deadline deadline) {
  const double remaining_s = std::chrono::duration<double>(deadline - Clock::now()).count();
  const double timeout_s = std::min(options_.response_timeout_s, remaining_s);
  if (timeout_s < 1e-4) return false;
  const auto us = static_cast<std::uint32_t>(std::llround(timeout_s * 1e6));
  modbus_set_response_timeout(ctx_, us / 1000000u, us % 1000000u);
  return true;
}

Clock::duration ModbusCouch::response_timeout() const {
  return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(options_.response_timeout_s));
}

bool ModbusCouch::drain_line(Deadline deadline) {
  for (;;) {
    const auto now = Clock::now();
    const auto until = std::min<Clock::time_point>(line_quiet_at_, deadline);
    pollfd line{modbus_get_socket(ctx_), POLLIN, 0};
    const auto wait_ms = until > now ? std::chrono::ceil<std::chrono::milliseconds>(until - now).count() : 0;
    const int ready = ::poll(&line, 1, static_cast<int>(wait_ms));
    // A line in error or hung up (an adapter unplugged, a peer gone) is never quiet: no request.
    if (ready > 0 && (line.revents & (POLLERR | POLLHUP | POLLNVAL)) != 0) return false;
    if (ready > 0) {  // bytes still arriving: discard them and wait for a silence again
      modbus_flush(ctx_);
      line_quiet_at_ = Clock::now() + response_timeout();
      if (Clock::now() >= deadline) return false;  // a line that never falls silent: bounded
      continue;
    }
    if (ready < 0 && errno != EINTR) return false;
    if (Clock::now() >= line_quiet_at_) return true;
    if (Clock::now() >= deadline) return false;  // not quiet yet: the request waits for a later cycle
  }
}

void ModbusCouch::mark_disconnected() {
  ++disconnects_;
  connected_.store(false, std::memory_order_release);
  wake_.notify_all();
}

DeviceStatus ModbusCouch::classify_failure(int error) {
  // On a serial line a late reply or the rest of a bad one may still come: quiet a timeout from now.
  if (error == ETIMEDOUT) {
    ++timeouts_;
    flush_before_next_ = true;
    line_quiet_at_ = Clock::now() + response_timeout();
    return DeviceStatus::kTimeout;
  }
  if (error > MODBUS_ENOBASE && error <= EMBXGTAR) {
    ++exceptions_;
    last_exception_ = error - MODBUS_ENOBASE;
    return DeviceStatus::kFault;
  }
  if (error == EMBBADCRC || error == EMBBADDATA || error == EMBBADEXC || error == EMBMDATA ||
      error == EMBBADSLAVE || error == EMBUNKEXC) {
    ++bad_replies_;
    flush_before_next_ = true;
    line_quiet_at_ = Clock::now() + response_timeout();
    return DeviceStatus::kFault;
  }
  mark_disconnected();  // ECONNRESET, EPIPE, EBADF, ENOTCONN, EIO...
  return DeviceStatus::kDisconnected;
}

DeviceStatus ModbusCouch::tcp_transact(const std::uint8_t* pdu, int pdu_length, std::uint8_t* reply_pdu,
                                       int expected_pdu_length) {
  constexpr int kMbap = 7;  // transaction, protocol, length, unit
  std::uint8_t adu[MODBUS_TCP_MAX_ADU_LENGTH];
  ++transaction_;
  adu[0] = static_cast<std::uint8_t>(transaction_ >> 8);
  adu[1] = static_cast<std::uint8_t>(transaction_ & 0xFF);
  adu[2] = adu[3] = 0;
  adu[4] = static_cast<std::uint8_t>((pdu_length + 1) >> 8);
  adu[5] = static_cast<std::uint8_t>((pdu_length + 1) & 0xFF);
  adu[6] = static_cast<std::uint8_t>(options_.unit_id);
  std::memcpy(adu + kMbap, pdu, std::size_t(pdu_length));
  const ssize_t sent = ::send(modbus_get_socket(ctx_), adu, std::size_t(kMbap + pdu_length), MSG_NOSIGNAL);
  if (sent != kMbap + pdu_length) return classify_failure(sent < 0 ? errno : EIO);
  std::uint8_t reply[MODBUS_TCP_MAX_ADU_LENGTH];
  const int length = modbus_receive_confirmation(ctx_, reply);
  if (length < 0) return classify_failure(errno);
  const int transaction = (reply[0] << 8) | reply[1];
  const bool framed = length >= kMbap + 2 && transaction == transaction_ && reply[2] == 0 && reply[3] == 0;
  if (!framed || reply[6] != options_.unit_id) return classify_failure(framed ? EMBBADSLAVE : EMBBADDATA);
  if (reply[kMbap] == (pdu[0] | 0x80)) {
    const int code = reply[kMbap + 1];
    return classify_failure(code >= 1 && code <= MODBUS_EXCEPTION_GATEWAY_TARGET ? MODBUS_ENOBASE + code
                                                                                 : EMBBADEXC);
  }
  if (reply[kMbap] != pdu[0] || length != kMbap + expected_pdu_length) return classify_failure(EMBBADDATA);
  std::memcpy(reply_pdu, reply + kMbap, std::size_t(expected_pdu_length));
  return DeviceStatus::kOk;
}

DeviceStatus ModbusCouch::write_holding(const std::uint16_t* registers) {
  ++requests_;
  if (options_.transport == ModbusCouchOptions::Transport::kRtu)
    return modbus_write_registers(ctx_, reg::kTarget, reg::kHoldingCount, registers) == reg::kHoldingCount
               ? DeviceStatus::kOk
               : classify_failure(errno);
  std::uint8_t pdu[6 + 2 * reg::kHoldingCount];
  pdu[0] = MODBUS_FC_WRITE_MULTIPLE_REGISTERS;
  pdu[1] = 0;
  pdu[2] = reg::kTarget;
  pdu[3] = 0;
  pdu[4] = reg::kHoldingCount;
  pdu[5] = 2 * reg::kHoldingCount;
  for (int i = 0; i < reg::kHoldingCount; ++i) {
    pdu[6 + 2 * i] = static_cast<std::uint8_t>(registers[i] >> 8);
    pdu[7 + 2 * i] = static_cast<std::uint8_t>(registers[i] & 0xFF);
  }
  std::uint8_t reply[5];  // function, address, count
  const DeviceStatus s = tcp_transact(pdu, sizeof pdu, reply, sizeof reply);
  if (s != DeviceStatus::kOk) return s;
  return reply[2] == reg::kTarget && reply[4] == reg::kHoldingCount ? DeviceStatus::kOk
                                                                    : classify_failure(EMBBADDATA);
}

DeviceStatus ModbusCouch::write_control(std::uint16_t value) {
  ++requests_;
  if (options_.transport == ModbusCouchOptions::Transport::kRtu)
    return modbus_write_register(ctx_, reg::kControl, value) == 1 ? DeviceStatus::kOk
                                                                  : classify_failure(errno);
  const std::uint8_t pdu[5] = {MODBUS_FC_WRITE_SINGLE_REGISTER, 0, reg::kControl,
                               static_cast<std::uint8_t>(value >> 8),
                               static_cast<std::uint8_t>(value & 0xFF)};
  std::uint8_t reply[5];  // the request echoed
  const DeviceStatus s = tcp_transact(pdu, sizeof pdu, reply, sizeof reply);
  if (s != DeviceStatus::kOk) return s;
  return std::memcmp(pdu, reply, sizeof pdu) == 0 ? DeviceStatus::kOk : classify_failure(EMBBADDATA);
}

DeviceStatus ModbusCouch::read_inputs(std::uint16_t* registers) {
  ++requests_;
  if (options_.transport == ModbusCouchOptions::Transport::kRtu)
    return modbus_read_input_registers(ctx_, reg::kStatus, reg::kInputCount, registers) == reg::kInputCount
               ? DeviceStatus::kOk
               : classify_failure(errno);
  const std::uint8_t pdu[5] = {MODBUS_FC_READ_INPUT_REGISTERS, 0, reg::kStatus, 0, reg::kInputCount};
  std::uint8_t reply[2 + 2 * reg::kInputCount];  // function, byte count, registers
  const DeviceStatus s = tcp_transact(pdu, sizeof pdu, reply, sizeof reply);
  if (s != DeviceStatus::kOk) return s;
  if (reply[1] != 2 * reg::kInputCount) return classify_failure(EMBBADDATA);
  for (int i = 0; i < reg::kInputCount; ++i)
    registers[i] = static_cast<std::uint16_t>((reply[2 + 2 * i] << 8) | reply[3 + 2 * i]);
  return DeviceStatus::kOk;
}

DeviceStatus ModbusCouch::command(const tracking::Vector6d& correction, Deadline deadline) {
  if (!connected_.load(std::memory_order_acquire)) return DeviceStatus::kDisconnected;
  if (resync_.load()) return DeviceStatus::kRefused;  // no read-back since hold or reconnection
  std::uint16_t holding[reg::kHoldingCount];
  const tracking::Vector6d target = commanded_ + correction;
  if (!correction.allFinite() || !reg::encode_travel(target, holding + reg::kTarget))
    return DeviceStatus::kRefused;
  holding[reg::kCommandSequence] = static_cast<std::uint16_t>(sequence_ + 1);
  holding[reg::kControl] = reg::kEnable;
  if (!set_timeout(deadline)) return DeviceStatus::kTimeout;
  if (const DeviceStatus s = write_holding(holding); s != DeviceStatus::kOk) return s;
  ++sequence_;
  commanded_ = target;
  return DeviceStatus::kOk;
}

DeviceStatus ModbusCouch::readback(ActuatorState* state, Deadline deadline) {
  if (!connected_.load(std::memory_order_acquire)) return DeviceStatus::kDisconnected;
  std::uint16_t input[reg::kInputCount];
  if (!set_timeout(deadline)) return DeviceStatus::kTimeout;
  if (const DeviceStatus s = read_inputs(input); s != DeviceStatus::kOk) return s;
  state->position = reg::decode_travel(input + reg::kPosition);
  state->target = reg::decode_travel(input + reg::kAcceptedTarget);
  state->moving = (input[reg::kStatus] & reg::kStatusMoving) != 0;
  state->fault = (input[reg::kStatus] & reg::kStatusFault) != 0 || input[reg::kFaultWord] != reg::kNoFault;
  if (resync_.exchange(false)) {
    commanded_ = state->target;
    sequence_ = input[reg::kAcknowledged];
  }
  return DeviceStatus::kOk;
}

void ModbusCouch::hold() {
  resync_ = true;
  if (!connected_.load(std::memory_order_acquire)) return;  // the reconnect thread holds first
  // Hold has no cycle deadline: it gets the full response timeout.
  // No drain: the hold goes out now; its reply may be refused as another's (the next request
  // drains the line), but the couch has it.
  if (!set_timeout(Clock::now() + response_timeout(), /*drain=*/false)) return;
  (void)write_control(reg::kHold);  // a failure is counted; the read-back that follows tells the loop
}

void ModbusCouch::reconnect_thread() {
  std::unique_lock lock(wake_mutex_);
  const auto interval = std::chrono::duration<double>(options_.reconnect_interval_s);
  while (!stopping_) {
    wake_.wait_for(lock, interval);
    if (stopping_ || connected_.load(std::memory_order_acquire)) continue;
    // The cycle no longer touches ctx_: reconnect, hold, then hand it back.
    modbus_close(ctx_);
    modbus_set_response_timeout(ctx_, 0, 500000);
    if (modbus_connect(ctx_) != 0) continue;
    modbus_flush(ctx_);
    if (write_control(reg::kHold) != DeviceStatus::kOk) {
      modbus_close(ctx_);
      continue;
    }
    resync_ = true;
    flush_before_next_ = false;
    ++reconnects_;
    connected_.store(true, std::memory_order_release);
  }
}

}  // namespace lftrack::drivers

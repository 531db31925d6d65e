#include "lftrack/sim/modbus_couch_server.hpp"

#include <arpa/inet.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "lftrack/drivers/couch_register_map.hpp"

namespace lftrack::sim {

namespace reg = drivers::couch_registers;

ModbusCouchServer::ModbusCouchServer(drivers::Actuator* couch, const ModbusCouchServerOptions& options)
    : couch_(couch), options_(options) {}

Result<std::unique_ptr<ModbusCouchServer>> ModbusCouchServer::start(drivers::Actuator* couch,
                                                                    const ModbusCouchServerOptions& options) {
  if (couch == nullptr) return invalid_argument("modbus couch server: no couch");
  std::unique_ptr<ModbusCouchServer> s(new ModbusCouchServer(couch, options));
  const bool rtu = !options.rtu_device.empty();
  const std::string where = rtu ? options.rtu_device : options.address + ":" + std::to_string(options.port);
  s->ctx_ = rtu ? modbus_new_rtu(options.rtu_device.c_str(), 115200, 'E', 8, 1)
                : modbus_new_tcp(options.address.c_str(), options.port);
  if (s->ctx_ == nullptr) return io_error("modbus couch server: " + where + ": " + modbus_strerror(errno));
  modbus_set_slave(s->ctx_, options.unit_id);
  s->map_ = modbus_mapping_new_start_address(0, 0, 0, 0, 0, reg::kHoldingCount, 0, reg::kInputCount);
  if (s->map_ == nullptr) return io_error("modbus couch server: no register mapping");
  if (rtu) {
    if (modbus_connect(s->ctx_) != 0)
      return io_error("modbus couch server: cannot open " + where + ": " + modbus_strerror(errno));
  } else {
    s->listen_fd_ = modbus_tcp_listen(s->ctx_, 1);
    if (s->listen_fd_ < 0)
      return io_error("modbus couch server: cannot listen on " + where + ": " + modbus_strerror(errno));
    sockaddr_in address{};
    socklen_t length = sizeof address;
    if (getsockname(s->listen_fd_, reinterpret_cast<sockaddr*>(&address), &length) != 0)
      return io_error(std::string("modbus couch server: getsockname: ") + std::strerror(errno));
    s->port_ = ntohs(address.sin_port);
  }
  drivers::ActuatorState state;
  if (couch->readback(&state, {}) == drivers::DeviceStatus::kOk) s->accepted_target_ = state.target;
  s->refresh_inputs(false);
  s->thread_ = std::thread([p = s.get(), rtu] { rtu ? p->serve_rtu() : p->serve(); });
  return s;
}

ModbusCouchServer::~ModbusCouchServer() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (listen_fd_ >= 0) ::close(listen_fd_);
  if (ctx_ != nullptr) {
    modbus_close(ctx_);
    modbus_free(ctx_);
  }
  if (map_ != nullptr) modbus_mapping_free(map_);
}

void ModbusCouchServer::inject(CouchServerFault fault, int requests, CouchRequestKind kind) {
  fault_requests_ = 0;
  fault_ = static_cast<int>(fault);
  fault_kind_ = static_cast<int>(kind);
  fault_requests_ = requests;
}

CouchServerFault ModbusCouchServer::take_fault(CouchRequestKind kind) {
  const auto wanted = static_cast<CouchRequestKind>(fault_kind_.load());
  if (wanted != CouchRequestKind::kAny && wanted != kind) return CouchServerFault::kNone;
  int left = fault_requests_.load();
  while (left > 0 && !fault_requests_.compare_exchange_weak(left, left - 1)) {
  }
  return left > 0 ? static_cast<CouchServerFault>(fault_.load()) : CouchServerFault::kNone;
}

void ModbusCouchServer::serve() {
  std::uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
  while (!stop_) {
    pollfd listening{listen_fd_, POLLIN, 0};
    if (poll(&listening, 1, 20) <= 0) continue;
    int fd = listen_fd_;
    if (modbus_tcp_accept(ctx_, &fd) < 0) continue;
    ++connections_;
    while (!stop_) {
      pollfd client{modbus_get_socket(ctx_), POLLIN, 0};
      const int ready = poll(&client, 1, 20);
      if (ready == 0) continue;
      if (ready < 0 && errno == EINTR) continue;
      const int length = modbus_receive(ctx_, query);
      if (length < 0) break;  // the client went away
      if (length == 0) continue;
      ++requests_;
      handle(query, length);
      if (modbus_get_socket(ctx_) < 0) break;  // dropped on purpose
    }
    modbus_close(ctx_);
  }
}

void ModbusCouchServer::serve_rtu() {
  std::uint8_t query[MODBUS_RTU_MAX_ADU_LENGTH];
  while (!stop_) {
    pollfd line{modbus_get_socket(ctx_), POLLIN, 0};
    if (poll(&line, 1, 20) <= 0) continue;
    const int length = modbus_receive(ctx_, query);
    if (length <= 0) continue;  // another unit's request, or noise on the line
    ++requests_;
    handle(query, length);
  }
}

void ModbusCouchServer::refresh_inputs(bool mismatch) {
  drivers::ActuatorState state;
  const bool ok = couch_->readback(&state, {}) == drivers::DeviceStatus::kOk;
  if (mismatch) {
    state.position(0) += options_.mismatch_mm;
    state.target(0) += options_.mismatch_mm;
  }
  std::uint16_t* in = map_->tab_input_registers;
  in[reg::kStatus] = static_cast<std::uint16_t>((state.moving ? reg::kStatusMoving : 0) |
                                                (state.fault || !ok ? reg::kStatusFault : 0) |
                                                (holding_ ? reg::kStatusHolding : reg::kStatusEnabled));
  in[reg::kAcknowledged] = acknowledged_;
  in[reg::kFaultWord] = ok ? fault_word_ : reg::kFaultDrive;
  reg::encode_travel(state.position, in + reg::kPosition);
  reg::encode_travel(state.target, in + reg::kAcceptedTarget);
}

void ModbusCouchServer::hold_where_it_is() {
  couch_->hold();
  drivers::ActuatorState state;
  if (couch_->readback(&state, {}) == drivers::DeviceStatus::kOk) accepted_target_ = state.target;
  holding_ = true;
}

void ModbusCouchServer::handle(std::uint8_t* query, int length) {
  const int h = modbus_get_header_length(ctx_);
  const std::uint8_t function = query[h];
  const int address = (query[h + 1] << 8) | query[h + 2];
  const int count = (query[h + 3] << 8) | query[h + 4];
  bool mismatch = false;
  const CouchRequestKind kind =
      function == MODBUS_FC_READ_INPUT_REGISTERS ? CouchRequestKind::kReadback : CouchRequestKind::kCommand;
  switch (take_fault(kind)) {
    case CouchServerFault::kNone:
      break;
    case CouchServerFault::kNoReply:
      return;
    case CouchServerFault::kException4:
      modbus_reply_exception(ctx_, query, reg::kExceptionDeviceFailure);
      return;
    case CouchServerFault::kException6:
      modbus_reply_exception(ctx_, query, reg::kExceptionBusy);
      return;
    case CouchServerFault::kWrongUnit:
      query[h - 1] = static_cast<std::uint8_t>(query[h - 1] + 1);  // the reply copies the request's unit
      break;
    case CouchServerFault::kDropConnection:
      modbus_close(ctx_);
      return;
    case CouchServerFault::kReadbackMismatch:
      mismatch = true;
      break;
  }
  if (function == MODBUS_FC_WRITE_MULTIPLE_REGISTERS && address == reg::kTarget &&
      count == reg::kHoldingCount) {
    std::uint16_t holding[reg::kHoldingCount];
    for (int i = 0; i < reg::kHoldingCount; ++i)
      holding[i] = static_cast<std::uint16_t>((query[h + 6 + 2 * i] << 8) | query[h + 7 + 2 * i]);
    if (holding[reg::kControl] == reg::kEnable) {
      const tracking::Vector6d target = reg::decode_travel(holding + reg::kTarget);
      if (couch_->command(target - accepted_target_, {}) != drivers::DeviceStatus::kOk) {
        fault_word_ = reg::kFaultTargetOutOfRange;
        refresh_inputs(false);
        modbus_reply_exception(ctx_, query, reg::kExceptionIllegalValue);
        return;
      }
      accepted_target_ = target;
      acknowledged_ = holding[reg::kCommandSequence];
      fault_word_ = reg::kNoFault;
      holding_ = false;
    } else if (holding[reg::kControl] == reg::kHold) {
      hold_where_it_is();
    } else {
      // A control word that is neither enable nor hold is refused as a real drive refuses it
      // (exception 3), never echoed as if it were done.
      modbus_reply_exception(ctx_, query, reg::kExceptionIllegalValue);
      return;
    }
  } else if (function == MODBUS_FC_WRITE_SINGLE_REGISTER && address == reg::kControl) {
    const int value = (query[h + 3] << 8) | query[h + 4];
    if (value != reg::kHold && value != reg::kEnable) {
      modbus_reply_exception(ctx_, query, reg::kExceptionIllegalValue);
      return;
    }
    if (value == reg::kHold) hold_where_it_is();
  }
  refresh_inputs(mismatch);
  modbus_reply(ctx_, query, length, map_);
}

}  // namespace lftrack::sim

#include "lftrack/sim/modbus_couch_server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <thread>
#include <vector>

#include "lftrack/drivers/couch_register_map.hpp"

namespace lftrack::sim {

namespace reg = drivers::couch_registers;

namespace {

std::int64_t now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

// A TCP client: its socket, the bytes of the request it is sending, when it last completed one.
struct Connection {
  int fd = -1;
  std::uint8_t bytes[MODBUS_TCP_MAX_ADU_LENGTH] = {};
  std::size_t have = 0;
  std::int64_t heard_ns = 0;
  std::int64_t accepted_ns = 0;
  std::int64_t requests = 0;
  bool commander = false;  // sent the last command the couch acted on (the loop's connection)
};

// A connection younger than this is not closed to make room for a new one (it has had no time
// to show how often it asks); an older one may be, the one asking least often first.
constexpr std::int64_t kGraceNs = 1'000'000'000;

// What a request must be before it touches the couch: a PDU as long as its function says (a
// write of N registers carries 2N bytes), for this server's unit (or 0xFF, "this device", as
// Modbus TCP allows). Returns the Modbus exception to answer (0: none), or -1 to drop it unanswered.
int check_request(const std::uint8_t* query, int header, int length, int unit_id, bool tcp) {
  const int pdu = length - header - (tcp ? 0 : 2);  // RTU: the CRC after it
  if (pdu < 1) return -1;
  const int unit = query[header - 1];
  if (unit == 0) return -1;  // a broadcast: never answered, and no couch moves by one
  if (unit != unit_id && !(tcp && unit == 0xFF)) return tcp ? MODBUS_EXCEPTION_GATEWAY_TARGET : -1;
  const int function = query[header];
  const int address = pdu >= 3 ? (query[header + 1] << 8) | query[header + 2] : -1;
  const int count = pdu >= 5 ? (query[header + 3] << 8) | query[header + 4] : -1;
  switch (function) {
    case MODBUS_FC_READ_HOLDING_REGISTERS:
    case MODBUS_FC_READ_INPUT_REGISTERS: {
      // Checked here, never left to libmodbus: for a quantity out of range it sleeps its response
      // timeout and flushes before answering, and this server's one thread serves every client
      // (issue 50, second probe: six such reads put a running loop into FAULT).
      if (pdu != 5 || count < 1 || count > MODBUS_MAX_READ_REGISTERS) return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
      const int registers =
          function == MODBUS_FC_READ_INPUT_REGISTERS ? drivers::couch_registers::kInputCount : drivers::couch_registers::kHoldingCount;
      return address + count <= registers ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
    }
    case MODBUS_FC_WRITE_SINGLE_REGISTER:
      return pdu == 5 ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    case MODBUS_FC_WRITE_MULTIPLE_REGISTERS:
      if (pdu < 6 || count < 1 || count > MODBUS_MAX_WRITE_REGISTERS) return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
      return query[header + 5] == 2 * count && pdu == 6 + 2 * count ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    default:
      return 0;  // libmodbus answers what this couch does not implement (illegal function)
  }
}

}  // namespace

ModbusCouchServer::ModbusCouchServer(drivers::Actuator* couch, const ModbusCouchServerOptions& options)
    : couch_(couch), options_(options) {}

Result<std::unique_ptr<ModbusCouchServer>> ModbusCouchServer::start(drivers::Actuator* couch,
                                                                    const ModbusCouchServerOptions& options) {
  if (couch == nullptr) return invalid_argument("modbus couch server: no couch");
  if (options.max_connections < 1 || options.max_connections > 64)
    return invalid_argument("modbus couch server: max_connections must be 1 to 64");
  if (!std::isfinite(options.idle_timeout_s) || options.idle_timeout_s <= 0 || options.idle_timeout_s > 3600)
    return invalid_argument("modbus couch server: idle_timeout_s must be above 0 and at most 3600");
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
    s->listen_fd_ = modbus_tcp_listen(s->ctx_, options.max_connections);
    if (s->listen_fd_ < 0)
      return io_error("modbus couch server: cannot listen on " + where + ": " + modbus_strerror(errno));
    ::fcntl(s->listen_fd_, F_SETFL, ::fcntl(s->listen_fd_, F_GETFL) | O_NONBLOCK);  // accept never waits
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
  const auto idle_ns = static_cast<std::int64_t>(options_.idle_timeout_s * 1e9);
  std::vector<Connection> clients;
  std::vector<pollfd> fds;
  // Reads what `c` has sent and answers each request it completes; false when the connection is
  // to close (the client went away, sent what is not Modbus TCP, or a fault dropped it).
  const auto take = [&](Connection& c) {
    for (;;) {
      const ssize_t n = ::recv(c.fd, c.bytes + c.have, sizeof c.bytes - c.have, MSG_DONTWAIT);
      if (n == 0) return false;
      if (n < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR;
      c.have += std::size_t(n);
      // The MBAP header (7 bytes) says how long each request is.
      while (c.have >= 7) {
        const int protocol = (c.bytes[2] << 8) | c.bytes[3];
        const std::size_t length = std::size_t((c.bytes[4] << 8) | c.bytes[5]);  // unit id and PDU
        if (protocol != 0 || length < 2 || 6 + length > sizeof c.bytes) return false;
        if (c.have < 6 + length) break;
        // Zeros past the request: libmodbus reads a PDU as long as its function says, and never
        // the next request's bytes for it.
        std::uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH] = {};
        std::memcpy(query, c.bytes, 6 + length);
        std::memmove(c.bytes, c.bytes + 6 + length, c.have - (6 + length));
        c.have -= 6 + length;
        c.heard_ns = now_ns();
        ++c.requests;
        ++requests_;
        modbus_set_socket(ctx_, c.fd);
        handle(query, static_cast<int>(6 + length));
        if (commanded_) {
          for (Connection& other : clients) other.commander = false;
          c.commander = true;
        }
        const bool dropped = modbus_get_socket(ctx_) < 0;  // kDropConnection closed it
        modbus_set_socket(ctx_, -1);
        if (dropped) {
          c.fd = -1;
          return false;
        }
      }
    }
  };
  const auto close_connection = [&](Connection& c) {
    if (c.fd >= 0) ::close(c.fd);
    c.fd = -1;
  };
  while (!stop_) {
    fds.assign(1, pollfd{listen_fd_, POLLIN, 0});
    for (const Connection& c : clients) fds.push_back(pollfd{c.fd, POLLIN, 0});
    if (poll(fds.data(), fds.size(), 20) > 0) {
      for (std::size_t i = 0; i < clients.size(); ++i)
        if (fds[i + 1].revents != 0 && !take(clients[i])) close_connection(clients[i]);
      if (fds[0].revents & POLLIN) {
        const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd >= 0) {
          ++connections_;
          std::erase_if(clients, [](const Connection& c) { return c.fd < 0; });
          const std::int64_t accepted = now_ns();
          if (clients.size() >= std::size_t(options_.max_connections)) {
            // Room is made by closing, of the connections older than a second, the one that has
            // asked least often (requests per second since its accept), never the one that sent
            // the last command: the loop asks every period, so a flood of newcomers cannot push
            // it out (issue 50 probe), and connections that ask now and then cannot keep a
            // starting loop out (second and third probes: four asking every 20 s, then every
            // 0.5 s, held every slot); to hold a slot against the loop, a client must ask as
            // often as it does. Otherwise the newcomer is turned away.
            auto silent = clients.end();
            const auto rate = [accepted](const Connection& c) {
              return double(c.requests) / (1e-9 * double(accepted - c.accepted_ns));
            };
            for (auto it = clients.begin(); it != clients.end(); ++it)
              if (!it->commander && accepted - it->accepted_ns > kGraceNs &&
                  (silent == clients.end() || rate(*it) < rate(*silent)))
                silent = it;
            if (silent != clients.end()) {
              ++idle_closed_;  // counted before the client can see the close
              close_connection(*silent);
            }
          }
          std::erase_if(clients, [](const Connection& c) { return c.fd < 0; });
          if (clients.size() >= std::size_t(options_.max_connections)) {
            ++turned_away_;
            ::close(fd);
          } else {
            clients.push_back(Connection{});
            clients.back().fd = fd;
            clients.back().heard_ns = clients.back().accepted_ns = accepted;
            clients.back().commander = false;
          }
        }
      }
    }
    const std::int64_t now = now_ns();
    for (Connection& c : clients)
      if (c.fd >= 0 && now - c.heard_ns > idle_ns) {
        ++idle_closed_;  // counted before the client can see the close (a test waits on the close)
        close_connection(c);
      }
    std::erase_if(clients, [](const Connection& c) { return c.fd < 0; });
  }
  for (Connection& c : clients) close_connection(c);
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
  commanded_ = false;
  const int h = modbus_get_header_length(ctx_);
  if (const int refused = check_request(query, h, length, options_.unit_id, options_.rtu_device.empty());
      refused != 0) {
    ++malformed_;
    if (refused > 0) modbus_reply_exception(ctx_, query, unsigned(refused));
    return;
  }
  const std::uint8_t function = query[h];
  const int address = (query[h + 1] << 8) | query[h + 2];
  const int count = (query[h + 3] << 8) | query[h + 4];
  // The couch acts on two writes only: the whole block (target, sequence, control word) and the
  // control word alone. Any other write would land in the register table, be answered as done and
  // not be carried out (issue 50 probe: a hold written another way was acknowledged, and the
  // couch kept moving): refused, as a drive refuses what it does not implement.
  const bool read = function == MODBUS_FC_READ_HOLDING_REGISTERS || function == MODBUS_FC_READ_INPUT_REGISTERS;
  const bool block = function == MODBUS_FC_WRITE_MULTIPLE_REGISTERS && address == reg::kTarget &&
                     count == reg::kHoldingCount;
  const bool control_word = function == MODBUS_FC_WRITE_SINGLE_REGISTER && address == reg::kControl;
  if (!read && !block && !control_word) {
    const bool a_write = function == MODBUS_FC_WRITE_SINGLE_REGISTER || function == MODBUS_FC_WRITE_MULTIPLE_REGISTERS ||
                         function == MODBUS_FC_WRITE_SINGLE_COIL || function == MODBUS_FC_WRITE_MULTIPLE_COILS ||
                         function == MODBUS_FC_MASK_WRITE_REGISTER || function == MODBUS_FC_WRITE_AND_READ_REGISTERS;
    ++malformed_;
    modbus_reply_exception(ctx_, query,
                           a_write ? MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS : MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
    return;
  }
  bool mismatch = false, late = false;
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
    case CouchServerFault::kLateReply:
      late = true;
      break;
  }
  if (block) {
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
      commanded_ = true;
    } else if (holding[reg::kControl] == reg::kHold) {
      hold_where_it_is();
      commanded_ = true;
    } else {
      // A control word that is neither enable nor hold is refused as a real drive refuses it
      // (exception 3), never echoed as if it were done.
      modbus_reply_exception(ctx_, query, reg::kExceptionIllegalValue);
      return;
    }
  } else if (control_word) {
    const int value = (query[h + 3] << 8) | query[h + 4];
    if (value != reg::kHold && value != reg::kEnable) {
      modbus_reply_exception(ctx_, query, reg::kExceptionIllegalValue);
      return;
    }
    if (value == reg::kHold) hold_where_it_is();
    commanded_ = true;
  }
  refresh_inputs(mismatch);
  if (late) std::this_thread::sleep_for(std::chrono::duration<double>(options_.late_reply_s));
  modbus_reply(ctx_, query, length, map_);
}

}  // namespace lftrack::sim

#pragma once
// The treatment couch over Modbus (libmodbus, TCP or RTU), register map in couch_register_map.hpp.
//
// Cycle calls bound every request by the earlier of the cycle's deadline and the configured
// response timeout, and turn every failure into a status:
//   timeout                        -> kTimeout
//   exception reply, bad reply     -> kFault (wrong unit id, wrong transaction, bad length or CRC)
// libmodbus 3.1.6 does not check a TCP reply's unit id (its RTU backend checks the address and
// CRC), so over TCP the driver frames each request itself (its own transaction id), lets
// libmodbus receive the reply, and checks transaction, protocol, unit, function and length.
//   connection lost or refused     -> kDisconnected
// After a lost connection, cycle calls return kDisconnected at once and never touch the socket:
// a reconnect thread (an ordinary, non-real-time thread) reconnects outside the cycle, puts the
// couch on hold first, and only then hands the connection back. A reconnected couch therefore
// stays held until the loop's next command, which only an operator resume can lead to.
//
// Commands are absolute targets (the last commanded target plus the correction), so a retried
// write cannot move the couch twice. After hold() or a reconnection, the driver takes the
// couch's accepted target from the next read-back as the base for the next correction.

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <string>
#include <thread>

#include "lftrack/drivers/actuator.hpp"

typedef struct _modbus modbus_t;  // libmodbus's opaque context (modbus.h)

namespace lftrack::drivers {

struct ModbusCouchOptions {
  enum class Transport { kTcp, kRtu };
  Transport transport = Transport::kTcp;
  std::string host = "127.0.0.1";  // TCP
  int port = 502;
  std::string serial_device;  // RTU: e.g. /dev/ttyUSB0
  int baud = 115200;
  char parity = 'E';
  int data_bits = 8, stop_bits = 1;
  int unit_id = 1;
  double response_timeout_s = 0.02;   // per request, at most; the cycle's deadline may cut it
  double reconnect_interval_s = 0.2;  // between reconnection attempts
};

// What went wrong so far, for the summary and the tests (read from any thread).
struct ModbusCouchCounters {
  std::int64_t requests = 0, timeouts = 0, exceptions = 0, bad_replies = 0, disconnects = 0, reconnects = 0;
  int last_exception = 0;  // Modbus exception code of the last exception reply
};

class ModbusCouch final : public Actuator {
 public:
  explicit ModbusCouch(ModbusCouchOptions options);
  ~ModbusCouch() override;
  ModbusCouch(const ModbusCouch&) = delete;
  ModbusCouch& operator=(const ModbusCouch&) = delete;

  // Outside the cycle: connects, reads the couch's accepted target as the base for corrections,
  // and starts the reconnect thread. Fails with a message naming the endpoint.
  Status open() override;
  DeviceStatus command(const tracking::Vector6d& correction, Deadline deadline) override;
  DeviceStatus readback(ActuatorState* state, Deadline deadline) override;
  void hold() override;  // bounded by the response timeout; sent on reconnection if disconnected
  void close() override;

  bool connected() const { return connected_.load(std::memory_order_acquire); }
  ModbusCouchCounters counters() const;
  std::string endpoint() const;

 private:
  // One request's outcome from errno after a failed libmodbus call.
  DeviceStatus classify_failure(int error);
  // The three requests of the register map, over either transport.
  DeviceStatus write_holding(const std::uint16_t* registers);  // kHoldingCount from kTarget
  DeviceStatus write_control(std::uint16_t value);
  DeviceStatus read_inputs(std::uint16_t* registers);  // kInputCount from kStatus
  // TCP: sends `pdu` (function code first) and receives a reply of `expected_pdu_length` bytes
  // (function code first) into `reply_pdu`.
  DeviceStatus tcp_transact(const std::uint8_t* pdu, int pdu_length, std::uint8_t* reply_pdu,
                            int expected_pdu_length);
  // Sets the response timeout for a request due by `deadline`; false (send nothing) when no time
  // is left, or when an RTU line is not yet quiet after a timeout (drain_line; `drain` false: a
  // hold, which goes out at once after a flush and leaves the draining to the next request).
  bool set_timeout(Deadline deadline, bool drain = true);
  bool set_response_timeout(Deadline deadline);
  std::chrono::steady_clock::duration response_timeout() const;  // options_.response_timeout_s
  // RTU after a timeout or a bad reply: discards what arrives until the line has been silent for a
  // response timeout (line_quiet_at_), waiting no later than `deadline`; true once it is quiet. A
  // read-back's reply has no transaction id on a serial line, and a late one has exactly the shape
  // of the next: without this, one late reply would answer every later request a cycle stale.
  // Limit: a reply later than its timeout plus one more response timeout can still answer the
  // next request (the loop's read-back check then sees the stale target after a command). False
  // also for a line in error or hung up.
  bool drain_line(Deadline deadline);
  void reconnect_thread();
  void mark_disconnected();

  ModbusCouchOptions options_;
  modbus_t* ctx_ = nullptr;
  // The cycle thread uses ctx_ only while connected_; the reconnect thread only while not.
  std::atomic<bool> connected_{false};
  std::atomic<bool> stopping_{false};
  std::thread reconnector_;
  std::mutex wake_mutex_;
  std::condition_variable wake_;

  tracking::Vector6d commanded_ = tracking::Vector6d::Zero();  // last target sent (travel)
  std::atomic<bool> resync_{true};  // take commanded_ from the next read-back's accepted target
  std::uint16_t sequence_ = 0;
  std::uint16_t transaction_ = 0;   // TCP transaction id of the last request
  bool flush_before_next_ = false;  // a late reply may be waiting after a timeout
  std::chrono::steady_clock::time_point line_quiet_at_{};  // RTU: silent from then on, if nothing arrives

  std::atomic<std::int64_t> requests_{0}, timeouts_{0}, exceptions_{0}, bad_replies_{0}, disconnects_{0},
      reconnects_{0};
  std::atomic<int> last_exception_{0};
};

}  // namespace lftrack::drivers

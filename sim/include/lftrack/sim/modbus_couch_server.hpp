#pragma once
// The virtual couch as a real Modbus TCP server (libmodbus) on 127.0.0.1, for protocol tests and
// hardware-in-the-loop runs: the couch driver (drivers/modbus_couch.hpp) talks to it exactly as
// it would to a treatment couch, with the register map of drivers/couch_register_map.hpp.
//
// The server fronts a device (an Actuator with the couch's dynamics: VirtualCouch, or the
// simulated room's couch) and calls it from its own thread; the device must therefore be either
// used by nobody else or safe to share (SimulatedRoom locks).
//
// Over TCP it serves several clients at once, as a couch controller serves a monitoring client
// beside the one that commands it: each request is answered on its own connection, in the order
// requests complete, and no client waits for another (a request is read as its bytes arrive,
// never by waiting on one connection). A connection that completes no request for
// idle_timeout_s is closed; one beyond max_connections closes, of the connections older than a
// second, the one that asks least often, never the one that sent the last command the couch
// acted on, else it is turned away: the loop's connection (it asks every period and commands) is
// never pushed out by a flood of new ones, and connections that ask less often than a loop cannot
// keep one out; one whose bytes
// are not Modbus TCP (protocol id not 0, a length outside 2..254) is closed. A request is checked
// before it touches the couch: a PDU shorter or longer than its function says, or a write whose
// byte count is not twice its register count, is answered with exception 3 (illegal data value)
// and moves nothing; one for another unit (TCP: not unit_id or 0xFF) with exception 11 (gateway
// target failed to respond), over RTU not at all; a broadcast (unit 0) is never answered. The
// couch acts on two writes only, the whole block (function 16 from the target, 14 registers) and
// the control word alone (function 6); every other write is refused with exception 2, never
// acknowledged and left undone.
//
// Faults are injected for the next N requests: no reply at all, exception 4 (device failure) or
// 6 (busy), a reply with the wrong unit id, a dropped connection, a read-back that disagrees
// with the command (position and accepted target offset by `mismatch_mm` on x).

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>

#include "lftrack/drivers/actuator.hpp"
#include "lftrack/tracking/status.hpp"

typedef struct _modbus modbus_t;
typedef struct _modbus_mapping_t modbus_mapping_t;

namespace lftrack::sim {

enum class CouchServerFault : int {
  kNone,
  kNoReply,
  kException4,
  kException6,
  kWrongUnit,
  kDropConnection,
  kReadbackMismatch,
  kLateReply,  // the reply (the state when the request came) goes out late_reply_s later
};

// Which requests an injected fault meets.
enum class CouchRequestKind : int { kAny, kReadback, kCommand };

struct ModbusCouchServerOptions {
  std::string address = "127.0.0.1";  // TCP: the address to listen on (0.0.0.0: every interface)
  int port = 0;  // 0: any free port (port() says which)
  // Non-empty: serve Modbus RTU on this serial device (a tty, or a pty in tests) instead of TCP.
  std::string rtu_device;
  int unit_id = 1;
  double mismatch_mm = 2.0;
  double late_reply_s = 0.3;  // kLateReply: how late; the server answers nothing else meanwhile
  int max_connections = 4;     // TCP: clients served at once, 1 to 64
  double idle_timeout_s = 30;  // TCP: a connection without a request for this long is closed; (0, 3600]
};

class ModbusCouchServer {
 public:
  // `couch` must outlive the server.
  static Result<std::unique_ptr<ModbusCouchServer>> start(drivers::Actuator* couch,
                                                          const ModbusCouchServerOptions& options = {});
  ~ModbusCouchServer();
  ModbusCouchServer(const ModbusCouchServer&) = delete;
  ModbusCouchServer& operator=(const ModbusCouchServer&) = delete;

  int port() const { return port_; }
  // The next `requests` requests of `kind` meet `fault` (replacing any fault still pending).
  void inject(CouchServerFault fault, int requests = 1, CouchRequestKind kind = CouchRequestKind::kAny);
  std::int64_t requests() const { return requests_.load(); }
  std::int64_t connections() const { return connections_.load(); }  // TCP connections accepted
  std::int64_t idle_closed() const { return idle_closed_.load(); }  // closed for idling or for a newer one
  std::int64_t turned_away() const { return turned_away_.load(); }  // connections refused: every slot busy
  std::int64_t malformed() const { return malformed_.load(); }      // requests refused before the couch

 private:
  ModbusCouchServer(drivers::Actuator* couch, const ModbusCouchServerOptions& options);
  void serve();  // TCP
  void serve_rtu();
  void handle(std::uint8_t* query, int length);
  CouchServerFault take_fault(CouchRequestKind kind);
  void refresh_inputs(bool mismatch);
  void hold_where_it_is();  // the control word kHold: stop, and take the position as the accepted target

  drivers::Actuator* couch_;
  ModbusCouchServerOptions options_;
  modbus_t* ctx_ = nullptr;
  modbus_mapping_t* map_ = nullptr;
  int listen_fd_ = -1;
  int port_ = 0;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<int> fault_{0}, fault_requests_{0}, fault_kind_{0};
  std::atomic<std::int64_t> requests_{0}, connections_{0}, idle_closed_{0}, turned_away_{0}, malformed_{0};
  bool commanded_ = false;  // the request handle() just answered was a command the couch acted on
  tracking::Vector6d accepted_target_ = tracking::Vector6d::Zero();
  std::uint16_t acknowledged_ = 0;
  std::uint16_t fault_word_ = 0;
  bool holding_ = false;
};

}  // namespace lftrack::sim

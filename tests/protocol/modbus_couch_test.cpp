// The couch driver against the virtual couch served by libmodbus on loopback (TCP) and over a
// pseudo-terminal null modem (RTU): the register map, dynamics through the protocol, every
// Modbus fault of the catalogue (docs/faults.md), and clients that connect and go silent.

#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <poll.h>
#include <pty.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/drivers/couch_register_map.hpp"
#include "lftrack/drivers/modbus_couch.hpp"
#include "lftrack/sim/modbus_couch_server.hpp"
#include "lftrack/sim/null_modem.hpp"
#include "lftrack/sim/virtual_couch.hpp"
#include "protocol_test_support.hpp"

namespace lftrack {
namespace {

using drivers::ActuatorState;
using drivers::DeviceStatus;
using drivers::ModbusCouch;
using sim::CouchServerFault;
using tracking::Vector6d;
using Clock = std::chrono::steady_clock;

using test::in_ms;
using test::LockedCouch;
using test::shift;

class ModbusCouchTest : public ::testing::Test {
 protected:
  void SetUp() override {
    sim::VirtualCouchSpec spec;
    spec.latency_s = 0.1;
    spec.max_speed_mm_s = 10;
    spec.range_mm = 20;
    couch = std::make_unique<LockedCouch>(spec);
    auto s = sim::ModbusCouchServer::start(couch.get());
    ASSERT_TRUE(s.ok()) << s.status().message();
    server = std::move(s).value();
    open_driver(0.05);
  }
  // The driver under test, against this server, replacing any before it.
  void open_driver(double response_timeout_s) {
    if (driver) driver->close();
    drivers::ModbusCouchOptions o;
    o.port = server->port();
    o.response_timeout_s = response_timeout_s;
    o.reconnect_interval_s = 0.05;
    driver = std::make_unique<ModbusCouch>(o);
    ASSERT_TRUE(driver->open().ok());
  }
  void TearDown() override {
    if (driver) driver->close();
    server.reset();
  }

  std::unique_ptr<LockedCouch> couch;
  std::unique_ptr<sim::ModbusCouchServer> server;
  std::unique_ptr<ModbusCouch> driver;
};

TEST(CouchRegisterMap, TravelRoundTripsToTheMicrometreAndRefusesWhatDoesNotFit) {
  Vector6d travel;
  travel << 12.3456, -0.0004, 2000.0, 0.0123456, -1e-7, -3.0;
  std::uint16_t r[12];
  ASSERT_TRUE(drivers::couch_registers::encode_travel(travel, r));
  const Vector6d back = drivers::couch_registers::decode_travel(r);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(back(i), travel(i), 0.5e-3);
  for (int i = 3; i < 6; ++i) EXPECT_NEAR(back(i), travel(i), 0.5e-6);
  Vector6d bad = travel;
  bad(1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(drivers::couch_registers::encode_travel(bad, r));
  bad = travel;
  bad(2) = 3e6;  // 3 km does not fit in 32 bits of micrometres
  EXPECT_FALSE(drivers::couch_registers::encode_travel(bad, r));
}

TEST_F(ModbusCouchTest, CommandsMoveTheCouchWithItsDynamicsAndTheReadBackReportsThem) {
  ASSERT_EQ(driver->command(shift(5, 0.01), in_ms(100)), DeviceStatus::kOk);
  ActuatorState s;
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 5, 1e-3);
  EXPECT_NEAR(s.target(5), 0.01, 1e-6);
  EXPECT_NEAR(s.position(0), 0, 1e-3);  // latency not yet over
  EXPECT_TRUE(s.moving);
  EXPECT_FALSE(s.fault);
  couch->advance_to(0.35);  // 0.25 s of motion at 10 mm/s
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.position(0), 2.5, 1e-3);
  // A second correction is relative to the last target.
  ASSERT_EQ(driver->command(shift(-1), in_ms(100)), DeviceStatus::kOk);
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 4, 1e-3);
  // Hold stops where it is; the next correction starts from there.
  driver->hold();
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 2.5, 1e-3);
  couch->advance_to(2.0);
  EXPECT_NEAR(couch->position()(0), 2.5, 1e-6);
  ASSERT_EQ(driver->command(shift(1), in_ms(100)), DeviceStatus::kOk);
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 3.5, 1e-3);
}

TEST_F(ModbusCouchTest, ATargetOutsideTheRangeIsRefusedWithExceptionThreeAndChangesNothing) {
  EXPECT_EQ(driver->command(shift(25), in_ms(100)), DeviceStatus::kFault);
  EXPECT_EQ(driver->counters().last_exception, 3);
  ActuatorState s;
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 0, 1e-9);
  ASSERT_EQ(driver->command(shift(5), in_ms(100)), DeviceStatus::kOk);
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 5, 1e-3);
}

TEST_F(ModbusCouchTest, NoReplyIsATimeoutWithinTheResponseTimeoutAndTheNextRequestWorks) {
  server->inject(CouchServerFault::kNoReply);
  const auto t0 = Clock::now();
  ActuatorState s;
  EXPECT_EQ(driver->readback(&s, in_ms(1000)), DeviceStatus::kTimeout);
  EXPECT_LT(std::chrono::duration<double>(Clock::now() - t0).count(), 0.5);
  EXPECT_EQ(driver->counters().timeouts, 1);
  EXPECT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
}

TEST_F(ModbusCouchTest, TheCyclesDeadlineCutsTheResponseTimeout) {
  // A response timeout of 2 s, so that a loaded host's scheduling cannot pass for it.
  open_driver(2.0);
  if (HasFatalFailure()) return;
  server->inject(CouchServerFault::kNoReply);
  const std::int64_t at_start = server->requests();
  const auto t0 = Clock::now();
  EXPECT_EQ(driver->command(shift(1), in_ms(5)), DeviceStatus::kTimeout);
  EXPECT_LT(std::chrono::duration<double>(Clock::now() - t0).count(), 1.0) << "cut at the 5 ms deadline";
  // A deadline already past sends nothing. The server counts the request above on its own
  // thread: wait until it has, or a late count would look like a request sent now.
  for (const auto until = Clock::now() + std::chrono::seconds(5); server->requests() == at_start && Clock::now() < until;)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  const std::int64_t before = server->requests();
  ASSERT_GT(before, at_start);
  EXPECT_EQ(driver->command(shift(1), Clock::now()), DeviceStatus::kTimeout);
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_EQ(server->requests(), before);
}

TEST_F(ModbusCouchTest, ExceptionsFourAndSixAreFaultsWithTheirCodes) {
  server->inject(CouchServerFault::kException4);
  EXPECT_EQ(driver->command(shift(1), in_ms(100)), DeviceStatus::kFault);
  EXPECT_EQ(driver->counters().last_exception, 4);
  server->inject(CouchServerFault::kException6);
  ActuatorState s;
  EXPECT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kFault);
  EXPECT_EQ(driver->counters().last_exception, 6);
  EXPECT_EQ(driver->counters().exceptions, 2);
  // The refused command did not move the base.
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 0, 1e-9);
}

TEST_F(ModbusCouchTest, AReplyFromTheWrongUnitIsAFault) {
  server->inject(CouchServerFault::kWrongUnit);
  ActuatorState s;
  EXPECT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kFault);
  EXPECT_EQ(driver->counters().bad_replies, 1);
  EXPECT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
}

TEST_F(ModbusCouchTest, ADroppedConnectionIsReconnectedOutsideTheCycleWithTheCouchHeld) {
  ASSERT_EQ(driver->command(shift(5), in_ms(100)), DeviceStatus::kOk);
  couch->advance_to(0.2);  // moving at 10 mm/s
  server->inject(CouchServerFault::kDropConnection);
  ActuatorState s;
  EXPECT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kDisconnected);
  // Cycle calls now answer at once and send nothing: disconnected, or, where the reconnection
  // outside the cycle has already finished (a loaded host can run it first), refused until a
  // read-back has taken the couch's target as the base. Either way the couch holds (below).
  const auto t0 = Clock::now();
  const DeviceStatus right_after = driver->command(shift(1), in_ms(100));
  EXPECT_TRUE(right_after == DeviceStatus::kDisconnected || right_after == DeviceStatus::kRefused)
      << static_cast<int>(right_after);
  // At once: well inside the 50 ms a request would wait for its reply (a loaded host may preempt).
  EXPECT_LT(std::chrono::duration<double>(Clock::now() - t0).count(), 0.025);
  const auto until = Clock::now() + std::chrono::seconds(5);
  while (!driver->connected() && Clock::now() < until)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  ASSERT_TRUE(driver->connected());
  EXPECT_EQ(driver->counters().reconnects, 1);
  EXPECT_EQ(server->connections(), 2);
  // The reconnected couch was held where it was: it does not resume the old target.
  couch->advance_to(3.0);
  EXPECT_NEAR(couch->position()(0), 1.0, 1e-6);
  // No command before a read-back has taken the couch's target as the base.
  EXPECT_EQ(driver->command(shift(1), in_ms(100)), DeviceStatus::kRefused);
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 1.0, 1e-3);
  ASSERT_EQ(driver->command(shift(1), in_ms(100)), DeviceStatus::kOk);
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 2.0, 1e-3);
}

TEST_F(ModbusCouchTest, AReadBackThatDisagreesWithTheCommandIsReportedAsItIs) {
  ASSERT_EQ(driver->command(shift(3), in_ms(100)), DeviceStatus::kOk);
  server->inject(CouchServerFault::kReadbackMismatch);
  ActuatorState s;
  ASSERT_EQ(driver->readback(&s, in_ms(100)), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 5.0, 1e-3);  // the loop's gate compares it with what it commanded
}

// The served couch as an outside client meets it (raw libmodbus, not our driver): a control word
// that is neither enable nor hold is refused with exception 3 and changes nothing; the whole
// block with hold holds.
TEST_F(ModbusCouchTest, AControlWordThatIsNeitherEnableNorHoldIsRefused) {
  ASSERT_EQ(driver->command(shift(5), in_ms(100)), DeviceStatus::kOk);
  couch->advance_to(0.2);  // 0.1 s of motion at 10 mm/s after the latency: 1 mm
  modbus_t* raw = modbus_new_tcp("127.0.0.1", server->port());
  ASSERT_NE(raw, nullptr);
  ASSERT_EQ(modbus_connect(raw), 0) << modbus_strerror(errno);
  namespace reg = drivers::couch_registers;
  for (const int word : {0, 3, 0xFFFF}) {
    EXPECT_EQ(modbus_write_register(raw, reg::kControl, static_cast<std::uint16_t>(word)), -1) << word;
    EXPECT_EQ(errno, EMBXILVAL) << word << ": " << modbus_strerror(errno);
    std::uint16_t block[reg::kHoldingCount] = {};
    ASSERT_TRUE(reg::encode_travel(shift(-9), block + reg::kTarget));
    block[reg::kCommandSequence] = 77;
    block[reg::kControl] = static_cast<std::uint16_t>(word);
    EXPECT_EQ(modbus_write_registers(raw, reg::kTarget, reg::kHoldingCount, block), -1) << word;
    EXPECT_EQ(errno, EMBXILVAL) << word << ": " << modbus_strerror(errno);
  }
  std::uint16_t inputs[reg::kInputCount] = {};
  ASSERT_EQ(modbus_read_input_registers(raw, 0, reg::kInputCount, inputs), reg::kInputCount);
  EXPECT_NEAR(reg::decode_travel(inputs + reg::kAcceptedTarget)(0), 5, 1e-3) << "nothing refused may move the couch";
  EXPECT_TRUE(inputs[reg::kStatus] & reg::kStatusMoving);
  std::uint16_t block[reg::kHoldingCount] = {};
  ASSERT_TRUE(reg::encode_travel(shift(-9), block + reg::kTarget));
  block[reg::kControl] = reg::kHold;
  EXPECT_EQ(modbus_write_registers(raw, reg::kTarget, reg::kHoldingCount, block), reg::kHoldingCount)
      << modbus_strerror(errno);
  ASSERT_EQ(modbus_read_input_registers(raw, 0, reg::kInputCount, inputs), reg::kInputCount);
  EXPECT_NEAR(reg::decode_travel(inputs + reg::kAcceptedTarget)(0), 1, 1e-3)
      << "held where it was, the block's target ignored";
  EXPECT_TRUE(inputs[reg::kStatus] & reg::kStatusHolding);
  modbus_close(raw);
  modbus_free(raw);
}

// A plain TCP connection to the server that sends only `bytes` (none: silent).
int connect_silently(int port, const std::string& bytes = "") {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(static_cast<std::uint16_t>(port));
  to.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  EXPECT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&to), sizeof to), 0) << std::strerror(errno);
  if (!bytes.empty()) {
    EXPECT_EQ(::send(fd, bytes.data(), bytes.size(), 0), ssize_t(bytes.size()));
  }
  return fd;
}

// Whether the server closed `fd` (end of file) within `seconds`; `meanwhile` runs every 20 ms.
template <class Meanwhile>
bool closed_within(int fd, double seconds, Meanwhile meanwhile) {
  for (const auto until = Clock::now() + std::chrono::duration<double>(seconds); Clock::now() < until;) {
    pollfd p{fd, POLLIN, 0};
    char c;
    if (::poll(&p, 1, 20) > 0 && ::recv(fd, &c, 1, MSG_DONTWAIT) == 0) return true;
    meanwhile();
  }
  return false;
}

// A libmodbus client that answers within `response_timeout_s`.
modbus_t* modbus_client(int port, double response_timeout_s) {
  modbus_t* raw = modbus_new_tcp("127.0.0.1", port);
  EXPECT_NE(raw, nullptr);
  modbus_set_response_timeout(raw, 0, static_cast<std::uint32_t>(response_timeout_s * 1e6));
  EXPECT_EQ(modbus_connect(raw), 0) << modbus_strerror(errno);
  return raw;
}

// A client that connects and sends nothing, and one that sends half a request and stops, keep no
// one out: a real client beside them (the couch driver, and a plain libmodbus client) has every
// reply within its response timeout. (Before, the server served one connection at a time and a
// silent one kept every other client out for as long as it stayed.)
TEST_F(ModbusCouchTest, ASilentClientKeepsNoOtherClientWaiting) {
  driver->close();
  const std::int64_t before = server->connections();  // the fixture's driver
  const int silent = connect_silently(server->port());
  const int half = connect_silently(server->port(), std::string("\x00\x01\x00\x00\x00\x06\x01", 7));
  for (const auto until = Clock::now() + std::chrono::seconds(5);
       server->connections() < before + 2 && Clock::now() < until;)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ASSERT_EQ(server->connections(), before + 2) << "the server has accepted both";
  open_driver(0.2);
  if (HasFatalFailure()) return;
  ActuatorState s;
  EXPECT_EQ(driver->readback(&s, in_ms(500)), DeviceStatus::kOk);
  EXPECT_EQ(driver->command(shift(1), in_ms(500)), DeviceStatus::kOk);
  modbus_t* raw = modbus_client(server->port(), 0.5);
  namespace reg = drivers::couch_registers;
  std::uint16_t inputs[reg::kInputCount] = {};
  EXPECT_EQ(modbus_read_input_registers(raw, 0, reg::kInputCount, inputs), reg::kInputCount)
      << modbus_strerror(errno);
  EXPECT_NEAR(reg::decode_travel(inputs + reg::kAcceptedTarget)(0), 1, 1e-3)
      << "the driver's command, seen by a monitor";
  EXPECT_EQ(driver->readback(&s, in_ms(500)), DeviceStatus::kOk) << "both served, in turn";
  modbus_close(raw);
  modbus_free(raw);
  ::close(silent);
  ::close(half);
}

// A connection that completes no request for idle_timeout_s is closed, a client that keeps asking
// never is, and a connection beyond max_connections closes the one idle longest.
TEST(ModbusCouchServerTcp, ClosesIdleConnectionsAndMakesRoomForANewClient) {
  test::LockedCouch couch(sim::VirtualCouchSpec{});
  sim::ModbusCouchServerOptions so;
  so.idle_timeout_s = 0.3;
  so.max_connections = 3;
  auto server = sim::ModbusCouchServer::start(&couch, so);
  ASSERT_TRUE(server.ok()) << server.status().message();
  const int port = (*server)->port();
  namespace reg = drivers::couch_registers;
  std::uint16_t inputs[reg::kInputCount] = {};
  modbus_t* asking = modbus_client(port, 0.5);
  const int silent = connect_silently(port);
  const int half = connect_silently(port, std::string("\x00\x01\x00", 3));
  int read_backs = 0, answered = 0;
  const auto keep_asking = [&] {
    ++read_backs;
    answered += modbus_read_input_registers(asking, 0, reg::kInputCount, inputs) == reg::kInputCount;
  };
  EXPECT_TRUE(closed_within(silent, 5, keep_asking)) << "the silent connection is closed";
  EXPECT_TRUE(closed_within(half, 5, keep_asking)) << "so is the one that stopped half-way";
  EXPECT_EQ(answered, read_backs) << "the client that kept asking was answered every time";
  EXPECT_GE((*server)->idle_closed(), 2);
  ::close(silent);
  ::close(half);
  modbus_close(asking);
  modbus_free(asking);

  // Three slots, taken by silent connections (long idle timeout): once they have said nothing
  // for their second of grace, a new client displaces the oldest, and is answered.
  so.idle_timeout_s = 60;
  auto full = sim::ModbusCouchServer::start(&couch, so);
  ASSERT_TRUE(full.ok());
  std::vector<int> idle;
  for (int i = 0; i < 3; ++i) {
    idle.push_back(connect_silently((*full)->port()));
    for (const auto until = Clock::now() + std::chrono::seconds(5);
         (*full)->connections() < i + 1 && Clock::now() < until;)
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  ASSERT_EQ((*full)->connections(), 3);
  std::this_thread::sleep_for(std::chrono::milliseconds(1200));  // past the silent ones' grace
  modbus_t* late = modbus_client((*full)->port(), 0.5);
  EXPECT_EQ(modbus_read_input_registers(late, 0, reg::kInputCount, inputs), reg::kInputCount)
      << modbus_strerror(errno);
  EXPECT_TRUE(closed_within(idle[0], 5, [] {})) << "the first, idle longest, made room";
  EXPECT_EQ((*full)->idle_closed(), 1);
  modbus_close(late);
  modbus_free(late);
  for (int fd : idle) ::close(fd);
}

// Issue 50 probe: a flood of new connections pushed the loop's own connection out (the idlest
// was closed for each newcomer, and a client asking every 100 ms was often the idlest). The
// loop's connection (it holds the couch at start, then asks every cycle) is never displaced:
// newcomers beyond the slots are turned away, or displace another connection past its grace.
// (A client that only reads may be displaced by newcomers once it is the only connection past
// its grace: the loop is protected by having commanded, not by how often it asks.)
TEST(ModbusCouchServerTcp, AConnectionFloodNeverPushesOutAClientThatTalks) {
  test::LockedCouch couch(sim::VirtualCouchSpec{});
  sim::ModbusCouchServerOptions so;
  so.max_connections = 2;
  auto server = sim::ModbusCouchServer::start(&couch, so);
  ASSERT_TRUE(server.ok()) << server.status().message();
  namespace reg = drivers::couch_registers;
  std::uint16_t inputs[reg::kInputCount] = {};
  modbus_t* loop = modbus_client((*server)->port(), 0.5);
  // As the loop does at start (the start-up check holds the couch), then reads every cycle.
  ASSERT_EQ(modbus_write_register(loop, reg::kControl, reg::kHold), 1) << modbus_strerror(errno);
  ASSERT_EQ(modbus_read_input_registers(loop, 0, reg::kInputCount, inputs), reg::kInputCount);
  std::vector<int> flood;
  int asked = 0, answered = 0;
  for (int i = 0; i < 40; ++i) {
    flood.push_back(connect_silently((*server)->port()));
    ++asked;
    answered += modbus_read_input_registers(loop, 0, reg::kInputCount, inputs) == reg::kInputCount;
  }
  for (const auto until = Clock::now() + std::chrono::seconds(5);
       (*server)->connections() < 41 && Clock::now() < until;)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ++asked;
  answered += modbus_read_input_registers(loop, 0, reg::kInputCount, inputs) == reg::kInputCount;
  EXPECT_EQ(answered, asked) << "the talking client kept its connection and every answer";
  // One newcomer took the free slot; each of the other 39 was turned away, or (on a host slow
  // enough for the flood to outlast a silent connection's second of grace) displaced a silent one.
  EXPECT_EQ((*server)->turned_away() + (*server)->idle_closed(), 39);
  EXPECT_GE((*server)->turned_away(), 1);
  for (int fd : flood) ::close(fd);
  modbus_close(loop);
  modbus_free(loop);
}

std::vector<std::uint8_t> raw_exchange(int port, const std::vector<std::uint8_t>& request);

// Issue 50, second and third probes: four connections that each asked every 20 s, then every
// 0.5 s, held every slot, and a loop starting (or reconnecting) was turned away. A newcomer takes
// the slot of the connection older than a second that asks least often, never the one that sent
// the last command the couch acted on.
TEST(ModbusCouchServerTcp, ConnectionsThatSpeakNowAndThenCannotKeepTheLoopOut) {
  test::LockedCouch couch(sim::VirtualCouchSpec{});
  sim::ModbusCouchServerOptions so;
  so.max_connections = 2;
  auto server = sim::ModbusCouchServer::start(&couch, so);
  ASSERT_TRUE(server.ok()) << server.status().message();
  namespace reg = drivers::couch_registers;
  std::uint16_t inputs[reg::kInputCount] = {};
  modbus_t* commander = modbus_client((*server)->port(), 0.5);
  ASSERT_EQ(modbus_write_register(commander, reg::kControl, reg::kHold), 1) << modbus_strerror(errno);
  modbus_t* squatter = modbus_client((*server)->port(), 0.5);
  // The squatter asks every 0.2 s (third probe: every 0.5 s still kept the loop out) until both
  // are past their second of grace.
  for (const auto until = Clock::now() + std::chrono::milliseconds(1200); Clock::now() < until;) {
    ASSERT_EQ(modbus_read_input_registers(squatter, 0, reg::kInputCount, inputs), reg::kInputCount);
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  modbus_t* loop = modbus_client((*server)->port(), 0.5);
  EXPECT_EQ(modbus_read_input_registers(loop, 0, reg::kInputCount, inputs), reg::kInputCount)
      << "the newcomer got the squatter's slot: " << modbus_strerror(errno);
  EXPECT_EQ(modbus_write_register(commander, reg::kControl, reg::kHold), 1)
      << "the connection that commanded kept its slot: " << modbus_strerror(errno);
  EXPECT_EQ((*server)->idle_closed(), 1);
  EXPECT_EQ((*server)->turned_away(), 0);
  for (modbus_t* m : {commander, squatter, loop}) {
    modbus_close(m);
    modbus_free(m);
  }
}

// Issue 50, second probe: a read of 0 or 2000 registers went to libmodbus, which sleeps its
// response timeout before answering such a request, on the one thread that serves every client;
// six of them put a running loop into FAULT. Refused at once, with the exception.
TEST(ModbusCouchServerTcp, AnIllegalReadIsRefusedAtOnce) {
  test::LockedCouch couch(sim::VirtualCouchSpec{});
  auto server = sim::ModbusCouchServer::start(&couch, sim::ModbusCouchServerOptions{});
  ASSERT_TRUE(server.ok()) << server.status().message();
  const auto read = [](std::uint8_t function, int address, int count) {
    return std::vector<std::uint8_t>{0, 3, 0, 0, 0, 6, 1, function, std::uint8_t(address >> 8), std::uint8_t(address),
                                     std::uint8_t(count >> 8), std::uint8_t(count)};
  };
  struct Case {
    std::vector<std::uint8_t> request;
    std::uint8_t exception;
  };
  for (const Case& c : {Case{read(0x04, 0, 0), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE},
                        Case{read(0x04, 0, 2000), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE},
                        Case{read(0x03, 0, 126), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE},
                        Case{read(0x04, 20, 10), MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS},
                        Case{read(0x03, 0xFFFF, 1), MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS}}) {
    const auto started = Clock::now();
    const auto reply = raw_exchange((*server)->port(), c.request);
    const double ms = std::chrono::duration<double, std::milli>(Clock::now() - started).count();
    ASSERT_EQ(reply.size(), 9u);
    EXPECT_EQ(reply[7], c.request[7] | 0x80);
    EXPECT_EQ(reply[8], c.exception);
    std::printf("function %d, address %d: exception %d in %.1f ms\n", c.request[7], (c.request[8] << 8) | c.request[9],
                reply[8], ms);
  }
  EXPECT_EQ((*server)->malformed(), 5);
}

// A raw Modbus TCP request on its own connection, and the reply's bytes (empty: none in 2 s).
std::vector<std::uint8_t> raw_exchange(int port, const std::vector<std::uint8_t>& request) {
  const int fd = connect_silently(port, std::string(request.begin(), request.end()));
  std::vector<std::uint8_t> reply(260);
  pollfd p{fd, POLLIN, 0};
  const ssize_t n = ::poll(&p, 1, 2000) > 0 ? ::recv(fd, reply.data(), reply.size(), 0) : 0;
  reply.resize(n > 0 ? std::size_t(n) : 0);
  ::close(fd);
  return reply;
}

// A "write the target and enable" request (function 16 at the target, all 14 registers).
std::vector<std::uint8_t> enable_request(std::uint8_t unit, std::uint8_t byte_count, int registers_sent,
                                         double x_mm) {
  namespace reg = drivers::couch_registers;
  std::uint16_t block[reg::kHoldingCount] = {};
  tracking::Vector6d target = tracking::Vector6d::Zero();
  target(0) = x_mm;
  reg::encode_travel(target, block + reg::kTarget);
  block[reg::kCommandSequence] = 7;
  block[reg::kControl] = reg::kEnable;
  std::vector<std::uint8_t> pdu = {0x10, 0, reg::kTarget, 0, reg::kHoldingCount, byte_count};
  for (int i = 0; i < registers_sent; ++i) {
    pdu.push_back(std::uint8_t(block[i] >> 8));
    pdu.push_back(std::uint8_t(block[i] & 0xFF));
  }
  const std::size_t length = pdu.size() + 1;
  std::vector<std::uint8_t> adu = {0, 1, 0, 0, std::uint8_t(length >> 8), std::uint8_t(length & 0xFF), unit};
  adu.insert(adu.end(), pdu.begin(), pdu.end());
  return adu;
}

// Issue 50 probe: the couch acted on a function-16 write before its byte count was checked, and
// for any unit id. Such a request moves nothing and is answered with Modbus's exception.
TEST(ModbusCouchServerTcp, AMalformedOrMisaddressedWriteMovesNothing) {
  test::LockedCouch couch(sim::VirtualCouchSpec{});
  auto server = sim::ModbusCouchServer::start(&couch, sim::ModbusCouchServerOptions{});
  ASSERT_TRUE(server.ok()) << server.status().message();
  const int port = (*server)->port();
  struct Case {
    const char* what;
    std::vector<std::uint8_t> request;
    std::uint8_t exception;  // 0: no reply expected
  };
  const std::vector<Case> cases = {
      {"byte count 0", enable_request(1, 0, 14, 5), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE},
      {"byte count odd", enable_request(1, 27, 14, 5), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE},
      {"byte count of 15 registers", enable_request(1, 30, 14, 5), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE},
      {"13 registers of 14 sent", enable_request(1, 28, 13, 5), MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE},
      {"15 registers' bytes for 14", enable_request(1, 28, 14, 5), 0xFF},  // patched below
      {"another unit", enable_request(7, 28, 14, 5), MODBUS_EXCEPTION_GATEWAY_TARGET},
      {"unit 0 (a broadcast: no answer)", enable_request(0, 28, 14, 5), 0},
  };
  for (Case c : cases) {
    SCOPED_TRACE(c.what);
    if (c.exception == 0xFF) {  // two bytes more than the byte count says, the MBAP length counting them
      c.request.push_back(0);
      c.request.push_back(1);
      c.request[5] = std::uint8_t(c.request[5] + 2);
      c.exception = MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
    }
    const auto reply = raw_exchange(port, c.request);
    if (c.exception == 0) {
      EXPECT_TRUE(reply.empty());
    } else {
      ASSERT_EQ(reply.size(), 9u) << "an exception reply";
      EXPECT_EQ(reply[7], 0x90) << "function 16's exception";
      EXPECT_EQ(reply[8], c.exception);
    }
    drivers::ActuatorState s;
    ASSERT_EQ(couch.readback(&s, {}), DeviceStatus::kOk);
    EXPECT_LT(s.target.norm(), 1e-9) << "the couch was not moved";
  }
  EXPECT_EQ((*server)->malformed(), std::int64_t(cases.size()));
  // The same write, well formed for this unit (or 0xFF, "this device"), moves the couch.
  const auto reply = raw_exchange(port, enable_request(0xFF, 28, 14, 5));
  ASSERT_EQ(reply.size(), 12u);
  EXPECT_EQ(reply[7], 0x10);
  drivers::ActuatorState s;
  ASSERT_EQ(couch.readback(&s, {}), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 5, 1e-3);

  // Writes the couch does not act on are refused, not acknowledged and ignored (issue 50 probe:
  // a hold written as function 16 of the control word alone, 22 or 23 was answered as done and
  // the couch kept moving): exception 2 (illegal data address).
  namespace reg = drivers::couch_registers;
  const auto adu = [](std::vector<std::uint8_t> pdu) {
    const std::size_t length = pdu.size() + 1;
    std::vector<std::uint8_t> a = {0, 2, 0, 0, std::uint8_t(length >> 8), std::uint8_t(length & 0xFF), 1};
    a.insert(a.end(), pdu.begin(), pdu.end());
    return a;
  };
  const std::uint8_t hold = reg::kHold, control = reg::kControl;
  const std::vector<std::pair<const char*, std::vector<std::uint8_t>>> ignored = {
      {"function 16, the control word alone", adu({0x10, 0, control, 0, 1, 2, 0, hold})},
      {"function 6 at a target register", adu({0x06, 0, 0, 0, 7})},
      {"function 22 (mask write) at the control word", adu({0x16, 0, control, 0, 0, 0, hold})},
      {"function 23 (write and read) at the control word", adu({0x17, 0, 0, 0, 1, 0, control, 0, 1, 2, 0, hold})},
  };
  const std::int64_t malformed_before = (*server)->malformed();
  for (const auto& [what, request] : ignored) {
    SCOPED_TRACE(what);
    const auto r = raw_exchange(port, request);
    ASSERT_EQ(r.size(), 9u) << "an exception reply";
    EXPECT_EQ(r[7], request[7] | 0x80);
    EXPECT_EQ(r[8], MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS);
  }
  EXPECT_EQ((*server)->malformed() - malformed_before, std::int64_t(ignored.size()));
  ASSERT_EQ(couch.readback(&s, {}), DeviceStatus::kOk);
  EXPECT_NEAR(s.target(0), 5, 1e-3) << "none of them changed the couch";
  // The documented hold (function 6 at the control word) holds.
  const auto held = raw_exchange(port, adu({0x06, 0, control, 0, hold}));
  ASSERT_EQ(held.size(), 12u);
  EXPECT_EQ(held[7], 0x06);
}

TEST(ModbusCouch, OpeningWithNothingListeningSaysWhere) {
  drivers::ModbusCouchOptions o;
  o.port = 1;  // privileged and unused
  ModbusCouch driver(o);
  const Status s = driver.open();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.message().find("127.0.0.1:1"), std::string::npos) << s.message();
  EXPECT_EQ(driver.readback(nullptr, in_ms(10)), DeviceStatus::kDisconnected);
}

}  // namespace
}  // namespace lftrack

// Modbus RTU: the same driver and server over a serial line (sim/null_modem.hpp: two
// pseudo-terminals joined like a null-modem cable).
namespace lftrack {
namespace {

using sim::NullModem;

// The couch served over Modbus RTU on one end of a null modem, the driver on the other, the couch
// without latency.
class ModbusCouchRtu : public ::testing::Test {
 protected:
  // Starts the server with `so` (its device set here) and opens the driver with a response
  // timeout of `response_timeout_s`.
  void start(sim::ModbusCouchServerOptions so = {}, double response_timeout_s = 0.2) {
    ASSERT_TRUE(line_.ok()) << "no pseudo-terminals";
    so.rtu_device = line_.end(1);
    auto server = sim::ModbusCouchServer::start(&couch_, so);
    ASSERT_TRUE(server.ok()) << server.status().message();
    server_ = std::move(server).value();
    drivers::ModbusCouchOptions o;
    o.transport = drivers::ModbusCouchOptions::Transport::kRtu;
    o.serial_device = line_.end(0);
    o.response_timeout_s = response_timeout_s;
    driver_ = std::make_unique<ModbusCouch>(o);
    const Status opened = driver_->open();
    ASSERT_TRUE(opened.ok()) << opened.message();
  }
  static sim::VirtualCouchSpec without_latency() {
    sim::VirtualCouchSpec spec;
    spec.latency_s = 0;
    return spec;
  }
  NullModem line_;
  LockedCouch couch_{without_latency()};
  std::unique_ptr<sim::ModbusCouchServer> server_;
  std::unique_ptr<ModbusCouch> driver_;
};

TEST_F(ModbusCouchRtu, CommandsAndReadBackOverASerialLineAndAWrongUnitIsNeverTakenAsTheAnswer) {
  ASSERT_NO_FATAL_FAILURE(start());
  ModbusCouch& driver = *driver_;
  LockedCouch& couch = couch_;
  auto* server = &server_;
  ASSERT_EQ(driver.command(shift(4, 0.02), in_ms(500)), DeviceStatus::kOk);
  couch.advance_to(5.0);
  ActuatorState s;
  ASSERT_EQ(driver.readback(&s, in_ms(500)), DeviceStatus::kOk);
  EXPECT_NEAR(s.position(0), 4, 1e-3);
  EXPECT_NEAR(s.target(5), 0.02, 1e-6);
  // A reply carrying another unit's address is never taken as the couch's answer.
  (*server)->inject(CouchServerFault::kWrongUnit);
  EXPECT_NE(driver.readback(&s, in_ms(500)), DeviceStatus::kOk);
  (*server)->inject(CouchServerFault::kException4);
  EXPECT_EQ(driver.readback(&s, in_ms(500)), DeviceStatus::kFault);
  EXPECT_EQ(driver.counters().last_exception, 4);
  ASSERT_EQ(driver.readback(&s, in_ms(500)), DeviceStatus::kOk);
  driver.close();
}

// A reply that comes after its timeout on a serial line has no transaction id to tell it from the
// next request's: a late read-back reply has exactly its shape. The driver drains the line until
// it is quiet before it asks again, so the late reply never answers a later request (issue 54:
// without the drain, the next read-back took it, a cycle stale, and every later one too).
TEST_F(ModbusCouchRtu, ALateReplyNeverAnswersTheNextRequest) {
  // The reply comes half a timeout after the timeout, and the driver waits for a silence of one
  // timeout: 0.2 s of margin on either side for a loaded host.
  sim::ModbusCouchServerOptions so;
  so.late_reply_s = 0.6;
  ASSERT_NO_FATAL_FAILURE(start(so, /*response_timeout_s=*/0.4));
  ModbusCouch& driver = *driver_;
  LockedCouch& couch = couch_;
  auto* server = &server_;
  ASSERT_EQ(driver.command(shift(4, 0), in_ms(500)), DeviceStatus::kOk);
  ActuatorState s;
  ASSERT_EQ(driver.readback(&s, in_ms(500)), DeviceStatus::kOk);
  ASSERT_LT(s.position(0), 1.0) << "the couch has not moved yet";
  // The late reply carries the couch where it was; then the couch arrives.
  (*server)->inject(CouchServerFault::kLateReply, 1, sim::CouchRequestKind::kReadback);
  EXPECT_EQ(driver.readback(&s, in_ms(1000)), DeviceStatus::kTimeout);
  couch.advance_to(5.0);
  // Each read-back now says where the couch is, never the late reply's old position. A read-back
  // may find the line not yet quiet (kTimeout, nothing sent); the deadline is generous.
  for (int i = 0; i < 3; ++i) {
    DeviceStatus status = DeviceStatus::kTimeout;
    for (int tries = 0; tries < 20 && status == DeviceStatus::kTimeout; ++tries)
      status = driver.readback(&s, in_ms(1000));
    ASSERT_EQ(status, DeviceStatus::kOk) << "read-back " << i;
    EXPECT_NEAR(s.position(0), 4, 1e-3) << "read-back " << i << " was answered by the late reply";
  }
  EXPECT_EQ(driver.counters().timeouts, 1);
  driver.close();
}

}  // namespace
}  // namespace lftrack

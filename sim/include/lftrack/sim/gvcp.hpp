#pragma once
// GigE Vision's control protocol (GVCP) as a camera checks it, and the stream packets (GVSP) a
// camera sends: the wire format of the fake GigE cameras (sim/gige_fake_detector.hpp), free of
// sockets so that every check runs in a test.
//
// A camera never trusts a datagram. check_command() sorts each one:
// - dropped, unanswered: not a well-formed command (shorter than the 8-byte header, a key other
//   than 0x42, a length field that is not a multiple of 4 or exceeds what arrived, a payload
//   shorter than the command needs) or one that has no answer (PACKETRESEND: these cameras do
//   not resend);
// - refused with an error status: a well-formed command the camera cannot carry out (an unknown
//   command; a read or write outside the memory map or not 4-byte aligned; more than 536 bytes);
// - answered: everything it touches lies inside the memory map.
// So no request, whatever its length fields say, makes the camera read or write outside its
// memory. Big-endian on the wire, as GigE Vision is.

#include <cstddef>
#include <cstdint>

namespace lftrack::sim::gvcp {

constexpr std::uint16_t kPort = 3956;
constexpr std::size_t kHeaderBytes = 8;
constexpr std::uint8_t kKey = 0x42;  // the first byte of every command
constexpr std::uint8_t kFlagAckRequired = 0x01;
constexpr std::size_t kMaxDataBytes = 536;       // a command's or an acknowledge's payload at most
constexpr std::uint32_t kDiscoveryBytes = 0xF8;  // the bootstrap registers a discovery answer carries

enum class Command : std::uint16_t {
  kDiscovery = 0x0002,
  kPacketResend = 0x0040,
  kReadRegister = 0x0080,
  kWriteRegister = 0x0082,
  kReadMemory = 0x0084,
  kWriteMemory = 0x0086,
};

// GigE Vision status codes of an acknowledge.
enum class Status : std::uint16_t {
  kSuccess = 0x0000,
  kNotImplemented = 0x8001,
  kInvalidParameter = 0x8002,
  kInvalidAddress = 0x8003,
  kWriteProtect = 0x8004,
  kBadAlignment = 0x8005,
  kAccessDenied = 0x8006,
};

// The camera's memory: bytes [0, readable_bytes) may be read, [0, writable_bytes) written.
struct MemoryMap {
  std::uint32_t readable_bytes = 0;
  std::uint32_t writable_bytes = 0;
};

enum class Verdict { kAnswer, kRefuse, kDrop };

// One datagram, checked. For kAnswer, `payload` (inside the datagram, `length` bytes) holds what
// the command carries: register addresses (read register), address and value pairs (write
// register), or the block's address followed by its data (write memory); `address` and `count`
// are the block of a read or write memory. For kRefuse, `command` and `id` address the error
// acknowledge. `reason` says why a datagram was refused or dropped.
struct Checked {
  Verdict verdict = Verdict::kDrop;
  Status status = Status::kSuccess;
  Command command = Command::kDiscovery;
  std::uint16_t id = 0;
  bool ack_required = false;
  const std::uint8_t* payload = nullptr;
  std::size_t length = 0;
  std::uint32_t address = 0, count = 0;
  const char* reason = "";
};

Checked check_command(const std::uint8_t* datagram, std::size_t size, const MemoryMap& map);

std::uint32_t read_be32(const std::uint8_t* p);
void write_be32(std::uint8_t* p, std::uint32_t v);

// An acknowledge's header (8 bytes at `out`): `status`, the command's acknowledge code (its own
// + 1), `length` bytes of payload to follow, the command's id. Returns 8.
std::size_t write_ack_header(std::uint8_t* out, Status status, Command command, std::uint16_t length,
                             std::uint16_t id);

// GVSP packets of one image frame, standard ids (a 16-bit frame id, a 24-bit packet id: 0 the
// leader, 1..n the payload, n + 1 the trailer); each returns its size in bytes at `out`.
constexpr std::size_t kGvspHeaderBytes = 8;
constexpr std::size_t kGvspLeaderBytes = kGvspHeaderBytes + 36;
constexpr std::size_t kGvspTrailerBytes = kGvspHeaderBytes + 8;
// What a stream packet adds to its payload on the wire: IP (20) and UDP (8) headers and the GVSP
// header; a stream channel's packet size counts them.
constexpr std::size_t kGvspOverheadBytes = 20 + 8 + kGvspHeaderBytes;
struct ImageLeader {
  std::uint64_t timestamp_ns = 0;
  std::uint32_t pixel_format = 0, width = 0, height = 0, x = 0, y = 0;
};
std::size_t write_gvsp_leader(std::uint8_t* out, std::uint16_t frame_id, const ImageLeader& image);
std::size_t write_gvsp_payload(std::uint8_t* out, std::uint16_t frame_id, std::uint32_t packet_id,
                               const std::uint8_t* data, std::size_t bytes);
std::size_t write_gvsp_trailer(std::uint8_t* out, std::uint16_t frame_id, std::uint32_t packet_id);

}  // namespace lftrack::sim::gvcp

#include "lftrack/sim/gvcp.hpp"

#include <cstring>

namespace lftrack::sim::gvcp {

namespace {

std::uint16_t read_be16(const std::uint8_t* p) {
  return std::uint16_t((p[0] << 8) | p[1]);
}

void write_be16(std::uint8_t* p, std::uint16_t v) {
  p[0] = std::uint8_t(v >> 8);
  p[1] = std::uint8_t(v);
}

// Where a register or block of `bytes` at `address` may not be accessed: kSuccess if it may.
Status place(std::uint32_t address, std::uint64_t bytes, std::uint32_t limit, std::uint32_t readable) {
  if (address % 4 != 0) return Status::kBadAlignment;
  if (std::uint64_t(address) + bytes <= limit) return Status::kSuccess;
  return std::uint64_t(address) + bytes <= readable ? Status::kWriteProtect : Status::kInvalidAddress;
}

}  // namespace

std::uint32_t read_be32(const std::uint8_t* p) {
  return (std::uint32_t(p[0]) << 24) | (std::uint32_t(p[1]) << 16) | (std::uint32_t(p[2]) << 8) | p[3];
}

void write_be32(std::uint8_t* p, std::uint32_t v) {
  p[0] = std::uint8_t(v >> 24);
  p[1] = std::uint8_t(v >> 16);
  p[2] = std::uint8_t(v >> 8);
  p[3] = std::uint8_t(v);
}

Checked check_command(const std::uint8_t* datagram, std::size_t size, const MemoryMap& map) {
  Checked c;
  const auto drop = [&c](const char* why) {
    c.verdict = Verdict::kDrop;
    c.reason = why;
    return c;
  };
  const auto refuse = [&c](Status status, const char* why) {
    c.verdict = Verdict::kRefuse;
    c.status = status;
    c.reason = why;
    return c;
  };
  if (datagram == nullptr || size < kHeaderBytes) return drop("shorter than the 8-byte GVCP header");
  if (datagram[0] != kKey) return drop("not a command (its key is not 0x42)");
  const std::size_t length = read_be16(datagram + 4);
  if (length % 4 != 0) return drop("its length field is not a multiple of 4");
  if (length > size - kHeaderBytes) return drop("its length field exceeds the datagram");
  c.ack_required = (datagram[1] & kFlagAckRequired) != 0;
  c.command = Command(read_be16(datagram + 2));
  c.id = read_be16(datagram + 6);
  c.payload = datagram + kHeaderBytes;
  c.length = length;
  const std::uint8_t* p = c.payload;
  switch (c.command) {
    case Command::kDiscovery:
      break;
    case Command::kPacketResend:
      return drop("packet resend (these cameras do not resend)");
    case Command::kReadRegister:
      if (length == 0) return drop("a register read without an address");
      if (length > kMaxDataBytes)
        return refuse(Status::kInvalidParameter, "more than 536 bytes of addresses");
      for (std::size_t i = 0; i < length; i += 4)
        if (const Status s = place(read_be32(p + i), 4, map.readable_bytes, map.readable_bytes);
            s != Status::kSuccess)
          return refuse(s, "a register read outside the memory map or not aligned");
      break;
    case Command::kWriteRegister:
      if (length == 0 || length % 8 != 0) return drop("a register write that is not address and value pairs");
      if (length > kMaxDataBytes)
        return refuse(Status::kInvalidParameter, "more than 536 bytes of registers");
      for (std::size_t i = 0; i < length; i += 8)
        if (const Status s = place(read_be32(p + i), 4, map.writable_bytes, map.readable_bytes);
            s != Status::kSuccess)
          return refuse(s, "a register write outside the writable memory or not aligned");
      break;
    case Command::kReadMemory:
      if (length < 8) return drop("a memory read without its address and count");
      c.address = read_be32(p);
      c.count = read_be32(p + 4) & 0xFFFF;  // the upper 16 bits are reserved
      if (c.count == 0 || c.count % 4 != 0 || c.count > kMaxDataBytes)
        return refuse(Status::kInvalidParameter,
                      "a memory read of 0, more than 536 or not a multiple of 4 bytes");
      if (const Status s = place(c.address, c.count, map.readable_bytes, map.readable_bytes);
          s != Status::kSuccess)
        return refuse(s, "a memory read outside the memory map or not aligned");
      break;
    case Command::kWriteMemory:
      if (length < 8) return drop("a memory write without its address and data");
      c.address = read_be32(p);
      c.count = std::uint32_t(length - 4);
      if (c.count > kMaxDataBytes)
        return refuse(Status::kInvalidParameter, "a memory write of more than 536 bytes");
      if (const Status s = place(c.address, c.count, map.writable_bytes, map.readable_bytes);
          s != Status::kSuccess)
        return refuse(s, "a memory write outside the writable memory or not aligned");
      break;
    default:
      return refuse(Status::kNotImplemented, "an unknown command");
  }
  c.verdict = Verdict::kAnswer;
  return c;
}

std::size_t write_ack_header(std::uint8_t* out, Status status, Command command, std::uint16_t length,
                             std::uint16_t id) {
  write_be16(out, std::uint16_t(status));
  write_be16(out + 2, std::uint16_t(std::uint16_t(command) + 1));
  write_be16(out + 4, length);
  write_be16(out + 6, id);
  return kHeaderBytes;
}

namespace {

// The 8-byte GVSP header: status 0, the frame id, then the content type (1 leader, 2 trailer,
// 3 payload) in the top byte of the packet id's word.
void write_gvsp_header(std::uint8_t* out, std::uint16_t frame_id, std::uint8_t content,
                       std::uint32_t packet_id) {
  write_be16(out, 0);
  write_be16(out + 2, frame_id);
  write_be32(out + 4, (std::uint32_t(content) << 24) | (packet_id & 0x00FFFFFF));
}

}  // namespace

std::size_t write_gvsp_leader(std::uint8_t* out, std::uint16_t frame_id, const ImageLeader& image) {
  write_gvsp_header(out, frame_id, 1, 0);
  std::uint8_t* p = out + kGvspHeaderBytes;
  write_be16(p, 0);      // flags
  write_be16(p + 2, 1);  // payload type: image
  write_be32(p + 4, std::uint32_t(image.timestamp_ns >> 32));
  write_be32(p + 8, std::uint32_t(image.timestamp_ns));
  write_be32(p + 12, image.pixel_format);
  write_be32(p + 16, image.width);
  write_be32(p + 20, image.height);
  write_be32(p + 24, image.x);
  write_be32(p + 28, image.y);
  write_be32(p + 32, 0);  // x and y padding
  return kGvspLeaderBytes;
}

std::size_t write_gvsp_payload(std::uint8_t* out, std::uint16_t frame_id, std::uint32_t packet_id,
                               const std::uint8_t* data, std::size_t bytes) {
  write_gvsp_header(out, frame_id, 3, packet_id);
  std::memcpy(out + kGvspHeaderBytes, data, bytes);
  return kGvspHeaderBytes + bytes;
}

std::size_t write_gvsp_trailer(std::uint8_t* out, std::uint16_t frame_id, std::uint32_t packet_id) {
  write_gvsp_header(out, frame_id, 2, packet_id);
  write_be32(out + kGvspHeaderBytes, 1);  // payload type: image
  write_be32(out + kGvspHeaderBytes + 4, 0);
  return kGvspTrailerBytes;
}

}  // namespace lftrack::sim::gvcp

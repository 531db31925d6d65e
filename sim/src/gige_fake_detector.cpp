#include "lftrack/sim/gige_fake_detector.hpp"

#include <arpa/inet.h>
#include <arv.h>
#include <ifaddrs.h>
#include <net/if.h>
#include <netinet/in.h>
#include <poll.h>
#include <stdlib.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <thread>

#include "lftrack/sim/gvcp.hpp"

namespace lftrack::sim {

namespace {

// Aravis's bootstrap registers (GigE Vision) that the camera itself reads; the rest of its
// memory is Aravis's register model's (arvfakecamera.h).
constexpr std::uint32_t kControlChannelPrivilege = 0x0A00;
constexpr std::uint32_t kHeartbeatTimeoutMs = 0x0938;
constexpr std::uint32_t kStreamPort = 0x0D00;
constexpr std::uint32_t kStreamPacketSize = 0x0D04;
constexpr std::uint32_t kStreamAddress = 0x0D18;
// The camera's clock: tick frequency (read-only), control (bit 1 latches, bit 0 resets to 0) and
// the latched value, high word first.
constexpr std::uint32_t kTimestampControl = 0x0944;
constexpr std::uint32_t kTimestampValueHigh = 0x0948, kTimestampValueLow = 0x094C;

struct InterfaceUp {
  std::string name, address, broadcast;  // broadcast: empty where the interface has none
};

// Every interface that is up with an IPv4 address.
std::vector<InterfaceUp> interfaces_up() {
  std::vector<InterfaceUp> out;
  ifaddrs* list = nullptr;
  if (getifaddrs(&list) != 0) return out;
  const auto text = [](const sockaddr* a) {
    char t[INET_ADDRSTRLEN] = {};
    const auto* in = reinterpret_cast<const sockaddr_in*>(a);
    return a != nullptr && a->sa_family == AF_INET &&
                   inet_ntop(AF_INET, &in->sin_addr, t, sizeof t) != nullptr
               ? std::string(t)
               : std::string();
  };
  for (ifaddrs* i = list; i != nullptr; i = i->ifa_next) {
    if (i->ifa_addr == nullptr || i->ifa_addr->sa_family != AF_INET || (i->ifa_flags & IFF_UP) == 0) continue;
    const bool broadcast = (i->ifa_flags & IFF_BROADCAST) != 0;
    out.push_back({i->ifa_name, text(i->ifa_addr), broadcast ? text(i->ifa_broadaddr) : std::string()});
  }
  freeifaddrs(list);
  return out;
}

// Aravis's GenICam description of its fake camera without the Mono16 entry, in a file of its own
// (the register model reads it once, when made); empty where that cannot be done.
std::string write_mono8_description() {
  ArvFakeCamera* plain = arv_fake_camera_new("LFTRACK-XML");
  if (plain == nullptr) return {};
  std::size_t size = 0;
  const char* xml = arv_fake_camera_get_genicam_xml(plain, &size);
  std::string text = xml != nullptr ? std::string(xml, size) : std::string();
  g_object_unref(plain);
  const std::string entry = "<EnumEntry Name=\"Mono16\"";
  const std::size_t from = text.find(entry);
  const std::size_t to = from == std::string::npos ? from : text.find("</EnumEntry>", from);
  if (to == std::string::npos) return {};
  text.erase(from, to + std::strlen("</EnumEntry>") - from);
  char path[] = "/tmp/lftrack-fake-gige-XXXXXX.xml";
  const int fd = mkstemps(path, 4);
  if (fd < 0) return {};
  const bool written = write(fd, text.data(), text.size()) == ssize_t(text.size());
  ::close(fd);
  if (!written) {
    std::remove(path);
    return {};
  }
  return path;
}

sockaddr_in ipv4(const std::string& address, std::uint16_t port) {
  sockaddr_in in{};
  in.sin_family = AF_INET;
  in.sin_port = htons(port);
  if (inet_pton(AF_INET, address.c_str(), &in.sin_addr) != 1) in.sin_family = AF_UNSPEC;
  return in;
}

// A UDP socket bound to `at`; -1 with errno where it cannot be.
int bound_udp(const sockaddr_in& at, bool shared) {
  const int fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return -1;
  const int on = 1;
  if (shared) {  // as other cameras bind the broadcast address: every one receives each broadcast
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &on, sizeof on);
    setsockopt(fd, SOL_SOCKET, SO_REUSEPORT, &on, sizeof on);
  }
  if (bind(fd, reinterpret_cast<const sockaddr*>(&at), sizeof at) != 0) {
    const int e = errno;
    ::close(fd);
    errno = e;
    return -1;
  }
  return fd;
}

std::int64_t now_us() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

}  // namespace

// The camera's sockets and thread over Aravis's register model. Everything below run() is the
// camera's thread only.
struct GigeFakeDetector::Server {
  GigeFakeDetector* owner = nullptr;
  ArvFakeCamera* camera = nullptr;
  gvcp::MemoryMap map;
  int control_fd = -1, global_discovery_fd = -1, subnet_discovery_fd = -1, stream_fd = -1, wake_fd = -1;
  std::thread thread;
  std::atomic<bool> cancel{false};
  bool have_controller = false;
  sockaddr_in controller{};
  std::int64_t controller_heard_us = 0;
  std::int64_t clock_zero_ns = 0;  // CLOCK_REALTIME (ns) at the last reset of the camera's clock
  std::size_t image_bytes = 0;  // the stream's frame buffer

  ~Server() {
    if (thread.joinable()) {
      cancel.store(true);
      const std::uint64_t one = 1;
      (void)!::write(wake_fd, &one, sizeof one);
      thread.join();
    }
    for (int fd : {control_fd, global_discovery_fd, subnet_discovery_fd, stream_fd, wake_fd})
      if (fd >= 0) ::close(fd);
    if (camera != nullptr) g_object_unref(camera);
  }

  std::uint32_t read_register(std::uint32_t address) const {
    guint32 value = 0;
    arv_fake_camera_read_register(camera, address, &value);
    return value;
  }

  // Aravis's fill-pattern callback (ArvFakeCameraFillPattern), from arv_fake_camera_fill_buffer.
  static void fill(ArvBuffer* buffer, void* self, guint32 /*exposure_us*/, guint32 /*gain*/,
                   ArvPixelFormat format) {
    auto* s = static_cast<Server*>(self);
    s->owner->serve(const_cast<void*>(arv_buffer_get_data(buffer, nullptr)), s->image_bytes,
                    arv_buffer_get_image_width(buffer), arv_buffer_get_image_height(buffer),
                    arv_buffer_get_image_x(buffer), arv_buffer_get_image_y(buffer), std::uint32_t(format));
  }

  // The bytes of the image the registers describe, or 0 where the panel cannot give it.
  std::size_t image_size(std::uint32_t width, std::uint32_t height, std::uint32_t x, std::uint32_t y,
                         std::uint32_t format) const {
    const std::uint64_t bits = ARV_PIXEL_FORMAT_BIT_PER_PIXEL(format);
    if (width == 0 || height == 0 || std::uint64_t(x) + width > std::uint64_t(owner->options_.cols) ||
        std::uint64_t(y) + height > std::uint64_t(owner->options_.rows) ||
        (bits != 8 && bits != 16 && bits != 24))
      return 0;
    return std::size_t(std::uint64_t(width) * height * (bits / 8));
  }

  // Registers whose values the camera's own schedule depends on, and the values it accepts, as a
  // panel's firmware bounds them (issue 50 probe: a frame period of 0 or a heartbeat timeout of
  // 0xFFFFFFFF was taken as written: a frame loop with no period, a controller never expired).
  struct Bounded {
    std::uint32_t address, low, high;
  };
  static constexpr Bounded kBounded[] = {
      {ARV_FAKE_CAMERA_REGISTER_ACQUISITION_FRAME_PERIOD_US, 1'000, 10'000'000},  // 1 kHz to 0.1 Hz
      {kHeartbeatTimeoutMs, 500, 60'000},  // GigE Vision's least, to a minute
      {ARV_FAKE_CAMERA_REGISTER_BINNING_HORIZONTAL, 1, 1},  // the twin reads out every pixel
      {ARV_FAKE_CAMERA_REGISTER_BINNING_VERTICAL, 1, 1},
  };
  // The bootstrap registers a camera only reads out (GigE Vision: version, device mode, MAC and
  // IP, names, serial, the GenICam URLs, capabilities, the timestamp's tick frequency and latched
  // value), [begin, end) in bytes; the user-defined
  // name (0x00E8), Aravis's fake-camera registers (0x0100-0x01FF and its trigger at 0x0300), the
  // heartbeat, control, message and stream channel registers stay writable (issue 50 probe: one
  // write of the first URL left every client unable to read the camera's description).
  struct Range {
    std::uint32_t begin, end;
  };
  static constexpr Range kReadOnly[] = {{0x0000, 0x00E8}, {0x0200, 0x0300}, {0x0400, 0x0900},
                                        {0x0900, 0x0938}, {0x093C, 0x0944}, {0x0948, 0x0950}};
  static bool overlaps(std::uint32_t address, std::uint32_t count, std::uint32_t begin, std::uint32_t end) {
    return std::uint64_t(address) < end && begin < std::uint64_t(address) + count;
  }
  // kSuccess, or why a write of `value` at `address` is refused. The image registers take only
  // what the panel can give (issue 50 probe: width 0 and a pixel format 0xDEADBEEF were
  // acknowledged, and every client was refused the frame size until a restart): a width and an
  // offset within the sensor's columns, a height and an offset within its rows, Mono8 or Mono16;
  // the sensor's own size is read-only.
  gvcp::Status check_register_write(std::uint32_t address, std::uint32_t value) const {
    for (const Range& r : kReadOnly)
      if (overlaps(address, 4, r.begin, r.end)) return gvcp::Status::kWriteProtect;
    for (const Bounded& b : kBounded)
      if (address == b.address && (value < b.low || value > b.high)) return gvcp::Status::kInvalidParameter;
    const auto cols = std::uint32_t(owner->options_.cols), rows = std::uint32_t(owner->options_.rows);
    const auto within = [](bool ok) { return ok ? gvcp::Status::kSuccess : gvcp::Status::kInvalidParameter; };
    switch (address) {
      case ARV_FAKE_CAMERA_REGISTER_SENSOR_WIDTH:
      case ARV_FAKE_CAMERA_REGISTER_SENSOR_HEIGHT:
        return gvcp::Status::kWriteProtect;
      case ARV_FAKE_CAMERA_REGISTER_WIDTH:
        return within(value >= 1 && value <= cols);
      case ARV_FAKE_CAMERA_REGISTER_HEIGHT:
        return within(value >= 1 && value <= rows);
      case ARV_FAKE_CAMERA_REGISTER_X_OFFSET:
        return within(value < cols);
      case ARV_FAKE_CAMERA_REGISTER_Y_OFFSET:
        return within(value < rows);
      case ARV_FAKE_CAMERA_REGISTER_PIXEL_FORMAT:
        return within(value == std::uint32_t(ARV_PIXEL_FORMAT_MONO_8) ||
                      value == std::uint32_t(ARV_PIXEL_FORMAT_MONO_16));
      default:
        return gvcp::Status::kSuccess;
    }
  }
  // A memory write may not reach around those checks: one that touches a read-only or bounded
  // register is refused (clients write registers with WRITEREG, memory for strings).
  static bool touches_guarded(std::uint32_t address, std::uint32_t count) {
    for (const Range& r : kReadOnly)
      if (overlaps(address, count, r.begin, r.end)) return true;
    for (const Bounded& b : kBounded)
      if (overlaps(address, count, b.address, b.address + 4)) return true;
    return overlaps(address, count, ARV_FAKE_CAMERA_REGISTER_WIDTH, ARV_FAKE_CAMERA_REGISTER_Y_OFFSET + 4);
  }

  // The camera's clock in ns (1 GHz ticks): Aravis's register model stamps each frame with the
  // host's CLOCK_REALTIME (g_get_real_time, whole us) as it fills it; a reset moves the zero.
  std::int64_t clock_now_ns() const { return std::int64_t(g_get_real_time()) * 1000 - clock_zero_ns; }
  void control_clock(std::uint32_t value) {
    if (value & 1u) clock_zero_ns = std::int64_t(g_get_real_time()) * 1000;
    if (value & 2u) {
      const auto latched = std::uint64_t(clock_now_ns());
      arv_fake_camera_write_register(camera, kTimestampValueHigh, std::uint32_t(latched >> 32));
      arv_fake_camera_write_register(camera, kTimestampValueLow, std::uint32_t(latched));
    }
  }

  void expire_controller(std::int64_t now) {
    if (have_controller &&
        now - controller_heard_us > std::int64_t(read_register(kHeartbeatTimeoutMs)) * 1000) {
      have_controller = false;
      arv_fake_camera_set_control_channel_privilege(camera, 0);
    }
  }

  // One datagram from `from` on `fd`: checked, then carried out and answered, refused, or dropped.
  // The discovery sockets answer discovery only.
  void answer(int fd, const sockaddr_in& from, const std::uint8_t* datagram, std::size_t size) {
    const std::int64_t now = now_us();
    expire_controller(now);
    const gvcp::Checked c = gvcp::check_command(datagram, size, map);
    if (c.verdict == gvcp::Verdict::kDrop) {
      owner->malformed_.fetch_add(1, std::memory_order_relaxed);
      return;
    }
    if (fd != control_fd && c.command != gvcp::Command::kDiscovery)
      return;  // a broadcast command: for no one camera
    const bool from_controller = have_controller && from.sin_addr.s_addr == controller.sin_addr.s_addr &&
                                 from.sin_port == controller.sin_port;
    if (from_controller) controller_heard_us = now;
    const bool may_write = !have_controller || from_controller;
    std::uint8_t ack[gvcp::kHeaderBytes + gvcp::kMaxDataBytes + 4];
    std::uint8_t* data = ack + gvcp::kHeaderBytes;
    std::size_t length = 0;
    gvcp::Status status = c.status;
    if (c.verdict == gvcp::Verdict::kRefuse) {
      owner->malformed_.fetch_add(1, std::memory_order_relaxed);
    } else if ((c.command == gvcp::Command::kWriteRegister || c.command == gvcp::Command::kWriteMemory) &&
               !may_write) {
      status = gvcp::Status::kAccessDenied;  // another client holds control
    } else {
      switch (c.command) {
        case gvcp::Command::kDiscovery:
          arv_fake_camera_read_memory(camera, 0, gvcp::kDiscoveryBytes, data);
          length = gvcp::kDiscoveryBytes;
          break;
        case gvcp::Command::kReadRegister:
          for (std::size_t i = 0; i < c.length; i += 4)
            gvcp::write_be32(data + i, read_register(gvcp::read_be32(c.payload + i)));
          length = c.length;
          break;
        case gvcp::Command::kWriteRegister: {
          // All or nothing: every pair is checked before any is written; the acknowledgement's
          // index says how many were written (GigE Vision: 0 when the first is refused).
          for (std::size_t i = 0; i < c.length && status == gvcp::Status::kSuccess; i += 8)
            status = check_register_write(gvcp::read_be32(c.payload + i), gvcp::read_be32(c.payload + i + 4));
          std::uint32_t written = 0;
          if (status == gvcp::Status::kSuccess) {
            for (std::size_t i = 0; i < c.length; i += 8, ++written) {
              const std::uint32_t address = gvcp::read_be32(c.payload + i),
                                  value = gvcp::read_be32(c.payload + i + 4);
              if (address == kTimestampControl)
                control_clock(value);
              else
                arv_fake_camera_write_register(camera, address, value);
            }
          } else {
            owner->malformed_.fetch_add(1, std::memory_order_relaxed);
          }
          gvcp::write_be32(data, written);  // reserved, then the registers written
          length = 4;
          break;
        }
        case gvcp::Command::kReadMemory:
          gvcp::write_be32(data, c.address);
          arv_fake_camera_read_memory(camera, c.address, c.count, data + 4);
          length = 4 + c.count;
          break;
        case gvcp::Command::kWriteMemory:
          if (touches_guarded(c.address, c.count)) {
            status = gvcp::Status::kWriteProtect;
            owner->malformed_.fetch_add(1, std::memory_order_relaxed);
          } else {
            arv_fake_camera_write_memory(camera, c.address, c.count, c.payload + 4);
          }
          gvcp::write_be32(data, c.address);
          length = 4;
          break;
        case gvcp::Command::kPacketResend:
          break;
      }
    }
    if (c.ack_required) {
      gvcp::write_ack_header(ack, status, c.command, std::uint16_t(length), c.id);
      ::sendto(fd, ack, gvcp::kHeaderBytes + length, MSG_DONTWAIT, reinterpret_cast<const sockaddr*>(&from),
               sizeof from);
    }
    const bool privileged = arv_fake_camera_get_control_channel_privilege(camera) != 0;
    if (!have_controller && privileged) {
      have_controller = true;
      controller = from;
      controller_heard_us = now;
    } else if (have_controller && !privileged) {
      have_controller = false;
    }
  }

  // The datagrams waiting on the sockets, at most 64 per socket (a flood cannot hold off frames).
  void take_datagrams(const pollfd* fds, int n, std::uint8_t* buffer, std::size_t capacity) {
    for (int i = 0; i < n; ++i) {
      if ((fds[i].revents & POLLIN) == 0 || fds[i].fd == wake_fd) continue;
      for (int k = 0; k < 64; ++k) {
        sockaddr_in from{};
        socklen_t from_length = sizeof from;
        const ssize_t got = ::recvfrom(fds[i].fd, buffer, capacity, MSG_DONTWAIT,
                                       reinterpret_cast<sockaddr*>(&from), &from_length);
        if (got < 0) break;
        if (from.sin_family == AF_INET) answer(fds[i].fd, from, buffer, std::size_t(got));
      }
    }
  }

  // The image buffer's frame as GVSP packets to `to`: leader, payload, trailer. Nothing where the
  // frame the registers now describe is not the one the buffer holds.
  void send_frame(ArvBuffer* image, const sockaddr_in& to, std::uint32_t packet_size, std::uint8_t* packet) {
    if (arv_buffer_get_status(image) != ARV_BUFFER_STATUS_SUCCESS) return;
    gvcp::ImageLeader leader;
    leader.timestamp_ns = arv_buffer_get_timestamp(image) - std::uint64_t(clock_zero_ns);
    leader.pixel_format = std::uint32_t(arv_buffer_get_image_pixel_format(image));
    leader.width = std::uint32_t(arv_buffer_get_image_width(image));
    leader.height = std::uint32_t(arv_buffer_get_image_height(image));
    leader.x = std::uint32_t(arv_buffer_get_image_x(image));
    leader.y = std::uint32_t(arv_buffer_get_image_y(image));
    if (image_size(leader.width, leader.height, leader.x, leader.y, leader.pixel_format) != image_bytes)
      return;
    const auto* pixels = static_cast<const std::uint8_t*>(arv_buffer_get_data(image, nullptr));
    const auto frame_id = std::uint16_t(arv_buffer_get_frame_id(image));
    const auto send = [&](std::size_t bytes) {
      ::sendto(stream_fd, packet, bytes, 0, reinterpret_cast<const sockaddr*>(&to), sizeof to);
    };
    send(gvcp::write_gvsp_leader(packet, frame_id, leader));
    const std::size_t per_packet =
        std::clamp<std::size_t>(packet_size, 576, 65535) - gvcp::kGvspOverheadBytes;
    std::uint32_t packet_id = 1;
    for (std::size_t offset = 0; offset < image_bytes; offset += per_packet, ++packet_id)
      send(gvcp::write_gvsp_payload(packet, frame_id, packet_id, pixels + offset,
                                    std::min(per_packet, image_bytes - offset)));
    send(gvcp::write_gvsp_trailer(packet, frame_id, packet_id));
  }

  void run() {
    std::vector<std::uint8_t> datagram(65536), packet(65536);
    pollfd fds[4];
    int n = 0;
    for (int fd : {control_fd, global_discovery_fd, subnet_discovery_fd, wake_fd})
      if (fd >= 0) fds[n++] = {fd, POLLIN, 0};
    ArvBuffer* image = nullptr;
    sockaddr_in stream{};
    while (!cancel.load()) {
      const auto acquiring = [&] {
        return arv_fake_camera_get_control_channel_privilege(camera) != 0 &&
               arv_fake_camera_get_acquisition_status(camera) != 0;
      };
      // Commands until the next frame is due (in the register model's frame schedule).
      guint64 next_us = guint64(g_get_real_time()) + 100'000;
      if (acquiring()) arv_fake_camera_get_sleep_time_for_next_frame(camera, &next_us);
      for (;;) {
        const gint64 left_us = gint64(next_us) - g_get_real_time();
        if (left_us <= 0 || cancel.load()) break;
        if (::poll(fds, nfds_t(n), int(std::min<gint64>((left_us + 999) / 1000, 100))) > 0)
          take_datagrams(fds, n, datagram.data(), datagram.size());
      }
      expire_controller(now_us());
      if (!acquiring()) {
        if (image != nullptr) g_object_unref(image);
        image = nullptr;
        continue;
      }
      if (image == nullptr) {  // the stream starts: its destination and frame size, as they are now
        const std::uint32_t address = read_register(kStreamAddress),
                            port = read_register(kStreamPort) & 0xFFFF;
        image_bytes = image_size(read_register(ARV_FAKE_CAMERA_REGISTER_WIDTH),
                                 read_register(ARV_FAKE_CAMERA_REGISTER_HEIGHT),
                                 read_register(ARV_FAKE_CAMERA_REGISTER_X_OFFSET),
                                 read_register(ARV_FAKE_CAMERA_REGISTER_Y_OFFSET),
                                 read_register(ARV_FAKE_CAMERA_REGISTER_PIXEL_FORMAT));
        if (address == 0 || port == 0 || image_bytes == 0) continue;  // nowhere to send, or no such image
        stream = {};
        stream.sin_family = AF_INET;
        stream.sin_addr.s_addr = htonl(address);
        stream.sin_port = htons(std::uint16_t(port));
        image = arv_buffer_new(image_bytes, nullptr);
      }
      if (arv_fake_camera_is_in_free_running_mode(camera) ||
          (arv_fake_camera_is_in_software_trigger_mode(camera) &&
           arv_fake_camera_check_and_acknowledge_software_trigger(camera))) {
        guint32 packet_size = 0;
        arv_fake_camera_fill_buffer(camera, image, &packet_size);
        send_frame(image, stream, packet_size, packet.data());
      }
    }
    if (image != nullptr) g_object_unref(image);
  }
};

bool gvcp_port_free(const std::string& address) {
  const sockaddr_in at = ipv4(address, gvcp::kPort);
  if (at.sin_family != AF_INET) return false;
  const int fd = bound_udp(at, false);
  if (fd >= 0) ::close(fd);
  return fd >= 0;
}

std::vector<std::string> local_ipv4_addresses() {
  std::vector<std::string> out;
  for (const InterfaceUp& i : interfaces_up())
    if (std::find(out.begin(), out.end(), i.address) == out.end()) out.push_back(i.address);
  std::stable_partition(out.begin(), out.end(), [](const std::string& a) { return a == "127.0.0.1"; });
  return out;
}

GigeFakeDetector::GigeFakeDetector(GigeFakeDetectorOptions options, GigeFrameRenderer render)
    : options_(std::move(options)), render_(std::move(render)) {}

GigeFakeDetector::~GigeFakeDetector() {
  stop();
}

bool GigeFakeDetector::running() const {
  return server_ != nullptr;
}

Status GigeFakeDetector::start() {
  const std::string name = "fake gige camera " + options_.serial;
  if (server_ != nullptr) return failed_precondition(name + ": already running");
  if (options_.rows <= 0 || options_.cols <= 0 || options_.rows > 16384 || options_.cols > 16384)
    return invalid_argument(name + ": rows and cols must be 1 to 16384");
  if (options_.serial.empty() || options_.serial.size() > 15)
    return invalid_argument("fake gige camera: the serial number must have 1 to 15 characters");
  if (!std::isfinite(options_.frame_rate_hz) || options_.frame_rate_hz < 0.1 || options_.frame_rate_hz > 1000)
    return invalid_argument(name + ": frame_rate_hz must be 0.1 to 1000");
  if (!std::isfinite(options_.trigger_poll_hz) || options_.trigger_poll_hz < 1 ||
      options_.trigger_poll_hz > 10000)
    return invalid_argument(name + ": trigger_poll_hz must be 1 to 10000");
  if (!render_) return invalid_argument(name + ": no renderer");

  // The address: an interface's (by its name), or the one given; the broadcast address of the
  // interface that carries it, for subnet discovery.
  std::string known, broadcast;
  address_.clear();
  const std::vector<InterfaceUp> interfaces = interfaces_up();
  for (const InterfaceUp& i : interfaces) {
    known += (known.empty() ? "" : ", ") + i.name + " " + i.address;
    if (address_.empty() && i.name == options_.interface) address_ = i.address;
  }
  const sockaddr_in given = ipv4(options_.interface, 0);
  const in_addr_t host_order = ntohl(given.sin_addr.s_addr);
  if (address_.empty() && given.sin_family == AF_INET && host_order != INADDR_ANY &&
      host_order != INADDR_BROADCAST && !IN_MULTICAST(host_order))
    address_ = options_.interface;  // one host address: not every interface, a broadcast or a group
  for (const InterfaceUp& i : interfaces)
    if (i.address == address_) broadcast = i.broadcast;
  const std::string here = known.empty() ? std::string("none") : known;
  const std::string nowhere = name + ": no interface that is up has the address or name '" +
                              options_.interface +
                              "' (a fake camera listens on an interface's own address or on any 127.x.y.z; "
                              "this host has " +
                              here + ")";
  if (address_.empty()) return not_found(nowhere);

  auto s = std::make_unique<Server>();
  s->owner = this;
  s->control_fd = bound_udp(ipv4(address_, gvcp::kPort), false);
  const int bind_error = errno;
  if (s->control_fd < 0 && bind_error == EADDRNOTAVAIL) return not_found(nowhere);
  if (s->control_fd < 0)
    return io_error(name + ": cannot listen on " + address_ +
                    ":3956 (GVCP): another GigE camera or program holds that port on that address (" +
                    std::strerror(bind_error) + ")");
  // Discovery: the limited broadcast (shared with other cameras) and the interface's subnet
  // broadcast; a camera without them is still reached at its address.
  s->global_discovery_fd = bound_udp(ipv4("255.255.255.255", gvcp::kPort), true);
  if (!broadcast.empty() && broadcast != address_)
    s->subnet_discovery_fd = bound_udp(ipv4(broadcast, gvcp::kPort), false);
  s->stream_fd = bound_udp(ipv4(address_, 0), false);
  s->wake_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
  if (s->stream_fd < 0 || s->wake_fd < 0) {
    const int error = errno;
    return io_error(name + ": no stream socket (" + std::strerror(error) + ")");
  }

  scratch_.assign(std::size_t(options_.rows) * std::size_t(options_.cols), 0);
  next_index_ = 0;
  served_.store(0);
  std::string description;
  if (options_.mono8_only) {
    description = write_mono8_description();
    if (description.empty()) return io_error(name + ": cannot write a GenICam description without Mono16");
  }
  s->camera =
      arv_fake_camera_new_full(options_.serial.c_str(), description.empty() ? nullptr : description.c_str());
  if (!description.empty()) std::remove(description.c_str());  // read when the camera was made
  if (s->camera == nullptr) return internal_error(name + ": Aravis made no camera register model");
  std::size_t xml_bytes = 0;
  arv_fake_camera_get_genicam_xml(s->camera, &xml_bytes);
  // Registers, then the GenICam description (the register model zero-fills a read past its end).
  s->map.writable_bytes = ARV_FAKE_CAMERA_MEMORY_SIZE;
  s->map.readable_bytes = std::uint32_t(ARV_FAKE_CAMERA_MEMORY_SIZE + (xml_bytes + 3) / 4 * 4);
  GInetAddress* inet = g_inet_address_new_from_string(address_.c_str());
  arv_fake_camera_set_inet_address(s->camera, inet);
  g_object_unref(inet);
  ArvFakeCamera* fake = s->camera;
  const auto rows = guint32(options_.rows), cols = guint32(options_.cols);
  arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_SENSOR_WIDTH, cols);
  arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_SENSOR_HEIGHT, rows);
  arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_WIDTH, cols);
  arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_HEIGHT, rows);
  arv_fake_camera_write_register(
      fake, ARV_FAKE_CAMERA_REGISTER_PIXEL_FORMAT,
      guint32(options_.mono8_only ? ARV_PIXEL_FORMAT_MONO_8 : ARV_PIXEL_FORMAT_MONO_16));
  arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_ACQUISITION_FRAME_PERIOD_US,
                                 guint32(std::lround(1e6 / options_.frame_rate_hz)));
  arv_fake_camera_set_trigger_frequency(fake, options_.trigger_poll_hz);
  arv_fake_camera_set_fill_pattern(fake, &Server::fill, s.get());
  Server* server = s.get();
  s->thread = std::thread([server] { server->run(); });
  server_ = std::move(s);
  return {};
}

void GigeFakeDetector::stop() {
  server_.reset();  // joins its thread, closes its sockets
}

void GigeFakeDetector::serve(void* data, std::size_t bytes, std::uint32_t width, std::uint32_t height,
                             std::uint32_t x, std::uint32_t y, std::uint32_t pixel_format) {
  const std::uint64_t index = next_index_++;
  served_.store(next_index_, std::memory_order_relaxed);
  const int rows = options_.rows, cols = options_.cols;
  const auto format = ArvPixelFormat(pixel_format);
  const std::uint64_t bytes_per_pixel = ARV_PIXEL_FORMAT_BIT_PER_PIXEL(format) / 8;
  if (data == nullptr || width == 0 || height == 0 || bytes_per_pixel == 0 || bytes_per_pixel > 3 ||
      std::uint64_t(x) + width > std::uint64_t(cols) || std::uint64_t(y) + height > std::uint64_t(rows) ||
      std::uint64_t(width) * height * bytes_per_pixel > bytes)
    return;
  if (format == ARV_PIXEL_FORMAT_MONO_16 && width == std::uint32_t(cols) && height == std::uint32_t(rows)) {
    render_(index, static_cast<std::uint16_t*>(data), rows, cols);  // straight into the frame sent
    return;
  }
  // Another window or format: render the whole panel, then send the window the client asked for
  // (Mono16 as it is, 8-bit formats as the high byte, RGB8 as three high bytes).
  render_(index, scratch_.data(), rows, cols);
  auto* out = static_cast<std::uint8_t*>(data);
  for (std::uint32_t r = 0; r < height; ++r) {
    for (std::uint32_t c = 0; c < width; ++c) {
      const std::uint16_t v = scratch_[std::size_t(r + y) * std::size_t(cols) + std::size_t(c + x)];
      std::uint8_t* p = out + (std::size_t(r) * width + c) * bytes_per_pixel;
      if (bytes_per_pixel == 2) {
        std::memcpy(p, &v, 2);
      } else {
        for (std::uint64_t b = 0; b < bytes_per_pixel; ++b) p[b] = std::uint8_t(v >> 8);
      }
    }
  }
}

}  // namespace lftrack::sim

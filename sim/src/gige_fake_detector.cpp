#include "lftrack/sim/gige_fake_detector.hpp"

#include <arpa/inet.h>
#include <arv.h>
#include <ifaddrs.h>
#include <net/if.h>
#include <netinet/in.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

namespace lftrack::sim {

struct GigeFakeDetector::Arv {
  ArvGvFakeCamera* camera = nullptr;

  // Aravis's fill-pattern callback (ArvFakeCameraFillPattern), on the fake camera's thread.
  static void fill(ArvBuffer* buffer, void* self, guint32 /*exposure_us*/, guint32 /*gain*/,
                   ArvPixelFormat format) {
    void* data =
        const_cast<void*>(arv_buffer_get_data(buffer, nullptr));  // the frame the camera is about to send
    static_cast<GigeFakeDetector*>(self)->serve(
        data, arv_buffer_get_image_width(buffer), arv_buffer_get_image_height(buffer),
        arv_buffer_get_image_x(buffer), arv_buffer_get_image_y(buffer), std::uint32_t(format));
  }
};

namespace {

// name -> the IPv4 address of every interface that is up.
std::vector<std::pair<std::string, std::string>> interfaces_up() {
  std::vector<std::pair<std::string, std::string>> out;
  ifaddrs* list = nullptr;
  if (getifaddrs(&list) != 0) return out;
  for (ifaddrs* i = list; i != nullptr; i = i->ifa_next) {
    if (i->ifa_addr == nullptr || i->ifa_addr->sa_family != AF_INET || (i->ifa_flags & IFF_UP) == 0) continue;
    char text[INET_ADDRSTRLEN] = {};
    const auto* in = reinterpret_cast<const sockaddr_in*>(i->ifa_addr);
    if (inet_ntop(AF_INET, &in->sin_addr, text, sizeof text) != nullptr) out.emplace_back(i->ifa_name, text);
  }
  freeifaddrs(list);
  return out;
}

// Aravis's GenICam description of its fake camera without the Mono16 entry, in a file of its own
// (the fake camera reads it once, when made); empty where that cannot be done.
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

}  // namespace

bool gvcp_port_free(const std::string& address) {
  sockaddr_in in{};
  in.sin_family = AF_INET;
  in.sin_port = htons(3956);
  if (inet_pton(AF_INET, address.c_str(), &in.sin_addr) != 1) return false;
  const int fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return false;
  const bool bound = bind(fd, reinterpret_cast<const sockaddr*>(&in), sizeof in) == 0;
  ::close(fd);
  return bound;
}

std::vector<std::string> local_ipv4_addresses() {
  std::vector<std::string> out;
  for (const auto& [name, address] : interfaces_up())
    if (std::find(out.begin(), out.end(), address) == out.end()) out.push_back(address);
  std::stable_partition(out.begin(), out.end(), [](const std::string& a) { return a == "127.0.0.1"; });
  return out;
}

GigeFakeDetector::GigeFakeDetector(GigeFakeDetectorOptions options, GigeFrameRenderer render)
    : options_(std::move(options)), render_(std::move(render)), arv_(std::make_unique<Arv>()) {}

GigeFakeDetector::~GigeFakeDetector() {
  stop();
}

bool GigeFakeDetector::running() const {
  return arv_->camera != nullptr;
}

Status GigeFakeDetector::start() {
  const std::string name = "fake gige camera " + options_.serial;
  if (arv_->camera != nullptr) return failed_precondition(name + ": already running");
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

  // The address: given, or the interface's; it must be one this host's interfaces carry.
  std::string known;
  address_.clear();
  for (const auto& [interface, address] : interfaces_up()) {
    known += (known.empty() ? "" : ", ") + interface + " " + address;
    if (address_.empty() && (address == options_.interface || interface == options_.interface))
      address_ = address;
  }
  if (address_.empty())
    return not_found(name + ": no interface that is up has the address or name '" + options_.interface +
                     "' (Aravis's fake camera listens only on an interface's own address; this host has " +
                     (known.empty() ? std::string("none") : known) + ")");

  const std::string taken = name + ": cannot listen on " + address_ +
                            ":3956 (GVCP): another GigE camera or program holds that port on that address";
  if (!gvcp_port_free(address_)) return io_error(taken);

  scratch_.assign(std::size_t(options_.rows) * std::size_t(options_.cols), 0);
  next_index_ = 0;
  served_.store(0);
  std::string description;
  if (options_.mono8_only) {
    description = write_mono8_description();
    if (description.empty()) return io_error(name + ": cannot write a GenICam description without Mono16");
  }
  arv_->camera = arv_gv_fake_camera_new_full(address_.c_str(), options_.serial.c_str(),
                                             description.empty() ? nullptr : description.c_str());
  if (!description.empty()) std::remove(description.c_str());  // read when the camera was made
  if (arv_->camera == nullptr) return internal_error(name + ": Aravis made no fake camera");
  // is_running() is true even where the GVCP socket could not be bound: the port must now be
  // held (by this camera: it was free a moment ago).
  if (!arv_gv_fake_camera_is_running(arv_->camera) || gvcp_port_free(address_)) {
    stop();
    return io_error(taken);
  }
  ArvFakeCamera* fake = arv_gv_fake_camera_get_fake_camera(arv_->camera);
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
  arv_fake_camera_set_fill_pattern(fake, &Arv::fill, this);
  return {};
}

void GigeFakeDetector::stop() {
  if (arv_->camera == nullptr) return;
  g_object_unref(arv_->camera);  // joins its thread, closes its sockets
  arv_->camera = nullptr;
}

void GigeFakeDetector::serve(void* data, int width, int height, int x, int y, std::uint32_t pixel_format) {
  const std::uint64_t index = next_index_++;
  served_.store(next_index_, std::memory_order_relaxed);
  if (data == nullptr || width <= 0 || height <= 0) return;
  const int rows = options_.rows, cols = options_.cols;
  const auto format = ArvPixelFormat(pixel_format);
  if (format == ARV_PIXEL_FORMAT_MONO_16 && width == cols && height == rows && x == 0 && y == 0) {
    render_(index, static_cast<std::uint16_t*>(data), rows, cols);  // straight into the frame sent
    return;
  }
  // Another window or format: render the whole panel, then send the window the client asked for
  // (Mono16 as it is, 8-bit formats as the high byte, RGB8 as three high bytes).
  render_(index, scratch_.data(), rows, cols);
  const int bytes_per_pixel = int(ARV_PIXEL_FORMAT_BIT_PER_PIXEL(format)) / 8;
  auto* out = static_cast<std::uint8_t*>(data);
  for (int r = 0; r < height; ++r) {
    for (int c = 0; c < width; ++c) {
      const int sr = r + y, sc = c + x;
      const std::uint16_t v =
          sr < rows && sc < cols ? scratch_[std::size_t(sr) * std::size_t(cols) + std::size_t(sc)] : 0;
      std::uint8_t* p =
          out + (std::size_t(r) * std::size_t(width) + std::size_t(c)) * std::size_t(bytes_per_pixel);
      if (bytes_per_pixel == 2) {
        std::memcpy(p, &v, 2);
      } else {
        for (int b = 0; b < bytes_per_pixel; ++b) p[b] = std::uint8_t(v >> 8);
      }
    }
  }
}

}  // namespace lftrack::sim

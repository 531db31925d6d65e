#include "lftrack/drivers/gige_detector.hpp"

#include <arv.h>
#include <dirent.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <time.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <semaphore>
#include <shared_mutex>
#include <thread>

namespace lftrack::drivers {

namespace {

struct FormatChoice {
  ArvPixelFormat format;
  int bytes_per_pixel;
};
// Preferred formats, best first: 16 bits, then 14, 12 and 10 bits in 16-bit containers (the
// unpacked PFNC formats; packed Mono12p/Mono10p are not read), then 8 bits.
constexpr FormatChoice kPixelFormats[] = {{ARV_PIXEL_FORMAT_MONO_16, 2},
                                     {ARV_PIXEL_FORMAT_MONO_14, 2},
                                     {ARV_PIXEL_FORMAT_MONO_12, 2},
                                     {ARV_PIXEL_FORMAT_MONO_10, 2},
                                     {ARV_PIXEL_FORMAT_MONO_8, 1}};

// The message of a GError, which it frees; `fallback` where there is none.
std::string take_message(GError*& error, const std::string& fallback) {
  if (error == nullptr) return fallback;
  std::string m = error->message != nullptr ? error->message : fallback;
  g_clear_error(&error);
  return m;
}

// net.core.rmem_max, the most SO_RCVBUF gives an unprivileged socket; -1 where unknown.
long long receive_buffer_limit() {
  std::ifstream in("/proc/sys/net/core/rmem_max");
  long long v = -1;
  if (!(in >> v)) return -1;
  return v;
}

// Aravis 0.8.26 sets the stream socket's receive buffer only when the first frame's first packet
// is in (arvgvstream.c, _update_socket from _find_frame_data): by then the default buffer
// (net.core.rmem_default, 208 KiB) has overflowed under that frame's burst, so the first frame
// of every stream arrived incomplete. This sets it before acquisition starts, on the UDP socket
// bound to the stream's port (Aravis keeps the socket to itself). False where none was found.
bool set_stream_receive_buffer(guint16 port, int bytes) {
  DIR* fds = opendir("/proc/self/fd");
  if (fds == nullptr) return false;
  bool done = false;
  while (dirent* entry = readdir(fds)) {
    char* end = nullptr;
    const long fd = std::strtol(entry->d_name, &end, 10);
    if (end == entry->d_name || *end != '\0' || fd == dirfd(fds)) continue;
    sockaddr_storage address{};
    socklen_t length = sizeof address;
    int type = 0;
    socklen_t type_length = sizeof type;
    if (getsockname(int(fd), reinterpret_cast<sockaddr*>(&address), &length) != 0 ||
        address.ss_family != AF_INET || getsockopt(int(fd), SOL_SOCKET, SO_TYPE, &type, &type_length) != 0 ||
        type != SOCK_DGRAM)
      continue;
    if (ntohs(reinterpret_cast<const sockaddr_in*>(&address)->sin_port) != port) continue;
    done = setsockopt(int(fd), SOL_SOCKET, SO_RCVBUF, &bytes, sizeof bytes) == 0;
    break;
  }
  closedir(fds);
  return done;
}

std::int64_t clock_ns(clockid_t id) {
  timespec ts{};
  clock_gettime(id, &ts);
  return std::int64_t(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

void on_control_lost(ArvDevice*, gpointer flag) {
  static_cast<std::atomic<bool>*>(flag)->store(true, std::memory_order_release);
}

bool in(double v, double lo, double hi) {
  return std::isfinite(v) && v >= lo && v <= hi;
}

}  // namespace

// Aravis's objects for one open camera, and what its threads share with the cycle.
struct GigeDetector::Arv {
  ArvDevice* device = nullptr;  // our reference; the camera and the stream hold their own
  ArvCamera* camera = nullptr;
  ArvStream* stream = nullptr;
  gulong control_lost_handler = 0;
  guint underruns_info = G_MAXUINT;       // the stream's "n_underruns" statistic, by index
  std::atomic<bool> control_lost{false};  // set by Aravis's heartbeat thread
  std::atomic<bool> gone{false};          // marked by capture() (the cycle's thread); read by the clock's
  // The software trigger's thread.
  std::thread trigger_thread;
  std::counting_semaphore<> trigger_wake{0};
  std::atomic<bool> trigger_armed{false};
  std::atomic<std::int64_t> trigger_at_ns{0};
  std::atomic<bool> trigger_stop{false};
  std::atomic<std::int64_t> trigger_failures{0};
};

Status validate_gige_options(const GigeDetectorOptions& o) {
  const std::string name = "gige camera " + o.camera;
  if (o.camera.empty())
    return invalid_argument(
        "gige camera: no camera (an IPv4 address, host name, device id or serial number)");
  if (o.rows <= 0 || o.cols <= 0 || o.rows > 16384 || o.cols > 16384)
    return invalid_argument(name + ": rows and cols must be 1 to 16384");
  if (o.buffers < 2 || o.buffers > 64) return invalid_argument(name + ": buffers must be 2 to 64");
  if (!in(o.frame_rate_hz, 0, 1000))
    return invalid_argument(name + ": frame_rate_hz must be 0 (the camera's) to 1000");
  if (o.trigger == GigeTrigger::kLine && o.trigger_line.empty())
    return invalid_argument(name + ": a line trigger needs trigger_line (e.g. Line0)");
  if (o.packet_size != 0 && (o.packet_size < 576 || o.packet_size > 65535))
    return invalid_argument(name + ": packet_size must be 0 (the camera's) or 576 to 65535 bytes");
  if (!in(o.packet_timeout_ms, 0.1, 1000))
    return invalid_argument(name + ": packet_timeout_ms must be 0.1 to 1000");
  if (!in(o.frame_retention_ms, o.packet_timeout_ms, 10000))
    return invalid_argument(name + ": frame_retention_ms must be packet_timeout_ms to 10000");
  if (o.socket_buffer_bytes < -1)
    return invalid_argument(name + ": socket_buffer_bytes must be -1, 0 or a size");
  if (!in(o.leader_latency_ms, 0, 1000))
    return invalid_argument(name + ": leader_latency_ms must be 0 to 1000");
  return {};
}

GigeDetector::GigeDetector(GigeDetectorOptions options)
    : options_(std::move(options)), arv_(std::make_unique<Arv>()) {}

GigeDetector::~GigeDetector() {
  close();
}

bool GigeDetector::is_open() const {
  return arv_->camera != nullptr && !arv_->gone;
}

int GigeDetector::frames_waiting() const {
  if (arv_->stream == nullptr) return 0;
  gint input = 0, output = 0;
  arv_stream_get_n_buffers(arv_->stream, &input, &output);
  return int(output);
}

Status GigeDetector::fail(const std::string& what) {
  const std::string message = "gige camera " + options_.camera + ": " + what;
  release();
  return io_error(message);
}

Status GigeDetector::open() {
  LFTRACK_RETURN_IF_ERROR(validate_gige_options(options_));
  const std::string name = "gige camera " + options_.camera;
  if (arv_->device != nullptr) return failed_precondition(name + ": already open");
  GError* error = nullptr;

  // GigE Vision only: Aravis's system-wide arv_open_device() would ask USB3 Vision first.
  arv_->device = arv_interface_open_device(arv_gv_interface_get_instance(), options_.camera.c_str(), &error);
  if (arv_->device == nullptr)
    return not_found(name + ": no GigE Vision camera answers (" +
                     take_message(error, "not found by GigE Vision discovery on any interface") + ")");
  arv_->control_lost.store(false);
  arv_->gone = false;
  arv_->control_lost_handler =
      g_signal_connect(arv_->device, "control-lost", G_CALLBACK(on_control_lost), &arv_->control_lost);
  if (ARV_IS_GV_DEVICE(arv_->device) && !arv_gv_device_is_controller(ARV_GV_DEVICE(arv_->device)))
    return fail("another application controls it (GigE Vision control privilege refused)");
  arv_->camera = arv_camera_new_with_device(arv_->device, &error);
  if (arv_->camera == nullptr) return fail(take_message(error, "Aravis cannot make a camera of it"));
  const char* id = arv_camera_get_device_id(arv_->camera, nullptr);
  device_id_ = id != nullptr ? id : "";

  // A 16-bit grey format, best first.
  guint n_formats = 0;
  gint64* offered = arv_camera_dup_available_pixel_formats(arv_->camera, &n_formats, &error);
  if (offered == nullptr)
    return fail("cannot list its pixel formats (" + take_message(error, "no PixelFormat") + ")");
  const FormatChoice* chosen = nullptr;
  for (const FormatChoice& f : kPixelFormats) {
    if (std::find(offered, offered + n_formats, gint64(f.format)) != offered + n_formats) {
      chosen = &f;
      break;
    }
  }
  g_free(offered);
  if (chosen == nullptr) {
    std::string list;
    const char** names = arv_camera_dup_available_pixel_formats_as_strings(arv_->camera, &n_formats, nullptr);
    for (guint i = 0; names != nullptr && i < n_formats; ++i)
      list += (list.empty() ? "" : ", ") + std::string(names[i]);
    g_free(names);
    return fail("offers no grey format lftrack reads (Mono16, Mono14, Mono12, Mono10, Mono8); it offers " +
                (list.empty() ? std::string("none") : list));
  }
  arv_camera_set_pixel_format(arv_->camera, chosen->format, &error);
  if (error != nullptr) return fail("cannot set its pixel format: " + take_message(error, ""));
  pixel_format_ = arv_camera_get_pixel_format(arv_->camera, &error);
  const char* format_name = arv_camera_get_pixel_format_as_string(arv_->camera, nullptr);
  pixel_format_name_ = format_name != nullptr ? format_name : "?";
  if (error != nullptr || pixel_format_ != chosen->format)
    return fail("keeps pixel format " + pixel_format_name_ + " when asked for another");
  bytes_per_pixel_ = chosen->bytes_per_pixel;

  // The whole panel, as the scene says; never cropped to fit. Asked for first, so that a region
  // another program left (or a stranger wrote while nobody held the camera) is not taken for the
  // panel's size; what the camera then gives is checked.
  if (arv_camera_is_feature_available(arv_->camera, "Width", nullptr)) {
    arv_camera_set_region(arv_->camera, 0, 0, options_.cols, options_.rows, &error);
    g_clear_error(&error);  // a camera that cannot is judged by what it gives, below
  }
  gint x = 0, y = 0, width = 0, height = 0;
  arv_camera_get_region(arv_->camera, &x, &y, &width, &height, &error);
  if (error != nullptr) return fail("cannot read its image size: " + take_message(error, ""));
  if (width != options_.cols || height != options_.rows)
    return fail("gives " + std::to_string(width) + " x " + std::to_string(height) + " " + pixel_format_name_ +
                " for the scene's " + std::to_string(options_.cols) + " x " + std::to_string(options_.rows));

  // Trigger.
  switch (options_.trigger) {
    case GigeTrigger::kFreeRun:
      if (arv_camera_is_feature_available(arv_->camera, "TriggerMode", nullptr)) {
        arv_camera_clear_triggers(arv_->camera, &error);
        if (error != nullptr) return fail("cannot switch its triggers off: " + take_message(error, ""));
      }
      if (options_.frame_rate_hz > 0) {
        arv_camera_set_frame_rate(arv_->camera, options_.frame_rate_hz, &error);
        if (error != nullptr) return fail("cannot set its frame rate: " + take_message(error, ""));
        const double rate = arv_camera_get_frame_rate(arv_->camera, &error);
        if (error != nullptr || std::abs(rate - options_.frame_rate_hz) > 0.05 * options_.frame_rate_hz)
          return fail("runs at " + std::to_string(rate) + " Hz for the asked " +
                      std::to_string(options_.frame_rate_hz) + " Hz");
      }
      break;
    case GigeTrigger::kSoftware:
      if (!arv_camera_is_software_trigger_supported(arv_->camera, nullptr))
        return fail("has no software trigger (TriggerSoftware)");
      arv_camera_set_trigger(arv_->camera, "Software", &error);
      if (error != nullptr) return fail("cannot select the software trigger: " + take_message(error, ""));
      break;
    case GigeTrigger::kLine:
      if (!arv_camera_is_enumeration_entry_available(arv_->camera, "TriggerSource",
                                                     options_.trigger_line.c_str(), nullptr))
        return fail("has no trigger source " + options_.trigger_line);
      arv_camera_set_trigger(arv_->camera, options_.trigger_line.c_str(), &error);
      if (error != nullptr)
        return fail("cannot select trigger source " + options_.trigger_line + ": " + take_message(error, ""));
      break;
  }
  if (arv_camera_is_feature_available(arv_->camera, "AcquisitionMode", nullptr)) {
    arv_camera_set_acquisition_mode(arv_->camera, ARV_ACQUISITION_MODE_CONTINUOUS, &error);
    if (error != nullptr) return fail("cannot set continuous acquisition: " + take_message(error, ""));
  }

  // Transport.
  if (options_.packet_size > 0) {
    arv_camera_gv_set_packet_size(arv_->camera, options_.packet_size, &error);
    if (error != nullptr) return fail("cannot set packet size: " + take_message(error, ""));
    const guint got = arv_camera_gv_get_packet_size(arv_->camera, nullptr);
    if (int(got) != options_.packet_size)
      return fail("takes packet size " + std::to_string(got) + " for the asked " +
                  std::to_string(options_.packet_size));
  }
  arv_camera_gv_set_stream_options(arv_->camera, options_.packet_socket
                                                     ? ARV_GV_STREAM_OPTION_NONE
                                                     : ARV_GV_STREAM_OPTION_PACKET_SOCKET_DISABLED);
  const guint payload = arv_camera_get_payload(arv_->camera, &error);
  if (error != nullptr || payload == 0)
    return fail("gives no payload size: " + take_message(error, "0 bytes"));
  const std::size_t needed =
      std::size_t(options_.rows) * std::size_t(options_.cols) * std::size_t(bytes_per_pixel_);
  if (payload < needed)
    return fail("announces " + std::to_string(payload) + " bytes per frame, fewer than " +
                std::to_string(needed));
  const long long socket_buffer =
      options_.socket_buffer_bytes < 0 ? 2LL * payload : static_cast<long long>(options_.socket_buffer_bytes);
  const long long limit = receive_buffer_limit();
  if (socket_buffer > 0 && limit >= 0 && socket_buffer > limit)
    return fail("its stream needs a " + std::to_string(socket_buffer) +
                "-byte receive buffer (two frames) but net.core.rmem_max is " + std::to_string(limit) +
                ": raise it (sysctl -w net.core.rmem_max=" + std::to_string(socket_buffer) +
                ") or set socket_buffer_bytes");

  arv_->stream = arv_camera_create_stream(arv_->camera, nullptr, nullptr, &error);
  if (arv_->stream == nullptr) return fail("cannot open a stream: " + take_message(error, "no stream"));
  if (ARV_IS_GV_STREAM(arv_->stream)) {
    g_object_set(
        arv_->stream, "packet-resend",
        options_.packet_resend ? ARV_GV_STREAM_PACKET_RESEND_ALWAYS : ARV_GV_STREAM_PACKET_RESEND_NEVER,
        "packet-timeout", guint(options_.packet_timeout_ms * 1000), "frame-retention",
        guint(options_.frame_retention_ms * 1000), nullptr);
    if (socket_buffer > 0) {
      const gint bytes = gint(std::min<long long>(socket_buffer, G_MAXINT));
      g_object_set(arv_->stream, "socket-buffer", ARV_GV_STREAM_SOCKET_BUFFER_FIXED, "socket-buffer-size",
                   bytes, nullptr);
      (void)set_stream_receive_buffer(arv_gv_stream_get_port(ARV_GV_STREAM(arv_->stream)), bytes);
    }
  }
  for (int i = 0; i < options_.buffers; ++i)
    arv_stream_push_buffer(arv_->stream, arv_buffer_new_allocate(payload));
  arv_->underruns_info = G_MAXUINT;
  for (guint i = 0; i < arv_stream_get_n_infos(arv_->stream); ++i)
    if (g_strcmp0(arv_stream_get_info_name(arv_->stream, i), "n_underruns") == 0 &&
        arv_stream_get_info_type(arv_->stream, i) == G_TYPE_UINT64)
      arv_->underruns_info = i;
  underruns_at_open_ = counters_.underruns;

  start_device_clock();

  arv_camera_start_acquisition(arv_->camera, &error);
  if (error != nullptr) return fail("cannot start acquisition: " + take_message(error, ""));
  have_id_ = false;
  if (options_.trigger == GigeTrigger::kSoftware) start_trigger_thread();
  return {};
}

void GigeDetector::start_trigger_thread() {
  Arv* a = arv_.get();
  a->trigger_stop.store(false);
  a->trigger_armed.store(false);
  a->trigger_thread = std::thread([a] {
    for (;;) {
      a->trigger_wake.acquire();
      // Sleeps until the requested time, in slices short enough for close() not to wait.
      for (;;) {
        const std::int64_t left =
            a->trigger_at_ns.load(std::memory_order_acquire) - clock_ns(CLOCK_MONOTONIC);
        if (left <= 0 || a->trigger_stop.load(std::memory_order_acquire)) break;
        std::this_thread::sleep_for(std::chrono::nanoseconds(std::min<std::int64_t>(left, 10'000'000)));
      }
      if (a->trigger_stop.load(std::memory_order_acquire)) return;
      a->trigger_armed.store(false, std::memory_order_release);
      GError* error = nullptr;
      arv_camera_software_trigger(a->camera, &error);
      if (error != nullptr) {
        a->trigger_failures.fetch_add(1, std::memory_order_relaxed);
        g_clear_error(&error);
      }
    }
  });
}

void GigeDetector::stop_trigger_thread() {
  if (!arv_->trigger_thread.joinable()) return;
  arv_->trigger_stop.store(true, std::memory_order_release);
  arv_->trigger_wake.release();
  arv_->trigger_thread.join();
  while (arv_->trigger_wake.try_acquire()) {
  }
}

// GigE Vision's bootstrap registers for the camera's clock (GigE Vision 2.0, table 28-1): write
// kLatch to the control register, then read the latched 64-bit value, high word first.
constexpr guint64 kTimestampControl = 0x0944, kTimestampValueHigh = 0x0948;
constexpr guint32 kLatch = 2;

// How far a camera's clock may run from the host's between latch rounds (a crystal's tens of
// ppm, with room to spare), and how old a mapping may grow (rounds failing: every latch slower
// than DeviceClockMap::kMaxRoundTripNs) before the frames are timed by their arrival instead.
constexpr std::int64_t kDriftPartsPerMillion = 100;
constexpr std::int64_t kMaxMappingAgeNs = 5'000'000'000;
// A mapped exposure more than this before its frame's arrival is not believed (no panel reads
// out that slowly; a camera clock that stepped back is).
constexpr std::int64_t kMaxReadOutNs = 500'000'000;

void GigeDetector::start_device_clock() {
  clock_ = std::make_unique<DeviceClockMap>();
  tick_hz_ = 0;
  clock_problem_.clear();
  if (options_.exposure_clock != ExposureClock::kDevice) return;
  GError* error = nullptr;
  tick_hz_ = arv_gv_device_get_timestamp_tick_frequency(ARV_GV_DEVICE(arv_->device), &error);
  if (error != nullptr || tick_hz_ == 0) {
    clock_problem_ = "it gives no timestamp tick frequency (" + take_message(error, "0 Hz") + ")";
    tick_hz_ = 0;
    return;
  }
  std::string why;
  if (!latch_round(8, &why)) clock_problem_ = "its timestamp latch gave no usable time (" + why + ")";
}

bool GigeDetector::sync_clock(int latches) {
  return latch_round(latches, nullptr);
}

bool GigeDetector::latch_round(int latches, std::string* why) {
  if (tick_hz_ == 0 || arv_->device == nullptr || arv_->gone || clock_ == nullptr) return false;
  ArvDevice* device = arv_->device;
  clock_->begin_round();
  const std::int64_t refused_before = clock_->refused();
  for (int i = 0; i < latches; ++i) {
    GError* error = nullptr;
    ClockLatch latch;
    latch.host_before_ns = clock_ns(CLOCK_MONOTONIC);
    const gboolean latched = arv_device_write_register(device, kTimestampControl, kLatch, &error);
    latch.host_after_ns = clock_ns(CLOCK_MONOTONIC);
    std::uint8_t value[8] = {};  // the latched 64 bits, big-endian (GigE Vision), high word first
    if (!latched || !arv_device_read_memory(device, kTimestampValueHigh, sizeof value, value, &error)) {
      // A camera that does not answer: one timeout per round, not one per latch.
      if (why != nullptr) *why = take_message(error, "no answer");
      g_clear_error(&error);
      break;
    }
    std::uint64_t ticks = 0;
    for (std::uint8_t byte : value) ticks = (ticks << 8) | byte;
    // As Aravis converts the leader's timestamp (arv_gvsp_timestamp_to_ns): no overflow.
    const std::uint64_t ns =
        (ticks / tick_hz_) * 1'000'000'000ull + ((ticks % tick_hz_) * 1'000'000'000ull) / tick_hz_;
    latch.device_ns = ns > std::uint64_t(INT64_MAX) ? 0 : std::int64_t(ns);
    clock_->add(latch);
  }
  const bool renewed = clock_->end_round();
  if (!renewed && why != nullptr && why->empty() && clock_->refused() > refused_before)
    *why = "it latched 0, or every latch's round trip was over " +
           std::to_string(DeviceClockMap::kMaxRoundTripNs / 1'000'000) + " ms";
  return renewed;
}

bool GigeDetector::usable_mapping(std::int64_t now_ns, DeviceClockMap::Mapping* m) const {
  if (options_.exposure_clock != ExposureClock::kDevice || clock_ == nullptr) return false;
  *m = clock_->mapping();
  const std::int64_t age = now_ns - m->at_host_ns;
  if (m->at_host_ns == 0 || age > kMaxMappingAgeNs) return false;
  m->uncertainty_ns += std::max<std::int64_t>(age, 0) / (1'000'000 / kDriftPartsPerMillion);
  return true;
}

std::string GigeDetector::clock_source() const {
  if (options_.exposure_clock == ExposureClock::kArrival) return "arrival (exposure_clock: arrival)";
  if (device_clock_mapped())
    return "device clock (+-" + std::to_string((timestamp_uncertainty_ns() + 999) / 1000) + " us)";
  return "arrival: the device clock cannot be used: " +
         (clock_problem_.empty()
              ? std::string("no latch round has mapped it for 5 s, or the camera is not open")
              : clock_problem_);
}

bool GigeDetector::device_clock_mapped() const {
  DeviceClockMap::Mapping m;
  return usable_mapping(clock_ns(CLOCK_MONOTONIC), &m);
}

std::int64_t GigeDetector::timestamp_uncertainty_ns() const {
  DeviceClockMap::Mapping m;
  return usable_mapping(clock_ns(CLOCK_MONOTONIC), &m) ? m.uncertainty_ns : 0;
}

void GigeDetector::trigger(std::int64_t at_monotonic_ns) {
  if (!arv_->trigger_thread.joinable() || arv_->gone) return;
  arv_->trigger_at_ns.store(at_monotonic_ns, std::memory_order_release);
  if (!arv_->trigger_armed.exchange(true, std::memory_order_acq_rel)) arv_->trigger_wake.release();
}

void GigeDetector::release() {
  stop_trigger_thread();
  counters_.trigger_failures = arv_->trigger_failures.load(std::memory_order_relaxed);
  const bool lost = arv_->control_lost.load(std::memory_order_acquire);
  // Stopping acquisition is a GVCP command: skipped when the camera is known to be gone.
  if (arv_->camera != nullptr && arv_->stream != nullptr && !lost)
    arv_camera_stop_acquisition(arv_->camera, nullptr);
  if (arv_->stream != nullptr) g_object_unref(arv_->stream);  // joins the receive thread, frees the buffers
  arv_->stream = nullptr;
  if (arv_->camera != nullptr) g_object_unref(arv_->camera);
  arv_->camera = nullptr;
  if (arv_->device != nullptr) {
    if (arv_->control_lost_handler != 0)
      g_signal_handler_disconnect(arv_->device, arv_->control_lost_handler);
    arv_->control_lost_handler = 0;
    g_object_unref(arv_->device);  // the last reference: stops the heartbeat, leaves control
  }
  arv_->device = nullptr;
  arv_->gone = false;
}

void GigeDetector::close() {
  if (arv_->device == nullptr && arv_->camera == nullptr) return;
  release();
}

Status GigeDetector::reopen() {
  close();
  Status s = open();
  if (s.ok()) ++counters_.reopens;
  return s;
}

bool GigeDetector::copy_out(const void* data, std::size_t size, std::size_t stride, Frame* frame) const {
  const std::size_t line = std::size_t(options_.cols) * std::size_t(bytes_per_pixel_);
  if (data == nullptr || stride < line || size < stride * std::size_t(options_.rows - 1) + line) return false;
  const auto* bytes = static_cast<const std::uint8_t*>(data);
  for (int r = 0; r < options_.rows; ++r) {
    const std::uint8_t* in = bytes + std::size_t(r) * stride;
    std::uint16_t* out = &frame->pixels.at(r, 0);
    if (bytes_per_pixel_ == 1) {
      for (int c = 0; c < options_.cols; ++c) out[c] = in[c];  // widened, not scaled
    } else if constexpr (std::endian::native == std::endian::little) {
      std::memcpy(out, in, line);  // GigE Vision pixels are little-endian
    } else {
      for (int c = 0; c < options_.cols; ++c)
        out[c] = std::uint16_t(in[2 * c] | (std::uint16_t(in[2 * c + 1]) << 8));
    }
  }
  return true;
}

DeviceStatus GigeDetector::capture(Frame* frame, Deadline deadline) {
  Arv& a = *arv_;
  if (a.stream == nullptr || a.gone) return DeviceStatus::kDisconnected;
  counters_.trigger_failures = a.trigger_failures.load(std::memory_order_relaxed);
  if (a.control_lost.load(std::memory_order_acquire)) {
    a.gone = true;
    ++counters_.disconnects;
    return DeviceStatus::kDisconnected;
  }
  if (frame->pixels.rows() != options_.rows || frame->pixels.cols() != options_.cols)
    return DeviceStatus::kFault;

  const auto left =
      std::chrono::duration_cast<std::chrono::microseconds>(deadline - std::chrono::steady_clock::now());
  ArvBuffer* buffer = left.count() > 0 ? arv_stream_timeout_pop_buffer(a.stream, guint64(left.count()))
                                       : arv_stream_try_pop_buffer(a.stream);
  if (buffer == nullptr) {
    if (a.control_lost.load(std::memory_order_acquire)) {
      a.gone = true;
      ++counters_.disconnects;
      return DeviceStatus::kDisconnected;
    }
    ++counters_.timeouts;
    return DeviceStatus::kTimeout;
  }
  if (a.underruns_info != G_MAXUINT)
    counters_.underruns =
        underruns_at_open_ + std::int64_t(arv_stream_get_info_uint64(a.stream, a.underruns_info));
  // The newest complete buffer; every other one goes back unread.
  ArvBuffer* newest = nullptr;
  for (; buffer != nullptr; buffer = arv_stream_try_pop_buffer(a.stream)) {
    if (arv_buffer_get_status(buffer) != ARV_BUFFER_STATUS_SUCCESS) {
      ++counters_.incomplete;
      arv_stream_push_buffer(a.stream, buffer);
      continue;
    }
    if (newest != nullptr) {
      ++counters_.stale_dropped;
      arv_stream_push_buffer(a.stream, newest);
    }
    newest = buffer;
  }
  if (newest == nullptr) return DeviceStatus::kFault;

  const ArvBufferPayloadType type = arv_buffer_get_payload_type(newest);
  if ((type != ARV_BUFFER_PAYLOAD_TYPE_IMAGE && type != ARV_BUFFER_PAYLOAD_TYPE_EXTENDED_CHUNK_DATA) ||
      arv_buffer_get_image_width(newest) != options_.cols ||
      arv_buffer_get_image_height(newest) != options_.rows ||
      std::uint32_t(arv_buffer_get_image_pixel_format(newest)) != pixel_format_) {
    ++counters_.corrupt;
    arv_stream_push_buffer(a.stream, newest);
    return DeviceStatus::kFault;
  }

  const std::uint64_t id = arv_buffer_get_frame_id(newest);
  std::int64_t step = 1;
  if (have_id_) {
    bool backwards;
    if (id <= 0xFFFF && last_id_ <= 0xFFFF) {  // 16-bit ids: 0 is invalid, 65535 is followed by 1
      step = id > last_id_ ? std::int64_t(id - last_id_) : std::int64_t(id + 0xFFFF - last_id_);
      backwards = id == last_id_ || step > 0x7FFF;
    } else {
      step = std::int64_t(id - last_id_);
      backwards = step <= 0;
    }
    if (backwards) {
      ++counters_.backwards;
      last_id_ = id;
      arv_stream_push_buffer(a.stream, newest);
      return DeviceStatus::kFault;
    }
    if (step > 1) {
      ++counters_.frame_id_gaps;
      counters_.frames_lost += step - 1;
    }
  }

  std::size_t size = 0;
  const void* data = arv_buffer_get_image_data(newest, &size);
  gint x_padding = 0, y_padding = 0;
  arv_buffer_get_image_padding(newest, &x_padding, &y_padding);
  const std::size_t stride =
      std::size_t(options_.cols) * std::size_t(bytes_per_pixel_) + std::size_t(x_padding);
  if (!copy_out(data, size, stride, frame)) {
    ++counters_.corrupt;
    arv_stream_push_buffer(a.stream, newest);
    return DeviceStatus::kFault;
  }
  sequence_ = have_id_ ? sequence_ + std::uint32_t(step) : std::uint32_t(id);
  have_id_ = true;
  last_id_ = id;
  frame->sequence = sequence_;
  // The leader's arrival (host CLOCK_REALTIME) on CLOCK_MONOTONIC; the exposure by the camera's
  // clock where it is mapped and believable, else the arrival back to mid-exposure.
  const std::int64_t realtime_minus_monotonic = clock_ns(CLOCK_REALTIME) - clock_ns(CLOCK_MONOTONIC);
  const std::int64_t arrival_ns =
      std::int64_t(arv_buffer_get_system_timestamp(newest)) - realtime_minus_monotonic;
  last_device_timestamp_ns_ = std::int64_t(arv_buffer_get_timestamp(newest));
  last_arrival_timestamp_ns_ = arrival_ns - std::int64_t(options_.leader_latency_ms * 1e6);
  frame->timestamp_ns = last_arrival_timestamp_ns_;
  last_timed_by_device_ = false;
  last_uncertainty_ns_ = 0;
  if (options_.exposure_clock == ExposureClock::kDevice) {
    DeviceClockMap::Mapping m;
    const bool mapped = usable_mapping(clock_ns(CLOCK_MONOTONIC), &m) && last_device_timestamp_ns_ > 0;
    const std::int64_t exposure_ns = last_device_timestamp_ns_ + m.offset_ns;
    if (mapped && exposure_ns <= arrival_ns + m.uncertainty_ns && exposure_ns >= arrival_ns - kMaxReadOutNs) {
      frame->timestamp_ns = exposure_ns;
      last_timed_by_device_ = true;
      last_uncertainty_ns_ = m.uncertainty_ns;
    } else {
      ++counters_.clock_fallbacks;
    }
  }
  arv_stream_push_buffer(a.stream, newest);
  ++counters_.frames;
  return DeviceStatus::kOk;
}

GigeFrameSource::GigeFrameSource(std::vector<GigeDetectorOptions> detectors, double max_skew_ms)
    : max_skew_ms_(max_skew_ms) {
  for (GigeDetectorOptions& o : detectors) detectors_.push_back(std::make_unique<GigeDetector>(std::move(o)));
}

GigeFrameSource::~GigeFrameSource() {
  close();
}

void GigeFrameSource::reopen_loop() {
  std::int64_t synced_ns = clock_ns(CLOCK_MONOTONIC);
  while (!stop_.load()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (!gone_.load()) {
      // A round of clock latches a second: the cycle's acquire() shares the lock meanwhile.
      if (clock_ns(CLOCK_MONOTONIC) - synced_ns < 1'000'000'000) continue;
      synced_ns = clock_ns(CLOCK_MONOTONIC);
      std::shared_lock lock(devices_);
      for (auto& d : detectors_)
        if (d->is_open()) d->sync_clock();
      continue;
    }
    std::lock_guard lock(devices_);  // the cycle gets kDisconnected meanwhile
    if (stop_.load()) break;
    if (reopen_disconnected_locked().ok()) {
      gone_.store(false);
      ++reopens_;
    } else {
      for (int i = 0; i < 5 && !stop_.load(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }
}

Status GigeFrameSource::open(FramePair* pair) {
  if (detectors_.empty()) return invalid_argument("gige frame source: no detectors");
  pair->frames.resize(detectors_.size());
  for (std::size_t i = 0; i < detectors_.size(); ++i) {
    const GigeDetectorOptions& o = detectors_[i]->options();
    Frame& f = pair->frames[i];
    if (f.pixels.rows() != o.rows || f.pixels.cols() != o.cols)
      f.pixels = tracking::Image<std::uint16_t>(o.rows, o.cols);
  }
  for (std::size_t i = 0; i < detectors_.size(); ++i) {
    const Status s = detectors_[i]->open();
    if (!s.ok()) {
      for (std::size_t j = 0; j < i; ++j) detectors_[j]->close();
      return s;
    }
  }
  stop_.store(false);
  gone_.store(false);
  reopener_ = std::thread([this] { reopen_loop(); });
  return {};
}

void GigeFrameSource::request_exposure(std::int64_t exposure_time_ns) {
  bool software = true;
  for (auto& d : detectors_) {
    d->trigger(exposure_time_ns);
    software = software && d->options().trigger == GigeTrigger::kSoftware;
  }
  exposure_ns_ = software ? exposure_time_ns : 0;
}

DeviceStatus GigeFrameSource::acquire(FramePair* pair, Deadline deadline) {
  std::shared_lock lock(devices_, std::try_to_lock);
  if (!lock.owns_lock()) return DeviceStatus::kDisconnected;  // being reopened
  for (std::size_t i = 0; i < detectors_.size(); ++i) {
    GigeDetector& d = *detectors_[i];
    DeviceStatus s = d.capture(&pair->frames[i], deadline);
    // A frame exposed before this exposure was asked for is an earlier one's, late (give or take
    // how far the camera's clock mapping can be off).
    while (s == DeviceStatus::kOk && exposure_ns_ > 0 &&
           pair->frames[i].timestamp_ns < exposure_ns_ - d.last_timestamp_uncertainty_ns()) {
      ++stale_frames_;
      s = detectors_[i]->capture(&pair->frames[i], deadline);
    }
    if (s == DeviceStatus::kDisconnected) gone_.store(true);
    if (s != DeviceStatus::kOk) return s;
  }
  // One clock for the pair: where any frame could not be timed by its camera's clock, every frame
  // is timed by its arrival, so that the skew check never compares an exposure with an arrival.
  bool by_device = true, by_arrival = true;
  for (const auto& d : detectors_) {
    by_device = by_device && d->last_frame_timed_by_device();
    by_arrival = by_arrival && !d->last_frame_timed_by_device();
  }
  if (!by_device && !by_arrival) {
    ++pairs_timed_by_arrival_;
    for (std::size_t i = 0; i < detectors_.size(); ++i)
      pair->frames[i].timestamp_ns = detectors_[i]->last_arrival_timestamp_ns();
  }
  std::int64_t first = pair->frames[0].timestamp_ns, last = first;
  for (const Frame& f : pair->frames) {
    first = std::min(first, f.timestamp_ns);
    last = std::max(last, f.timestamp_ns);
  }
  if (double(last - first) > max_skew_ms_ * 1e6) {
    ++skewed_pairs_;
    return DeviceStatus::kFault;
  }
  return DeviceStatus::kOk;
}

DetectorIdentity GigeFrameSource::identity(std::size_t detector) const {
  if (detector >= detectors_.size()) return {};
  std::shared_lock lock(devices_);  // not while the source's thread reopens it
  const GigeDetector& d = *detectors_[detector];
  const bool fell_back = d.options().exposure_clock == ExposureClock::kDevice && !d.device_clock_mapped();
  return {d.camera(), d.device_id(), d.clock_source(), fell_back};
}

void GigeFrameSource::close() {
  stop_.store(true);
  if (reopener_.joinable()) reopener_.join();
  for (auto& d : detectors_) d->close();
}

Status GigeFrameSource::reopen_disconnected() {
  std::lock_guard lock(devices_);
  const Status s = reopen_disconnected_locked();
  if (s.ok()) gone_.store(false);
  return s;
}

Status GigeFrameSource::reopen_disconnected_locked() {
  for (auto& d : detectors_)
    if (!d->is_open()) LFTRACK_RETURN_IF_ERROR(d->reopen());
  return {};
}

}  // namespace lftrack::drivers

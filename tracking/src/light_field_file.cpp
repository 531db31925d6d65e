// Light-field files: a fixed 1024-byte little-endian header (magic, version, geometry, storage,
// hashes, payload size and CRC-32, header CRC-32) followed by the payload, memory-mapped on load.
//
// Header layout, version 1 (offsets in bytes):
//   0 magic "LFTRKLF\0" | 8 u32 version | 12 u32 header bytes (1024) | 16 u32 storage
//   20 u32 codebook size | 24 i32 size[4] | 40 f64 lo[4] | 72 f64 hi[4] | 104 f64 source[3]
//   128 f64 roi centre[3] | 152 f64 axis[3] | 176 f64 e1[3] | 200 f64 e2[3]
//   224 f64 nominal T_room_from_ct[16] (column-major) | 352 f64 registration origin[3]
//   376 f64 envelope translation mm | 384 f64 envelope rotation deg | 392 f64 fixed scale
//   400 u64 CT hash | 408 u64 plan hash | 416 u64 payload bytes | 424 u32 payload CRC-32
//   428 char view name[64]
//   492 u32 settings recorded (1; 0 in files written before) | 496 u32 integration
//   500 i32 ROI window row0, col0, rows, cols | 516 i32 VQ training tiles | 520 f64 margin fraction
//   528 f64 slice step mm | 536 u64 detector hash | 544 u64 VQ seed
//   ... zero ... | 1020 u32 CRC-32 of bytes 0..1019
// (The settings at 492.. came later in the zero bytes of version 1: older readers skip them.)
// Payload: float32 samples; or uint16 codes; or (VQ) the codebook (K x 16 float32) then one uint16
// codeword index per tile. Samples are ordered [u][v][s][t], t fastest; tiles likewise.

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>

#include "lftrack/tracking/checksum.hpp"
#include "lftrack/tracking/light_field.hpp"

namespace lftrack::tracking {
namespace {

constexpr char kMagic[8] = {'L', 'F', 'T', 'R', 'K', 'L', 'F', '\0'};
constexpr std::uint32_t kVersion = 1;
constexpr std::size_t kHeaderBytes = 1024;

class HeaderWriter {
 public:
  explicit HeaderWriter(unsigned char* buffer) : b_(buffer) {}
  template <class T>
  void at(std::size_t offset, const T& value) {
    std::memcpy(b_ + offset, &value, sizeof(T));
  }
  void vec(std::size_t offset, const Eigen::Vector3d& v) {
    for (int i = 0; i < 3; ++i) at(offset + 8 * i, v[i]);
  }

 private:
  unsigned char* b_;
};

class HeaderReader {
 public:
  explicit HeaderReader(const unsigned char* buffer) : b_(buffer) {}
  template <class T>
  T at(std::size_t offset) const {
    T value;
    std::memcpy(&value, b_ + offset, sizeof(T));
    return value;
  }
  Eigen::Vector3d vec(std::size_t offset) const {
    return {at<double>(offset), at<double>(offset + 8), at<double>(offset + 16)};
  }

 private:
  const unsigned char* b_;
};

std::size_t tile_count(const std::array<int, 4>& size) {
  std::size_t n = 1;
  for (int s : size) n *= static_cast<std::size_t>((s + 1) / 2);
  return n;
}

std::size_t expected_payload(const LightField::Header& h) {
  const auto samples = static_cast<std::size_t>(h.geometry.sample_count());
  switch (h.storage) {
    case LightFieldStorage::kFloat32:
      return samples * 4;
    case LightFieldStorage::kFixed16:
      return samples * 2;
    case LightFieldStorage::kVq:
      return std::size_t(h.codebook_size) * 64 + tile_count(h.geometry.size) * 2;
  }
  return 0;
}

// What the renderers read without a check, checked once here: float samples and codebook entries
// finite (a NaN under a valid CRC was written that way, or by someone else), every VQ code inside
// the codebook, a fixed-point scale finite and positive. Returns the first problem.
Status check_payload(const LightField::Header& h, const unsigned char* payload) {
  // A sample is a line integral of attenuation (mu x mm): never meaningfully negative, and no
  // patient reaches 10^4 (steel, 50 mm: about 25).
  auto first_not_a_line_integral = [](const unsigned char* p, std::size_t count) {
    for (std::size_t i = 0; i < count; ++i) {
      float v;
      std::memcpy(&v, p + 4 * i, 4);
      if (!(v >= -1.0f && v <= 1e4f)) return i;
    }
    return count;
  };
  switch (h.storage) {
    case LightFieldStorage::kFloat32: {
      const auto count = static_cast<std::size_t>(h.geometry.sample_count());
      if (const std::size_t i = first_not_a_line_integral(payload, count); i < count)
        return corrupt_data("sample " + std::to_string(i) +
                            " is not a line integral (NaN, infinite or outside [-1, 1e4]) under a valid checksum");
      return {};
    }
    case LightFieldStorage::kFixed16:
      if (!std::isfinite(h.fixed_scale) || !(h.fixed_scale > 0))
        return corrupt_data("the fixed-point scale is not a finite positive number");
      return {};
    case LightFieldStorage::kVq: {
      const std::size_t entries = std::size_t(h.codebook_size) * 16;
      if (const std::size_t i = first_not_a_line_integral(payload, entries); i < entries)
        return corrupt_data("codebook entry " + std::to_string(i / 16) +
                            " is not a line integral (NaN, infinite or outside [-1, 1e4])");
      const unsigned char* codes = payload + std::size_t(h.codebook_size) * 64;
      const std::size_t tiles = tile_count(h.geometry.size);
      for (std::size_t t = 0; t < tiles; ++t) {
        std::uint16_t code;
        std::memcpy(&code, codes + 2 * t, 2);
        if (code >= h.codebook_size)
          return corrupt_data("tile " + std::to_string(t) + " names codebook entry " + std::to_string(code) +
                              " of " + std::to_string(h.codebook_size));
      }
      return {};
    }
  }
  return corrupt_data("unknown storage mode");
}

std::string hex(std::uint64_t v) {
  std::ostringstream s;
  s << std::hex << v;
  return s.str();
}

}  // namespace

LightField::~LightField() {
  if (mapping_) munmap(mapping_, mapping_bytes_);
}

void LightField::point_at(const unsigned char* payload) {
  f32_ = nullptr;
  q16_ = nullptr;
  codebook_ = nullptr;
  codes_ = nullptr;
  switch (header_.storage) {
    case LightFieldStorage::kFloat32:
      f32_ = reinterpret_cast<const float*>(payload);
      break;
    case LightFieldStorage::kFixed16:
      q16_ = reinterpret_cast<const std::uint16_t*>(payload);
      break;
    case LightFieldStorage::kVq:
      codebook_ = reinterpret_cast<const float*>(payload);
      codes_ = reinterpret_cast<const std::uint16_t*>(payload + std::size_t(header_.codebook_size) * 64);
      break;
  }
}

float LightField::sample(int iu, int iv, int is, int it) const {
  const auto& s = header_.geometry.size;
  switch (header_.storage) {
    case LightFieldStorage::kFloat32:
      return f32_[((std::size_t(iu) * s[1] + iv) * s[2] + is) * s[3] + it];
    case LightFieldStorage::kFixed16:
      return static_cast<float>(q16_[((std::size_t(iu) * s[1] + iv) * s[2] + is) * s[3] + it] *
                                header_.fixed_scale);
    case LightFieldStorage::kVq: {
      const std::size_t tv = (s[1] + 1) / 2, ts = (s[2] + 1) / 2, tt = (s[3] + 1) / 2;
      const std::size_t tile = ((std::size_t(iu >> 1) * tv + (iv >> 1)) * ts + (is >> 1)) * tt + (it >> 1);
      const int element = ((iu & 1) << 3) | ((iv & 1) << 2) | ((is & 1) << 1) | (it & 1);
      return codebook_[std::size_t(codes_[tile]) * 16 + element];
    }
  }
  return 0.0f;
}

Status LightField::save(const std::filesystem::path& file) const {
  unsigned char header[kHeaderBytes] = {};
  HeaderWriter w(header);
  const LightFieldGeometry& g = header_.geometry;
  std::memcpy(header, kMagic, 8);
  w.at(8, kVersion);
  w.at(12, static_cast<std::uint32_t>(kHeaderBytes));
  w.at(16, static_cast<std::uint32_t>(header_.storage));
  w.at(20, static_cast<std::uint32_t>(header_.codebook_size));
  for (int a = 0; a < 4; ++a) {
    w.at(24 + 4 * a, static_cast<std::int32_t>(g.size[a]));
    w.at(40 + 8 * a, g.lo[a]);
    w.at(72 + 8 * a, g.hi[a]);
  }
  w.vec(104, g.source_ct_mm);
  w.vec(128, g.roi_centre_ct_mm);
  w.vec(152, g.axis);
  w.vec(176, g.e1);
  w.vec(200, g.e2);
  for (int i = 0; i < 16; ++i) w.at(224 + 8 * i, header_.nominal_T_room_from_ct.matrix().data()[i]);
  w.vec(352, header_.registration_origin_room_mm);
  w.at(376, header_.envelope.translation_mm);
  w.at(384, header_.envelope.rotation_deg);
  w.at(392, header_.fixed_scale);
  w.at(400, header_.ct_hash);
  w.at(408, header_.plan_hash);
  w.at(416, static_cast<std::uint64_t>(payload_bytes_));
  const unsigned char* payload =
      mapping_ ? static_cast<const unsigned char*>(mapping_) + kHeaderBytes : owned_.data();
  w.at(424, crc32_of(payload, payload_bytes_));
  std::strncpy(reinterpret_cast<char*>(header + 428), g.view_name.c_str(), 63);
  if (header_.settings_recorded) {
    w.at(492, std::uint32_t{1});
    w.at(496, static_cast<std::uint32_t>(header_.integration));
    w.at(500, static_cast<std::int32_t>(header_.roi_window.row0));
    w.at(504, static_cast<std::int32_t>(header_.roi_window.col0));
    w.at(508, static_cast<std::int32_t>(header_.roi_window.rows));
    w.at(512, static_cast<std::int32_t>(header_.roi_window.cols));
    w.at(516, static_cast<std::int32_t>(header_.vq_training_tiles));
    w.at(520, header_.margin_fraction);
    w.at(528, header_.slice_step_mm);
    w.at(536, header_.detector_hash);
    w.at(544, header_.vq_seed);
  }
  w.at(1020, crc32_of(header, 1020));

  // Per process: two processes saving the same field (tasks of a job array) never share a
  // half-written file.
  const std::filesystem::path partial = file.string() + "." + std::to_string(getpid()) + ".partial";
  const auto failed = [&](const std::string& why) {  // a failed save leaves nothing behind
    std::error_code ignored;
    std::filesystem::remove(partial, ignored);
    return io_error(file.string() + ": " + why);
  };
  {
    std::ofstream out(partial, std::ios::binary | std::ios::trunc);
    if (!out) return io_error(file.string() + ": cannot open for writing");
    out.write(reinterpret_cast<const char*>(header), kHeaderBytes);
    out.write(reinterpret_cast<const char*>(payload), static_cast<std::streamsize>(payload_bytes_));
    out.close();
    if (!out) return failed("write failed");
  }
  std::error_code ec;
  std::filesystem::rename(partial, file, ec);  // a reader never sees a half-written file
  if (ec) return failed("cannot rename into place: " + ec.message());
  return {};
}

namespace {

// Decodes and checks the 1024 header bytes at `data` (of the file `name`) into `h`.
Status decode_header(const unsigned char* data, const std::string& name, LightField::Header* out) {
  const HeaderReader r(data);
  if (std::memcmp(data, kMagic, 8) != 0) return corrupt_data(name + ": not a light-field file (bad magic)");
  const auto version = r.at<std::uint32_t>(8);
  if (version != kVersion) {
    return unsupported(name + ": unknown light-field file version " + std::to_string(version) +
                       " (this build reads version " + std::to_string(kVersion) +
                       "); run `lftrack precompute` again");
  }
  if (r.at<std::uint32_t>(1020) != crc32_of(data, 1020)) {
    return corrupt_data(name + ": header is corrupted (checksum mismatch)");
  }
  LightField::Header& h = *out;
  LightFieldGeometry& g = h.geometry;
  const auto storage = r.at<std::uint32_t>(16);
  if (storage > 2) return corrupt_data(name + ": unknown storage mode " + std::to_string(storage));
  h.storage = static_cast<LightFieldStorage>(storage);
  h.codebook_size = static_cast<int>(r.at<std::uint32_t>(20));
  for (int a = 0; a < 4; ++a) {
    g.size[a] = r.at<std::int32_t>(24 + 4 * a);
    g.lo[a] = r.at<double>(40 + 8 * a);
    g.hi[a] = r.at<double>(72 + 8 * a);
  }
  g.source_ct_mm = r.vec(104);
  g.roi_centre_ct_mm = r.vec(128);
  g.axis = r.vec(152);
  g.e1 = r.vec(176);
  g.e2 = r.vec(200);
  for (int i = 0; i < 16; ++i) h.nominal_T_room_from_ct.matrix().data()[i] = r.at<double>(224 + 8 * i);
  h.registration_origin_room_mm = r.vec(352);
  h.envelope.translation_mm = r.at<double>(376);
  h.envelope.rotation_deg = r.at<double>(384);
  h.fixed_scale = r.at<double>(392);
  h.ct_hash = r.at<std::uint64_t>(400);
  h.plan_hash = r.at<std::uint64_t>(408);
  char view_name[65] = {};
  std::memcpy(view_name, data + 428, 64);
  g.view_name = view_name;
  h.settings_recorded = r.at<std::uint32_t>(492) == 1;
  if (h.settings_recorded) {
    const auto integration = r.at<std::uint32_t>(496);
    if (integration > 1) return corrupt_data(name + ": unknown integration " + std::to_string(integration));
    h.integration = static_cast<LightFieldIntegration>(integration);
    h.roi_window = {r.at<std::int32_t>(500), r.at<std::int32_t>(504), r.at<std::int32_t>(508), r.at<std::int32_t>(512)};
    h.vq_training_tiles = r.at<std::int32_t>(516);
    h.margin_fraction = r.at<double>(520);
    h.slice_step_mm = r.at<double>(528);
    h.detector_hash = r.at<std::uint64_t>(536);
    h.vq_seed = r.at<std::uint64_t>(544);
  }
  if (Status s = g.validate(); !s.ok()) return s.with_context(name);
  // The pose and envelope the field was planned for: what the plan hash cannot vouch for when a
  // field is loaded without one (an outside probe loaded NaN envelopes and poses).
  const Eigen::Matrix3d R = h.nominal_T_room_from_ct.linear();
  if (!h.nominal_T_room_from_ct.matrix().allFinite() ||
      !(R.transpose() * R).isApprox(Eigen::Matrix3d::Identity(), 1e-6) ||
      !h.registration_origin_room_mm.allFinite() || !(h.envelope.translation_mm > 0 && h.envelope.translation_mm <= 50) ||
      !(h.envelope.rotation_deg > 0 && h.envelope.rotation_deg <= 45))
    return corrupt_data(name + ": the header's nominal pose, registration origin or envelope is not a valid one "
                        "(non-finite, not a rotation, or an envelope beyond 50 mm / 45 degrees)");
  if (h.storage == LightFieldStorage::kVq && (h.codebook_size < 1 || h.codebook_size > 65536)) {
    return corrupt_data(name + ": bad codebook size");
  }
  return {};
}

// Opens `file` for reading without blocking on a FIFO or device; refuses what is not a regular
// file. `size` gets its bytes.
Result<int> open_regular(const std::string& name, std::size_t* size) {
  const int fd = ::open(name.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) return not_found(name + ": cannot open light-field file (run `lftrack precompute`)");
  struct stat st {};
  if (fstat(fd, &st) != 0) {
    ::close(fd);
    return io_error(name + ": cannot stat");
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    return corrupt_data(name + ": not a regular file (a FIFO, device or folder); a light field is a file written by "
                        "`lftrack precompute`");
  }
  *size = static_cast<std::size_t>(st.st_size);
  if (*size < kHeaderBytes) {
    ::close(fd);
    return corrupt_data(name + ": truncated light-field file (" + std::to_string(*size) +
                        " bytes; the header alone is 1024)");
  }
  return fd;
}

}  // namespace

Result<LightField::Header> LightField::read_header(const std::filesystem::path& file) {
  const std::string name = file.string();
  std::size_t bytes = 0;
  auto fd = open_regular(name, &bytes);
  if (!fd.ok()) return fd.status();
  unsigned char data[kHeaderBytes];
  const ssize_t got = ::pread(*fd, data, kHeaderBytes, 0);
  ::close(*fd);
  if (got != static_cast<ssize_t>(kHeaderBytes)) return io_error(name + ": cannot read the header");
  Header h;
  LFTRACK_RETURN_IF_ERROR(decode_header(data, name, &h));
  return h;
}

Result<std::shared_ptr<const LightField>> LightField::load(const std::filesystem::path& file,
                                                           std::optional<std::uint64_t> expected_ct_hash,
                                                           std::optional<std::uint64_t> expected_plan_hash) {
  const std::string name = file.string();
  // Non-blocking: a FIFO or device named A.lf must not hang the program on open.
  std::size_t bytes = 0;
  auto fd = open_regular(name, &bytes);
  if (!fd.ok()) return fd.status();
  void* map = mmap(nullptr, bytes, PROT_READ, MAP_PRIVATE, *fd, 0);
  ::close(*fd);
  if (map == MAP_FAILED) return io_error(name + ": cannot memory-map");
  std::shared_ptr<LightField> field(new LightField);
  field->mapping_ = map;
  field->mapping_bytes_ = bytes;
  const auto* data = static_cast<const unsigned char*>(map);
  const HeaderReader r(data);
  LFTRACK_RETURN_IF_ERROR(decode_header(data, name, &field->header_));
  Header& h = field->header_;
  const std::size_t payload = expected_payload(h);
  const std::uint64_t payload_field = r.at<std::uint64_t>(416);
  if (payload_field != payload) {
    return corrupt_data(name + ": the header's payload size (" + std::to_string(payload_field) +
                        " bytes) disagrees with its own geometry and storage, which need " + std::to_string(payload) +
                        " bytes");
  }
  if (bytes != kHeaderBytes + payload) {
    return corrupt_data(name + ": " + (bytes < kHeaderBytes + payload ? "truncated" : "padded") + ": the file has " +
                        std::to_string(bytes) + " bytes, the 1024-byte header and its " + std::to_string(payload) +
                        "-byte payload make " + std::to_string(kHeaderBytes + payload));
  }
  if (r.at<std::uint32_t>(424) != crc32_of(data + kHeaderBytes, payload)) {
    return corrupt_data(name + ": sample data is corrupted (checksum mismatch)");
  }
  if (Status s = check_payload(h, data + kHeaderBytes); !s.ok()) return s.with_context(name);
  if (expected_ct_hash && *expected_ct_hash != h.ct_hash) {
    return failed_precondition(name + ": built for another CT (CT hash " + hex(h.ct_hash) + ", this CT has " +
                               hex(*expected_ct_hash) + "); run `lftrack precompute` again");
  }
  if (expected_plan_hash && *expected_plan_hash != h.plan_hash) {
    return failed_precondition(
        name +
        ": built for another geometry or light-field settings (view, ROI, pose, envelope or "
        "resolution changed, or an older lftrack planned it); run `lftrack precompute` again");
  }
  field->payload_bytes_ = payload;
  field->point_at(data + kHeaderBytes);
  return std::shared_ptr<const LightField>(field);
}

}  // namespace lftrack::tracking

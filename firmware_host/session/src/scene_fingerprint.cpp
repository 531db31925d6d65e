#include "lftrack/host/scene_fingerprint.hpp"

#include <openssl/sha.h>

#include <filesystem>
#include <sstream>

#include "lftrack/host/scene_devices.hpp"

namespace lftrack::host {

namespace {
std::array<std::uint8_t, 16> first_16_of_sha256(const std::string& text) {
  unsigned char hash[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(text.data()), text.size(), hash);
  std::array<std::uint8_t, 16> out{};
  for (std::size_t i = 0; i < out.size(); ++i) out[i] = hash[i];
  if (out == std::array<std::uint8_t, 16>{}) out[15] = 1;  // zeros are "not recorded" (odds 2^-128)
  return out;
}
}  // namespace

std::string room_geometry_text(const Scene& scene) {
  std::ostringstream geometry;
  geometry.precision(17);
  for (const DetectorSpec& d : scene.detectors) {
    const tracking::XrayView& v = d.view;
    geometry << v.name << ' ' << v.rows << ' ' << v.cols << ' ' << v.pitch_row_mm << ' ' << v.pitch_col_mm << ' '
             << v.source_mm.transpose() << ' ' << v.pixel00_mm.transpose() << ' ' << v.row_axis.transpose() << ' '
             << v.col_axis.transpose() << '\n';
  }
  return geometry.str();
}

std::array<std::uint8_t, 16> scene_fingerprint(const Scene& scene) {
  std::string ct = scene.ct.path;
  if (scene.ct.is_builtin_phantom()) {
    ct += " seed " + std::to_string(scene.ct.phantom_seed);
  } else {
    std::error_code ec;
    const std::filesystem::path canonical = std::filesystem::weakly_canonical(scene.ct.path, ec);
    if (!ec) ct = canonical.string();
  }
  return first_16_of_sha256("lftrack scene\nct " + ct + "\n" + room_geometry_text(scene));
}

std::array<std::uint8_t, 16> room_fingerprint(const Scene& scene) {
  // The devices too: a scene with real detectors at the QA phantom's geometry is another room.
  std::string devices = "actuator " + describe_actuator(scene.actuator) + " calibration " +
                        scene.actuator.calibration_file + "\n";
  for (const DetectorSpec& d : scene.detectors)
    devices += "detector " + d.view.name + " " + describe_frames(d.frames) + " calibration " +
               (d.simulator_calibration ? std::string("simulator") : d.calibration_file) + "\n";
  return first_16_of_sha256("lftrack room\n" + devices + room_geometry_text(scene));
}

std::string to_hex(const std::array<std::uint8_t, 16>& fingerprint) {
  static const char* kDigits = "0123456789abcdef";
  std::string hex;
  for (std::uint8_t b : fingerprint) {
    hex.push_back(kDigits[b >> 4]);
    hex.push_back(kDigits[b & 15]);
  }
  return hex;
}

}  // namespace lftrack::host

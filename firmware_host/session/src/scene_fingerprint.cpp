#include "lftrack/session/scene_fingerprint.hpp"

#include <openssl/evp.h>
#include <openssl/sha.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>

#include "lftrack/session/scene_devices.hpp"
#include "lftrack/tracking/version.hpp"

namespace lftrack::session {

namespace {
std::array<std::uint8_t, 16> first_16_of_sha256(const std::string& text) {
  unsigned char hash[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(text.data()), text.size(), hash);
  std::array<std::uint8_t, 16> out{};
  for (std::size_t i = 0; i < out.size(); ++i) out[i] = hash[i];
  if (out == std::array<std::uint8_t, 16>{}) out[15] = 1;  // zeros are "not recorded" (odds 2^-128)
  return out;
}
// SHA-256 of the file's bytes in hex, read in blocks (a calibration can be large); empty when no
// file is named, "unreadable" when it cannot be read (the fingerprint then differs from a QA's
// that could read it).
std::string file_contents_sha256(const std::string& path) {
  if (path.empty()) return {};
  std::ifstream in(path, std::ios::binary);
  if (!in) return "unreadable";
  const std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(), EVP_MD_CTX_free);
  if (!ctx || EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr) != 1) return "unreadable";
  std::vector<char> block(1 << 20);
  while (in) {
    in.read(block.data(), std::streamsize(block.size()));
    if (in.gcount() > 0 && EVP_DigestUpdate(ctx.get(), block.data(), std::size_t(in.gcount())) != 1)
      return "unreadable";
  }
  if (in.bad()) return "unreadable";
  unsigned char hash[EVP_MAX_MD_SIZE];
  unsigned int size = 0;
  if (EVP_DigestFinal_ex(ctx.get(), hash, &size) != 1) return "unreadable";
  static const char* kDigits = "0123456789abcdef";
  std::string hex;
  for (unsigned int i = 0; i < size; ++i) {
    hex.push_back(kDigits[hash[i] >> 4]);
    hex.push_back(kDigits[hash[i] & 15]);
  }
  return hex;
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
  // Calibrations by name and contents: a detector recalibrated since the QA is another detector.
  std::string devices = "actuator " + describe_actuator(scene.actuator) + " calibration " +
                        scene.actuator.calibration_file + " " +
                        file_contents_sha256(scene.actuator.calibration_file) + "\n";
  for (const DetectorSpec& d : scene.detectors)
    devices +=
        "detector " + d.view.name + " " + describe_frames(d.frames) + " calibration " +
        (d.simulator_calibration ? std::string("simulator")
                                 : d.calibration_file + " " + file_contents_sha256(d.calibration_file)) +
        "\n";
  return first_16_of_sha256(std::string("lftrack room\nprogram ") + kVersion + "\n" + devices +
                            room_geometry_text(scene));
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

}  // namespace lftrack::session

#include "lftrack/session/commissioning_file.hpp"

#include <openssl/sha.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/session/scene_fingerprint.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "scene_yaml.hpp"

namespace lftrack::session {

using loop::similarity_expectation;
using loop::VerdictLimits;
namespace fs = std::filesystem;

namespace {

std::string digest(const std::string& text) {
  unsigned char hash[SHA256_DIGEST_LENGTH];
  SHA256(reinterpret_cast<const unsigned char*>(text.data()), text.size(), hash);
  static const char* kDigits = "0123456789abcdef";
  std::string hex;
  for (int i = 0; i < 8; ++i) {
    hex.push_back(kDigits[hash[i] >> 4]);
    hex.push_back(kDigits[hash[i] & 15]);
  }
  return hex;
}

constexpr const char* kParts[] = {"ct", "geometry", "registration", "imaging"};

std::string* part(CommissioningFingerprint* f, int i) {
  std::string* parts[] = {&f->ct, &f->geometry, &f->registration, &f->imaging};
  return parts[i];
}

// A floor as the shortest text that reads back as the same double (what is read back is what
// was tallied).
std::string exact(double v) {
  char text[32];
  const auto [end, error] = std::to_chars(text, text + sizeof text, v);
  return error == std::errc() ? std::string(text, end) : "nan";
}

// The seal: a digest of the whole file but its own line ("seal: ..." at the start of a line), so
// that any edit by hand (a floor, a figure, a key added or repeated) no longer matches it.
constexpr const char* kSealKey = "seal: ";
std::string seal_of_text(const std::string& text_without_seal) {
  return digest("lftrack commissioning seal\n" + text_without_seal);
}
// `text` without its one seal line, and that line's value; false when there is not exactly one.
bool split_seal(const std::string& text, std::string* rest, std::string* seal) {
  std::size_t at = std::string::npos, count = 0;
  for (std::size_t line = 0; line < text.size();) {
    if (text.compare(line, std::strlen(kSealKey), kSealKey) == 0) at = line, ++count;
    const std::size_t end = text.find('\n', line);
    if (end == std::string::npos) break;
    line = end + 1;
  }
  if (count != 1) return false;
  const std::size_t end = text.find('\n', at);
  const std::size_t stop = end == std::string::npos ? text.size() : end + 1;
  *rest = text.substr(0, at) + text.substr(stop);
  std::string value = text.substr(at + std::strlen(kSealKey), stop - at - std::strlen(kSealKey));
  const auto quote = value.find('"'), close = value.find('"', quote + 1);
  *seal = quote == std::string::npos || close == std::string::npos ? "" : value.substr(quote + 1, close - quote - 1);
  return true;
}

const char* kWhatPartHolds[] = {
    "the CT (its voxels, the fiducials inserted)", "the room (detectors, nominal pose, ROI and roi.mask, origin, envelope)",
    "the registration (measure, plans, renderer, light fields, the verdict's other checks)", "the imaging (bits, dose, blur, physics)"};

}  // namespace

CommissioningFingerprint commissioning_fingerprint(const PreparedScene& p) {
  const Scene& s = p.scene;
  std::ostringstream ct, geometry, registration, imaging;
  for (auto* o : {&ct, &geometry, &registration, &imaging}) o->precision(17);
  ct << "mu " << tracking::volume_hash(*p.mu) << " water " << s.ct.mu_water_per_mm << " markers "
     << s.fiducials.insert << ' ' << s.fiducials.radius_mm;
  for (const Eigen::Vector3d& f : s.fiducials.positions_ct_mm) ct << ' ' << f.transpose();
  geometry << room_geometry_text(s) << "nominal " << p.nominal_T_room_from_ct.matrix().reshaped().transpose()
           << "\nroi " << p.roi_centre_ct_mm.transpose() << ' ' << s.roi.size_mm.transpose() << "\norigin "
           << p.registration_origin_ct_mm.transpose() << "\nenvelope " << s.envelope.translation_mm << ' '
           << s.envelope.rotation_deg;
  // roi.mask: which pixels the measures look at (absent: the whole windows, as before it existed).
  for (const tracking::Image<unsigned char>& mask : p.roi_masks) {
    std::uint64_t h = 1469598103934665603ull;  // FNV-1a over the mask's pixels
    for (unsigned char b : mask.pixels()) h = (h ^ b) * 1099511628211ull;
    geometry << "\nroi mask " << mask.rows() << 'x' << mask.cols() << ' ' << h;
  }
  const tracking::LightFieldSpec& lf = s.light_field;
  registration << "measure " << s.registration.similarity << " bins " << s.registration.histogram_bins << " plan "
               << s.registration.plan << " align " << s.loop.align_plan << " track " << s.loop.track_plan
               << " renderer " << s.renderer << " gamma " << s.registration.gamma_per_mm << " tre box "
               << s.registration.tre_box_mm << " light field";
  for (int n : lf.resolution) registration << ' ' << n;
  registration << " margin " << lf.margin_fraction << " integration " << int(lf.integration) << " step "
               << lf.slice_step_mm << " storage " << int(lf.storage) << " codebook " << lf.vq_codebook_size << ' '
               << lf.vq_training_tiles << ' ' << lf.vq_seed;
  if (lf.skip_air_below_hu > -1000)
    registration << " skip air " << lf.skip_air_below_hu;  // records before it stay valid
  // The verdict's other checks decide which wrong results the floors must refuse.
  const VerdictChecksSpec& checks = s.verdict_checks;
  registration << " edge " << checks.envelope_edge_mm << ' ' << checks.envelope_edge_deg << " view shift "
               << checks.max_view_shift_mm;
  // The frames as the detectors make them and as they are corrected: the dose the simulator's AEC
  // set, each detector's calibration (its file's bytes), the physics.
  for (const DetectorSpec& d : s.detectors) {
    imaging << d.view.name << " bits " << d.bits << " calibration ";
    if (d.calibration_file.empty()) {
      imaging << "simulator";
    } else {
      std::ifstream in(d.calibration_file, std::ios::binary);
      std::ostringstream bytes;
      bytes << in.rdbuf();
      imaging << digest(bytes.str());
    }
    imaging << '\n';
  }
  imaging << "photons " << s.sim.photons_per_pixel << " exposure " << p.exposure.photons_per_pixel << ' '
          << p.exposure.open_field_fraction << " blur " << s.sim.detector_blur_px << " physics "
          << s.sim.physics_name << ": " << sim_spec::describe(s.sim.physics);
  return {digest(ct.str()), digest(geometry.str()), digest(registration.str()), digest(imaging.str())};
}

Result<CommissioningRecord> read_commissioning_file(const fs::path& file) {
  std::error_code ec;
  if (!fs::exists(file, ec)) return not_found(file.string() + ": no commissioning file");
  if (!fs::is_regular_file(file, ec))
    return invalid_argument(file.string() + ": not a regular file (a folder, a device or a pipe)");
  const auto size = fs::file_size(file, ec);
  if (ec || size > (1 << 20)) return invalid_argument(file.string() + ": not a commissioning file (over 1 MiB)");
  std::string text;
  {
    std::ifstream in(file, std::ios::binary);
    std::ostringstream bytes;
    bytes << in.rdbuf();
    text = bytes.str();
  }
  const auto bad = [&](const std::string& why) {
    return invalid_argument(file.string() + ": " + why + " (write it with `lftrack commission`, not by hand)");
  };
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception&) {
    return bad("not YAML");
  }
  std::string unsealed, seal;
  if (!split_seal(text, &unsealed, &seal)) return bad("not one seal line");
  CommissioningRecord r;
  try {  // every look into the document: a complex key or a node of the wrong kind throws
    if (!root.IsMap() || !root["lftrack_commissioning"]) return bad("not an lftrack commissioning file");
    if (root["lftrack_commissioning"].as<int>() != 1) return bad("an unknown commissioning file version");
    const YAML::Node fingerprint = root["fingerprint"], floors = root["floors"];
    if (!fingerprint.IsMap() || !floors.IsMap()) return bad("no fingerprint or floors");
    for (int i = 0; i < 4; ++i) {
      if (!fingerprint[kParts[i]]) return bad(std::string("no fingerprint.") + kParts[i]);
      *part(&r.fingerprint, i) = fingerprint[kParts[i]].as<std::string>();
    }
    if (!root["measure"] || !floors["min_similarity"] || !floors["min_check_ncc"])
      return bad("no measure, floors.min_similarity or floors.min_check_ncc");
    r.measure = root["measure"].as<std::string>();
    r.min_similarity = floors["min_similarity"].as<double>();
    r.min_check_ncc = floors["min_check_ncc"].as<double>();
    if (floors["max_view_shift_mm"]) r.max_view_shift_mm = floors["max_view_shift_mm"].as<double>();
    if (!root["seal"] || root["seal"].as<std::string>() != seal || seal != seal_of_text(unsealed))
      return bad("edited by hand: its seal does not match its text");
    if (root["scene"]) r.scene = root["scene"].as<std::string>();
    if (root["made_utc"]) r.made_utc = root["made_utc"].as<std::string>();
    if (root["command"]) r.command = root["command"].as<std::string>();
  } catch (const YAML::Exception& e) {
    return bad(std::string("a value of the wrong kind: ") + e.what());
  }
  if (!std::isfinite(r.min_similarity) || !std::isfinite(r.min_check_ncc) || r.min_check_ncc <= 0 ||
      r.min_check_ncc >= 1)
    return bad("floors out of range (min_check_ncc must lie in (0, 1), both finite)");
  if (!(r.max_view_shift_mm >= 0 && r.max_view_shift_mm <= 20))
    return bad("floors.max_view_shift_mm out of range (0 to 20 mm)");
  // No floor below what commissioning may choose: halfway between what unrelated images score
  // and the measure's default (a floor lower than that would switch the check off).
  const auto expected = similarity_expectation(r.measure);
  if (!expected.ok()) return bad("an unknown measure '" + r.measure + "'");
  const double lowest_similarity =
      expected->no_information + 0.5 * (expected->min_similarity - expected->no_information);
  const double lowest_check = 0.5 * VerdictLimits{}.min_check_ncc;
  if (r.min_similarity < lowest_similarity - 1e-12 || r.min_check_ncc < lowest_check - 1e-12)
    return bad("floors below what commissioning chooses (" + r.measure + " at least " + exact(lowest_similarity) +
               ", check NCC at least " + exact(lowest_check) + ")");
  return r;
}

Status write_commissioning_file(const fs::path& file, const CommissioningRecord& r, const std::string& measured_yaml,
                                bool replace) {
  std::error_code ec;
  if (!replace && fs::exists(fs::symlink_status(file, ec)))
    return failed_precondition(file.string() + ": exists; say --replace to commission the scene again over it");
  std::ostringstream out;
  out.precision(6);
  out << "# The registration verdict's floors for one scene, measured by `lftrack commission`.\n"
      << "# Not to be edited: the loop and `lftrack register` refuse the scene once its CT, room,\n"
      << "# registration or imaging differ from the fingerprint below; commission it again then.\n"
      << "lftrack_commissioning: 1\n"
      << "scene: " << yaml_quoted(r.scene) << "\n"
      << "made_utc: " << r.made_utc << "\n"
      << "command: " << yaml_quoted(r.command) << "\n"
      << "fingerprint:\n";
  for (int i = 0; i < 4; ++i)
    out << "  " << kParts[i] << ": \"" << *part(const_cast<CommissioningFingerprint*>(&r.fingerprint), i) << "\"\n";
  out << "measure: " << r.measure << "\n"
      << "floors:                    # per view, at the registration's result\n"
      << "  min_similarity: " << exact(r.min_similarity) << "   # " << r.measure << "\n"
      << "  min_check_ncc: " << exact(r.min_check_ncc) << "    # NCC of the frame against the DRR\n";
  if (r.max_view_shift_mm != 0)  // 0: the scene has no view check
    out << "  max_view_shift_mm: " << exact(r.max_view_shift_mm) << "   # each view registered alone\n";
  const std::string head = out.str();
  const std::string sealed = head + measured_yaml;
  const std::string text = head + kSealKey + "\"" + seal_of_text(sealed) +
                           "\"   # of every other line: an edit by hand breaks it\n" + measured_yaml;
  const fs::path temp = file.string() + ".partial-" + std::to_string(::getpid());
  {
    std::ofstream f(temp, std::ios::trunc);
    if (!f) return io_error(temp.string() + ": cannot write");
    f << text;
    f.flush();
    if (!f) {
      fs::remove(temp, ec);
      return io_error(temp.string() + ": write failed (disk full?)");
    }
  }
  ec.clear();  // symlink_status above reports a missing file through it
  if (replace) {
    fs::rename(temp, file, ec);
  } else if (::link(temp.c_str(), file.c_str()) != 0) {  // fails, never replaces, if a file appeared
    ec = std::error_code(errno, std::generic_category());
  }
  std::error_code removed;
  if (!replace || ec) fs::remove(temp, removed);
  if (ec) return io_error(file.string() + ": cannot write: " + ec.message());
  return {};
}

Status check_commissioning_current(const PreparedScene& p, const CommissioningRecord& r, const fs::path& file) {
  const CommissioningFingerprint now = commissioning_fingerprint(p);
  if (now == r.fingerprint && r.measure == p.scene.registration.similarity) return {};
  std::string changed;
  for (int i = 0; i < 4; ++i)
    if (*part(const_cast<CommissioningFingerprint*>(&now), i) !=
        *part(const_cast<CommissioningFingerprint*>(&r.fingerprint), i))
      changed += std::string(changed.empty() ? "" : "; ") + kWhatPartHolds[i];
  if (r.measure != p.scene.registration.similarity)
    changed += std::string(changed.empty() ? "" : "; ") + "the measure (" + r.measure + " commissioned, " +
               p.scene.registration.similarity + " now)";
  return failed_precondition(file.string() + ": commissioned for another scene than " + p.scene.source +
                             ": differs in " + changed + ". Its floors do not hold here; commission it again: "
                             "lftrack commission --scene " + p.scene.source + " --replace");
}

}  // namespace lftrack::session

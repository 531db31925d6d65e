#include "lftrack/session/detector_calibration_file.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>

#include "detector_calibration_tiff.hpp"
#include "lftrack/tracking/frame_preprocessing.hpp"

namespace lftrack::session {

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
namespace tiff = calibration_tiff;

constexpr const char* kFormat = "lftrack detector calibration";
constexpr int kMaxSide = 16384;
constexpr std::size_t kMaxDescription = std::size_t(1) << 20;

json metadata(const calib::DetectorCalibration& c, const std::string& hash, const std::string& created) {
  const calib::DetectorCalibrationOptions& o = c.rule;
  json rule = {{"text", calib::describe_defect_rule(o)},
               {"dark_sd", o.dark_sd},
               {"noise_sd", o.noise_sd},
               {"gain_low", o.gain_low},
               {"gain_high", o.gain_high},
               {"line_low", o.line_low},
               {"line_high", o.line_high},
               {"line_defect_fraction", o.line_defect_fraction},
               {"max_saturated_fraction", o.max_saturated_fraction},
               {"min_signal_counts", o.min_signal_counts},
               {"max_unlit_fraction", o.max_unlit_fraction},
               {"min_dark_frames", o.min_dark_frames},
               {"min_flood_frames", o.min_flood_frames},
               {"bits", o.bits}};
  json defects = json::object();
  for (int r = 0; r < calib::kDefectRules; ++r) defects[calib::defect_rule_name(r)] = c.defects_by_rule[std::size_t(r)];
  defects["masked"] = c.defects;
  return {{"format", kFormat},
          {"version", kDetectorCalibrationVersion},
          {"pages", {tiff::kPageNames[0], tiff::kPageNames[1], tiff::kPageNames[2], tiff::kPageNames[3]}},
          {"detector", c.detector},
          {"rows", c.rows},
          {"cols", c.cols},
          {"dark_frames", c.dark_frames},
          {"flood_frames", c.flood_frames},
          {"open_field_counts", c.open_field_counts},
          {"saturation_counts", c.saturation_counts},
          {"saturation_source", c.saturation_source},
          {"offset_median_counts", c.offset_median_counts},
          {"noise_median_counts", c.noise_median_counts},
          {"defect_rule", rule},
          {"defects", defects},
          {"hash_algorithm", "FNV-1a 64"},
          {"content_hash", hash},
          {"created", created}};
}

// Reads typed, bounded values from a JSON object; the first problem is kept (with the key's
// path) and later reads return defaults.
class MetaReader {
 public:
  MetaReader(const json& j, std::string prefix, Status* error) : j_(j), prefix_(std::move(prefix)), error_(error) {}

  const json* find(const char* key) {
    if (!error_->ok()) return nullptr;
    const auto it = j_.find(key);
    if (it == j_.end()) {
      fail(key, "is missing");
      return nullptr;
    }
    return &*it;
  }
  long long integer(const char* key, long long lo, long long hi) {
    const json* v = find(key);
    if (v == nullptr) return lo;
    if (!v->is_number_integer()) return fail(key, "is not an integer"), lo;
    const long long x = v->is_number_unsigned() && v->get<unsigned long long>() >
                                                      static_cast<unsigned long long>(std::numeric_limits<long long>::max())
                            ? std::numeric_limits<long long>::max()
                            : v->get<long long>();
    if (x < lo || x > hi) return fail(key, "is " + std::to_string(x) + ", outside [" + std::to_string(lo) + ", " + std::to_string(hi) + "]"), lo;
    return x;
  }
  double number(const char* key, double lo, double hi) {
    const json* v = find(key);
    if (v == nullptr) return lo;
    if (!v->is_number()) return fail(key, "is not a number"), lo;
    const double x = v->get<double>();
    if (!(std::isfinite(x) && x >= lo && x <= hi)) return fail(key, "is " + v->dump() + ", outside [" + json(lo).dump() + ", " + json(hi).dump() + "]"), lo;
    return x;
  }
  std::string text(const char* key) {
    const json* v = find(key);
    if (v == nullptr) return {};
    if (!v->is_string()) return fail(key, "is not a string"), std::string();
    return v->get<std::string>();
  }
  void fail(const char* key, const std::string& why) {
    if (error_->ok()) *error_ = corrupt_data("metadata key '" + prefix_ + key + "' " + why);
  }

 private:
  const json& j_;
  std::string prefix_;
  Status* error_;
};

Status check_maps(const calib::DetectorCalibration& c) {
  if (c.rows < 1 || c.cols < 1 || c.rows > kMaxSide || c.cols > kMaxSide)
    return invalid_argument("detector calibration of " + std::to_string(c.cols) + " x " + std::to_string(c.rows) +
                            " pixels (1 to 16384 a side)");
  const std::size_t n = std::size_t(c.rows) * std::size_t(c.cols);
  const auto sized = [&](const auto& image) {
    return image.rows() == c.rows && image.cols() == c.cols && image.pixels().size() == n;
  };
  if (!sized(c.offset_counts) || !sized(c.gain) || !sized(c.noise_counts) || !sized(c.defective))
    return invalid_argument("detector calibration: a map of another size than " + std::to_string(c.cols) + " x " +
                            std::to_string(c.rows));
  for (std::size_t i = 0; i < n; ++i) {
    const float o = c.offset_counts.pixels()[i], g = c.gain.pixels()[i], s = c.noise_counts.pixels()[i];
    if (!std::isfinite(o) || !std::isfinite(g) || !std::isfinite(s))
      return invalid_argument("detector calibration: a non-finite value in a map");
    if (g < 0 || s < 0) return invalid_argument("detector calibration: a negative gain or noise");
    if (c.defective.pixels()[i] > 1) return invalid_argument("detector calibration: a defect flag other than 0 or 1");
  }
  if (!(std::isfinite(c.open_field_counts) && c.open_field_counts > 0 && c.open_field_counts <= 65535))
    return invalid_argument("detector calibration: open-field counts must be finite, (0, 65535]");
  if (c.saturation_counts < 1 || c.saturation_counts > 65535)
    return invalid_argument("detector calibration: saturation must be 1 to 65535 counts");
  if (!std::isfinite(c.offset_median_counts) || !std::isfinite(c.noise_median_counts))
    return invalid_argument("detector calibration: non-finite medians");
  return calib::check_detector_calibration_options(c.rule);
}

}  // namespace

Status write_detector_calibration(const fs::path& path, const calib::DetectorCalibration& c, bool overwrite) {
  if (path.empty() || !path.has_filename())
    return invalid_argument(path.string() + " names a folder, not a calibration file");
  struct stat st {};
  if (::lstat(path.c_str(), &st) == 0) {
    if (S_ISDIR(st.st_mode)) return invalid_argument(path.string() + " is a directory; name a file");
    if (!overwrite) return failed_precondition(path.string() + " exists; give --overwrite to replace it");
    if (!S_ISREG(st.st_mode)) return failed_precondition(path.string() + " is not a regular file (a link?); not replaced");
  }
  const fs::path parent = path.has_parent_path() ? path.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(parent, ec)) return not_found("the folder " + parent.string() + " does not exist");
  LFTRACK_RETURN_IF_ERROR(check_maps(c).with_context("not written"));
  const std::string hash = calib::detector_calibration_hash(c);
  const std::string description = metadata(c, hash, utc_now()).dump();
  const fs::path temporary = path.string() + ".partial-" + std::to_string(::getpid());
  Status s = tiff::write_tiff(temporary, c, description);
  if (s.ok()) {
    if (overwrite) {
      if (::rename(temporary.c_str(), path.c_str()) != 0)
        s = io_error("cannot move the calibration to " + path.string() + ": " + std::strerror(errno));
    } else if (::link(temporary.c_str(), path.c_str()) != 0) {
      // link() refuses an existing target atomically; rename() would replace one.
      s = errno == EEXIST ? failed_precondition(path.string() + " exists; give --overwrite to replace it")
                          : io_error("cannot place the calibration at " + path.string() + ": " + std::strerror(errno));
    }
  }
  ::unlink(temporary.c_str());  // after link(), or on failure; after rename() it is gone already
  return s;
}

Result<calib::DetectorCalibration> load_detector_calibration(const fs::path& path) {
  const std::string where = path.string();
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return not_found(where + ": no such detector calibration file");
  if (!S_ISREG(st.st_mode)) return invalid_argument(where + ": not a regular file");
  TIFFSetWarningHandler(nullptr);
  TIFFSetErrorHandler(nullptr);
  TIFF* tif = TIFFOpen(path.c_str(), "r");
  if (tif == nullptr) return corrupt_data(where + ": not a readable TIFF file (a detector calibration is one)");
  struct Closer {
    TIFF* t;
    ~Closer() { TIFFClose(t); }
  } closer{tif};
  char* description = nullptr;
  if (!TIFFGetField(tif, TIFFTAG_IMAGEDESCRIPTION, &description) || description == nullptr)
    return corrupt_data(where + ": no metadata (not a detector calibration written by lftrack)");
  const std::size_t description_size = ::strnlen(description, kMaxDescription + 1);
  if (description_size > kMaxDescription)
    return corrupt_data(where + ": metadata of more than 1 MiB (not a detector calibration written by lftrack)");
  const json j = json::parse(description, description + description_size, nullptr, false);
  if (j.is_discarded() || !j.is_object())
    return corrupt_data(where + ": its metadata is not a JSON object (not a detector calibration written by lftrack)");
  Status error;
  MetaReader m(j, "", &error);
  if (m.text("format") != kFormat)
    return error.ok() ? corrupt_data(where + ": metadata format is not '" + kFormat + "'") : error.with_context(where);
  const long long version = m.integer("version", 0, std::numeric_limits<int>::max());
  if (!error.ok()) return error.with_context(where);
  if (version != kDetectorCalibrationVersion)
    return unsupported(where + ": detector calibration version " + std::to_string(version) + " (this build reads version " +
                       std::to_string(kDetectorCalibrationVersion) + "; make it again with lftrack calibrate detector)");
  if (const json* names = m.find("pages");
      names != nullptr && *names != json::array({tiff::kPageNames[0], tiff::kPageNames[1],
                                                 tiff::kPageNames[2], tiff::kPageNames[3]}))
    m.fail("pages", "is not [\"offset_counts\", \"gain\", \"noise_counts\", \"defects\"]");
  calib::DetectorCalibration c;
  c.detector = m.text("detector");
  c.rows = int(m.integer("rows", 1, kMaxSide));
  c.cols = int(m.integer("cols", 1, kMaxSide));
  c.dark_frames = int(m.integer("dark_frames", 2, 100000000));
  c.flood_frames = int(m.integer("flood_frames", 1, 100000000));
  c.open_field_counts = m.number("open_field_counts", tracking::kMinOpenFieldCounts, 65535);
  c.saturation_counts = int(m.integer("saturation_counts", 1, 65535));
  c.saturation_source = m.text("saturation_source");
  if (error.ok() && c.saturation_source != "option" && c.saturation_source != "bits" && c.saturation_source != "observed")
    m.fail("saturation_source", "is '" + c.saturation_source + "', not option, bits or observed");
  c.offset_median_counts = m.number("offset_median_counts", 0, 65535);
  c.noise_median_counts = m.number("noise_median_counts", 0, 65535);
  if (const json* rule = m.find("defect_rule"); rule != nullptr) {
    if (!rule->is_object()) {
      m.fail("defect_rule", "is not an object");
    } else {
      MetaReader r(*rule, "defect_rule.", &error);
      calib::DetectorCalibrationOptions& o = c.rule;
      r.text("text");
      o.dark_sd = r.number("dark_sd", 1, 1000);
      o.noise_sd = r.number("noise_sd", 1, 1000);
      o.gain_low = r.number("gain_low", 0, 1);
      o.gain_high = r.number("gain_high", 1, 100);
      o.line_low = r.number("line_low", 0, 1);
      o.line_high = r.number("line_high", 1, 100);
      o.line_defect_fraction = r.number("line_defect_fraction", 0, 1);
      o.max_saturated_fraction = r.number("max_saturated_fraction", 0, 1);
      o.min_signal_counts = r.number("min_signal_counts", 0, 65535);
      o.max_unlit_fraction = r.number("max_unlit_fraction", 0, 1);
      o.min_dark_frames = int(r.integer("min_dark_frames", 2, 100000));
      o.min_flood_frames = int(r.integer("min_flood_frames", 1, 100000));
      o.bits = int(r.integer("bits", 0, 16));
      if (error.ok()) {
        if (Status s = calib::check_detector_calibration_options(o); !s.ok())
          error = corrupt_data("metadata defect_rule: " + s.message());
      }
    }
  }
  const std::int64_t pixels = std::int64_t(c.rows) * std::int64_t(c.cols);
  if (const json* defects = m.find("defects"); defects != nullptr) {
    if (!defects->is_object()) {
      m.fail("defects", "is not an object");
    } else {
      MetaReader d(*defects, "defects.", &error);
      for (int r = 0; r < calib::kDefectRules; ++r)
        c.defects_by_rule[std::size_t(r)] = d.integer(calib::defect_rule_name(r), 0, pixels);
      c.defects = d.integer("masked", 0, pixels);
    }
  }
  if (m.text("hash_algorithm") != "FNV-1a 64" && error.ok()) m.fail("hash_algorithm", "is not 'FNV-1a 64'");
  c.content_hash = m.text("content_hash");
  if (error.ok() && (c.content_hash.size() != 16 || c.content_hash.find_first_not_of("0123456789abcdef") != std::string::npos))
    m.fail("content_hash", "is not 16 hex digits");
  c.created = m.text("created");
  if (!error.ok()) return error.with_context(where);

  // The pages must be there and as large as the metadata says before memory is given to them.
  const tdir_t pages = TIFFNumberOfDirectories(tif);
  if (pages != tiff::kPages)
    return corrupt_data(where + ": " + std::to_string(pages) + " page(s); a detector calibration has " +
                        std::to_string(tiff::kPages) + " (offset, gain, noise, defects)");
  const std::uint64_t needed = std::uint64_t(tiff::kPages) * std::uint64_t(pixels) * 4;
  if (std::uint64_t(st.st_size) < needed)
    return corrupt_data(where + ": " + std::to_string(st.st_size) + " bytes cannot hold four " + std::to_string(c.cols) +
                        " x " + std::to_string(c.rows) + " float maps (truncated, or the metadata lies)");
  std::vector<float> page;
  c.offset_counts = tracking::Image<float>(c.rows, c.cols);
  c.gain = tracking::Image<float>(c.rows, c.cols);
  c.noise_counts = tracking::Image<float>(c.rows, c.cols);
  c.defective = tracking::Image<unsigned char>(c.rows, c.cols);
  tracking::Image<float>* maps[3] = {&c.offset_counts, &c.gain, &c.noise_counts};
  std::int64_t masked = 0;
  for (int p = 0; p < tiff::kPages; ++p) {
    LFTRACK_RETURN_IF_ERROR(tiff::read_page(tif, p, c.rows, c.cols, &page, where));
    if (p < 3) {
      std::copy(page.begin(), page.end(), maps[p]->pixels().begin());
      continue;
    }
    for (std::size_t i = 0; i < page.size(); ++i) {
      if (page[i] != 0.f && page[i] != 1.f)
        return corrupt_data(where + ": the defect page holds " + std::to_string(page[i]) + " (only 0 and 1)");
      c.defective.pixels()[i] = page[i] != 0.f ? 1 : 0;
      masked += c.defective.pixels()[i];
    }
  }
  for (std::size_t i = 0; i < c.gain.pixels().size(); ++i) {
    if (c.gain.pixels()[i] < 0) return corrupt_data(where + ": a negative gain (" + std::to_string(c.gain.pixels()[i]) + ")");
    if (c.noise_counts.pixels()[i] < 0) return corrupt_data(where + ": a negative noise");
  }
  if (masked != c.defects)
    return corrupt_data(where + ": the defect page masks " + std::to_string(masked) + " pixels, the metadata says " +
                        std::to_string(c.defects));
  if (const std::uint64_t end = tiff::last_directory_end(tif, path);
      end == 0 || end > std::uint64_t(st.st_size))
    return corrupt_data(where + ": the last page's directory runs past the end of the file (" +
                        std::to_string(st.st_size) + " bytes): truncated");
  const std::string hash = calib::detector_calibration_hash(c);
  if (hash != c.content_hash)
    return corrupt_data(where + ": the maps do not match their hash (" + hash + " against " + c.content_hash +
                        "): damaged or edited");
  return c;
}

std::string utc_now() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return text;
}

}  // namespace lftrack::session

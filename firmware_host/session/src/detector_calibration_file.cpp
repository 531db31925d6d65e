#include "lftrack/host/detector_calibration_file.hpp"

#include <sys/stat.h>
#include <tiffio.h>
#include <unistd.h>

#include <cmath>
#include <nlohmann/json.hpp>

namespace lftrack::host {

namespace {

constexpr const char* kFormat = "lftrack detector calibration";
constexpr int kVersion = 1;
constexpr int kPages = 4;
const char* const kPageNames[kPages] = {"offset_counts", "gain", "noise_counts", "defects"};

nlohmann::json metadata(const calib::DetectorCalibration& c) {
  nlohmann::json rule = {{"dark_sd", c.rule.dark_sd},
                         {"noise_sd", c.rule.noise_sd},
                         {"gain_low", c.rule.gain_low},
                         {"gain_high", c.rule.gain_high},
                         {"line_low", c.rule.line_low},
                         {"line_high", c.rule.line_high},
                         {"max_saturated_fraction", c.rule.max_saturated_fraction},
                         {"min_signal_counts", c.rule.min_signal_counts}};
  nlohmann::json defects;
  for (int r = 0; r < calib::kDefectRules; ++r) defects[calib::defect_rule_name(r)] = c.defects_by_rule[std::size_t(r)];
  defects["masked"] = c.defects;
  return {{"format", kFormat},
          {"version", kVersion},
          {"pages", {kPageNames[0], kPageNames[1], kPageNames[2], kPageNames[3]}},
          {"detector", c.detector},
          {"rows", c.rows},
          {"cols", c.cols},
          {"dark_frames", c.dark_frames},
          {"flood_frames", c.flood_frames},
          {"open_field_counts", c.open_field_counts},
          {"saturation_counts", c.saturation_counts},
          {"bits", c.rule.bits},
          {"defect_rule", rule},
          {"defects", defects},
          {"content_hash", c.content_hash}};
}

Status write_page(TIFF* tif, const float* data, int rows, int cols, const std::string& description, int page) {
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, std::uint32_t(cols));
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, std::uint32_t(rows));
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 32);
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
  TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_IEEEFP);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 1);
  TIFFSetField(tif, TIFFTAG_SUBFILETYPE, FILETYPE_PAGE);
  TIFFSetField(tif, TIFFTAG_PAGENUMBER, page, kPages);
  TIFFSetField(tif, TIFFTAG_PAGENAME, kPageNames[page]);
  if (!description.empty()) TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, description.c_str());
  for (int r = 0; r < rows; ++r)
    if (TIFFWriteScanline(tif, const_cast<float*>(data + std::size_t(r) * cols), std::uint32_t(r), 0) < 0)
      return io_error("cannot write the calibration's TIFF data");
  if (!TIFFWriteDirectory(tif)) return io_error("cannot write the calibration's TIFF directory");
  return {};
}

Status read_page(TIFF* tif, int page, int rows, int cols, std::vector<float>* out, const std::string& where) {
  if (!TIFFSetDirectory(tif, std::uint16_t(page)))
    return corrupt_data(where + ": page " + std::to_string(page + 1) + " (" + kPageNames[page] + ") is missing");
  std::uint32_t w = 0, h = 0;
  std::uint16_t bits = 0, samples = 1, format = 0;
  TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &w);
  TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &h);
  TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &samples);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &format);
  if (w != std::uint32_t(cols) || h != std::uint32_t(rows))
    return corrupt_data(where + ": page " + kPageNames[page] + " is " + std::to_string(w) + " x " + std::to_string(h) +
                        ", the metadata says " + std::to_string(cols) + " x " + std::to_string(rows));
  if (bits != 32 || samples != 1 || format != SAMPLEFORMAT_IEEEFP || TIFFIsTiled(tif))
    return corrupt_data(where + ": page " + kPageNames[page] + " is not one-sample 32-bit float in strips");
  out->resize(std::size_t(rows) * std::size_t(cols));
  for (int r = 0; r < rows; ++r)
    if (TIFFReadScanline(tif, out->data() + std::size_t(r) * cols, std::uint32_t(r), 0) < 0)
      return corrupt_data(where + ": page " + kPageNames[page] + " is truncated or unreadable");
  for (float v : *out)
    if (!std::isfinite(v)) return corrupt_data(where + ": page " + kPageNames[page] + " holds a non-finite value");
  return {};
}

}  // namespace

Status write_detector_calibration(const std::filesystem::path& path, const calib::DetectorCalibration& c,
                                  bool overwrite) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) == 0) {
    if (!overwrite) return failed_precondition(path.string() + " exists; give --overwrite to replace it");
    if (!S_ISREG(st.st_mode)) return failed_precondition(path.string() + " is not a regular file; not replaced");
  }
  const std::size_t n = std::size_t(c.rows) * std::size_t(c.cols);
  if (c.rows <= 0 || c.cols <= 0 || c.offset_counts.rows() != c.rows || c.gain.rows() != c.rows ||
      c.noise_counts.rows() != c.rows || c.defective.rows() != c.rows)
    return invalid_argument("detector calibration: maps of the wrong size");
  const std::filesystem::path temporary = path.string() + ".partial-" + std::to_string(::getpid());
  TIFFSetWarningHandler(nullptr);
  TIFFSetErrorHandler(nullptr);
  TIFF* tif = TIFFOpen(temporary.c_str(), "w");
  if (tif == nullptr) return io_error("cannot create " + temporary.string());
  std::vector<float> defects(n);
  for (std::size_t i = 0; i < n; ++i) defects[i] = c.defective.view().data[i] ? 1.f : 0.f;
  const float* pages[kPages] = {&c.offset_counts.at(0, 0), &c.gain.at(0, 0), &c.noise_counts.at(0, 0), defects.data()};
  Status s;
  for (int p = 0; p < kPages && s.ok(); ++p) s = write_page(tif, pages[p], c.rows, c.cols, p == 0 ? metadata(c).dump() : "", p);
  TIFFClose(tif);
  std::error_code ec;
  if (!s.ok()) {
    std::filesystem::remove(temporary, ec);
    return s;
  }
  std::filesystem::rename(temporary, path, ec);
  if (ec) {
    std::filesystem::remove(temporary, ec);
    return io_error("cannot move the calibration to " + path.string());
  }
  return {};
}

Result<calib::DetectorCalibration> load_detector_calibration(const std::filesystem::path& path) {
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
  nlohmann::json j = nlohmann::json::parse(description, nullptr, false);
  if (j.is_discarded() || !j.is_object()) return corrupt_data(where + ": its metadata is not JSON");
  calib::DetectorCalibration c;
  try {
    if (j.at("format").get<std::string>() != kFormat) return corrupt_data(where + ": not a detector calibration");
    if (j.at("version").get<int>() != kVersion)
      return unsupported(where + ": detector calibration version " + std::to_string(j.at("version").get<int>()) +
                         " (this build reads version " + std::to_string(kVersion) + ")");
    c.detector = j.at("detector").get<std::string>();
    c.rows = j.at("rows").get<int>();
    c.cols = j.at("cols").get<int>();
    c.dark_frames = j.at("dark_frames").get<int>();
    c.flood_frames = j.at("flood_frames").get<int>();
    c.open_field_counts = j.at("open_field_counts").get<double>();
    c.saturation_counts = j.at("saturation_counts").get<int>();
    c.rule.bits = j.at("bits").get<int>();
    const auto& rule = j.at("defect_rule");
    c.rule.dark_sd = rule.at("dark_sd").get<double>();
    c.rule.noise_sd = rule.at("noise_sd").get<double>();
    c.rule.gain_low = rule.at("gain_low").get<double>();
    c.rule.gain_high = rule.at("gain_high").get<double>();
    c.rule.line_low = rule.at("line_low").get<double>();
    c.rule.line_high = rule.at("line_high").get<double>();
    c.rule.max_saturated_fraction = rule.at("max_saturated_fraction").get<double>();
    c.rule.min_signal_counts = rule.at("min_signal_counts").get<double>();
    for (int r = 0; r < calib::kDefectRules; ++r)
      c.defects_by_rule[std::size_t(r)] = j.at("defects").at(calib::defect_rule_name(r)).get<std::int64_t>();
    c.defects = j.at("defects").at("masked").get<std::int64_t>();
    c.content_hash = j.at("content_hash").get<std::string>();
  } catch (const nlohmann::json::exception& e) {
    return corrupt_data(where + ": metadata incomplete or of the wrong type (" + e.what() + ")");
  }
  if (c.rows < 1 || c.cols < 1 || c.rows > 16384 || c.cols > 16384)
    return corrupt_data(where + ": a detector of " + std::to_string(c.cols) + " x " + std::to_string(c.rows) +
                        " pixels (1 to 16384 a side)");
  if (!(std::isfinite(c.open_field_counts) && c.open_field_counts > 0) || c.saturation_counts < 1 ||
      c.saturation_counts > 65535)
    return corrupt_data(where + ": open-field counts or saturation out of range");
  // The pages must be there and as large as the metadata says before memory is given to them.
  const std::uint64_t needed = std::uint64_t(kPages) * std::uint64_t(c.rows) * std::uint64_t(c.cols) * 4;
  if (std::uint64_t(st.st_size) < needed)
    return corrupt_data(where + ": " + std::to_string(st.st_size) + " bytes cannot hold four " + std::to_string(c.cols) +
                        " x " + std::to_string(c.rows) + " float maps (truncated?)");
  std::vector<float> page;
  c.offset_counts = tracking::Image<float>(c.rows, c.cols);
  c.gain = tracking::Image<float>(c.rows, c.cols);
  c.noise_counts = tracking::Image<float>(c.rows, c.cols);
  c.defective = tracking::Image<unsigned char>(c.rows, c.cols);
  tracking::Image<float>* maps[3] = {&c.offset_counts, &c.gain, &c.noise_counts};
  for (int p = 0; p < kPages; ++p) {
    LFTRACK_RETURN_IF_ERROR(read_page(tif, p, c.rows, c.cols, &page, where));
    if (p < 3) {
      std::copy(page.begin(), page.end(), maps[p]->view().data);
    } else {
      for (std::size_t i = 0; i < page.size(); ++i) {
        if (page[i] != 0.f && page[i] != 1.f) return corrupt_data(where + ": the defect page holds values other than 0 and 1");
        c.defective.view().data[i] = page[i] != 0.f ? 1 : 0;
      }
    }
  }
  if (TIFFSetDirectory(tif, kPages)) return corrupt_data(where + ": more than four pages");
  for (int r = 0; r < c.rows; ++r)
    for (int k = 0; k < c.cols; ++k)
      if (c.gain.at(r, k) < 0) return corrupt_data(where + ": a negative gain");
  const std::string hash = calib::detector_calibration_hash(c);
  if (hash != c.content_hash)
    return corrupt_data(where + ": the maps do not match their hash (" + hash + " against " + c.content_hash +
                        "): damaged or edited");
  return c;
}

}  // namespace lftrack::host

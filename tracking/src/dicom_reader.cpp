// DICOM CT series reader on DCMTK (dcmdata, with the JPEG, JPEG-LS and RLE decoders registered).
// DCMTK parses and decodes; this file checks that the slices form one regular volume and places
// it in the CT frame. DCMTK rather than GDCM: Debian's GDCM aborts (assert) on a file truncated
// inside its meta header and reads a file truncated inside its pixel data with only a warning;
// DCMTK reports both as errors.

#include <dcmtk/config/osconfig.h>  // must come first
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcrledrg.h>
#include <dcmtk/dcmdata/dcxfer.h>
#include <dcmtk/dcmjpeg/djdecode.h>
#include <dcmtk/dcmjpls/djdecode.h>
#include <dcmtk/oflog/oflog.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <iomanip>
#include <mutex>
#include <sstream>
#include <string_view>

#include "lftrack/tracking/volume_io.hpp"

namespace lftrack::tracking {
namespace {

namespace fs = std::filesystem;

struct Slice {
  fs::path file;
  std::string series_uid;
  int rows = 0;
  int cols = 0;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();       // ImagePositionPatient, mm
  Eigen::Vector3d row_cosine = Eigen::Vector3d::Zero();     // IOP[0..2]: direction of columns++
  Eigen::Vector3d col_cosine = Eigen::Vector3d::Zero();     // IOP[3..5]: direction of rows++
  Eigen::Vector2d pixel_spacing = Eigen::Vector2d::Zero();  // (between rows, between columns)
  double slope = 1.0;
  double intercept = 0.0;
  double along_normal_mm = 0.0;
  std::vector<float> hu;  // rows * cols, row-major
};

void register_decoders_once() {
  static std::once_flag once;
  std::call_once(once, [] {
    // DCMTK logs parse problems itself; ours carry the file name, so keep its logger quiet.
    OFLog::configure(OFLogger::FATAL_LOG_LEVEL);
    DJDecoderRegistration::registerCodecs();
    DJLSDecoderRegistration::registerCodecs();
    DcmRLEDecoderRegistration::registerCodecs();
  });
}

std::string get_string(DcmDataset& ds, const DcmTagKey& tag) {
  OFString value;
  if (ds.findAndGetOFStringArray(tag, value).bad()) return {};
  std::string s(value.c_str());
  const auto first = s.find_first_not_of(' ');
  const auto last = s.find_last_not_of(' ');
  return first == std::string::npos ? std::string() : s.substr(first, last - first + 1);
}

Status required_decimals(DcmDataset& ds, const DcmTagKey& tag, unsigned long n, const char* name,
                         std::vector<double>* out) {
  out->assign(n, 0.0);
  if (!ds.tagExistsWithValue(tag)) return corrupt_data(std::string("missing ") + name);
  DcmElement* element = nullptr;
  if (ds.findAndGetElement(tag, element).bad() || element->getVM() != n) {
    return corrupt_data(std::string(name) + " is not " + std::to_string(n) + " numbers: '" +
                        get_string(ds, tag) + "'");
  }
  // Each value read from its own text, whole: DCMTK reads "1abc" as 1 and "0x10" as 0.
  const std::string text = get_string(ds, tag);
  std::size_t start = 0;
  for (unsigned long i = 0; i < n; ++i) {
    const std::size_t end = std::min(text.find('\\', start), text.size());
    std::string part = text.substr(start, end - start);
    part.erase(0, part.find_first_not_of(' '));
    part.erase(part.find_last_not_of(' ') + 1);
    char* stop = nullptr;
    const double v = part.empty() ? 0 : std::strtod(part.c_str(), &stop);
    if (part.empty() || stop != part.c_str() + part.size() || !std::isfinite(v) ||
        part.find_first_of("xXpP") != std::string::npos)
      return corrupt_data(std::string(name) + " is not " + std::to_string(n) + " finite decimal numbers: '" + text +
                          "'");
    (*out)[i] = v;
    start = end + 1;
  }
  return {};
}

// Stored values as BitsStored allows them (PixelRepresentation: 0 unsigned, 1 two's complement).
struct StoredRange {
  double lowest = 0, highest = 0;
};

// Converts stored values to HU. Returns the index of the first value outside the stored range
// or whose HU is not finite or implausible (volume_io.hpp), or `count` when all are good.
template <class T>
std::size_t convert_pixels(const T* raw, std::size_t count, const StoredRange& stored, double slope,
                           double intercept, std::vector<float>* hu) {
  hu->resize(count);
  for (std::size_t i = 0; i < count; ++i) {
    const double value = static_cast<double>(raw[i]);
    const double h = slope * value + intercept;
    if (value < stored.lowest || value > stored.highest || !(h >= kLowestPlausibleHu && h <= kHighestPlausibleHu))
      return i;
    (*hu)[i] = static_cast<float>(h);
  }
  return count;
}

std::string number_text(double v) {
  std::ostringstream s;
  s << std::setprecision(10) << v;
  return s.str();
}

Status read_pixels(DcmDataset& ds, Slice* slice) {
  Uint16 samples = 1, bits_allocated = 0, bits_stored = 0, representation = 0;
  ds.findAndGetUint16(DCM_SamplesPerPixel, samples);
  ds.findAndGetUint16(DCM_BitsAllocated, bits_allocated);
  ds.findAndGetUint16(DCM_PixelRepresentation, representation);
  if (ds.findAndGetUint16(DCM_BitsStored, bits_stored).bad()) bits_stored = bits_allocated;
  if (bits_stored < 1 || bits_stored > bits_allocated)
    return corrupt_data("BitsStored " + std::to_string(bits_stored) + " is not 1 to BitsAllocated (" +
                        std::to_string(bits_allocated) + ")");
  StoredRange stored;
  if (representation == 1) {
    stored.lowest = -std::ldexp(1.0, bits_stored - 1);
    stored.highest = std::ldexp(1.0, bits_stored - 1) - 1;
  } else {
    stored.highest = std::ldexp(1.0, bits_stored) - 1;
  }
  if (samples != 1) {
    return unsupported("samples per pixel is " + std::to_string(samples) + ", expected 1 (greyscale)");
  }
  const DcmXfer original(ds.getOriginalXfer());
  if (original.isEncapsulated()) {
    if (ds.chooseRepresentation(EXS_LittleEndianExplicit, nullptr).bad() ||
        !ds.canWriteXfer(EXS_LittleEndianExplicit)) {
      return unsupported(std::string("pixel data cannot be decoded (transfer syntax ") +
                         original.getXferName() + ", " + original.getXferID() +
                         ", has no decoder in this DCMTK build)");
    }
  }
  const std::size_t count = std::size_t(slice->rows) * std::size_t(slice->cols);
  // Reads the stored values as T and converts them; `as_signed` reinterprets 16-bit words.
  auto convert = [&](auto get_array, auto type_tag, bool as_signed) -> Status {
    using T = decltype(type_tag);
    const T* raw = nullptr;
    unsigned long got = 0;
    if (get_array(&raw, &got).bad() || raw == nullptr) return corrupt_data("no readable pixel data");
    if (got < count) {
      return corrupt_data("pixel data holds " + std::to_string(got) + " values, expected " +
                          std::to_string(count));
    }
    std::size_t bad = count;
    double bad_value = 0;
    if constexpr (sizeof(T) == 2) {
      if (as_signed) {
        const auto* words = reinterpret_cast<const int16_t*>(raw);
        bad = convert_pixels(words, count, stored, slice->slope, slice->intercept, &slice->hu);
        if (bad < count) bad_value = words[bad];
      }
    }
    if (!(as_signed && sizeof(T) == 2)) {
      bad = convert_pixels(raw, count, stored, slice->slope, slice->intercept, &slice->hu);
      if (bad < count) bad_value = raw[bad];
    }
    if (bad == count) return {};
    const std::string where = "pixel (row " + std::to_string(bad / std::size_t(slice->cols)) + ", column " +
                              std::to_string(bad % std::size_t(slice->cols)) + ")";
    if (bad_value < stored.lowest || bad_value > stored.highest)
      return corrupt_data(where + ": stored value " + number_text(bad_value) + " does not fit BitsStored " +
                          std::to_string(bits_stored) + (representation == 1 ? " (signed)" : " (unsigned)"));
    return corrupt_data(where + ": stored value " + number_text(bad_value) + " x RescaleSlope " +
                        number_text(slice->slope) + " + RescaleIntercept " + number_text(slice->intercept) + " = " +
                        number_text(slice->slope * bad_value + slice->intercept) + " HU, outside the plausible [" +
                        number_text(kLowestPlausibleHu) + ", " + number_text(kHighestPlausibleHu) + "] HU");
  };
  if (bits_allocated == 16) {
    return convert(
        [&](const Uint16** r, unsigned long* n) { return ds.findAndGetUint16Array(DCM_PixelData, *r, n); },
        Uint16{}, representation == 1);
  }
  if (bits_allocated == 8) {
    return convert(
        [&](const Uint8** r, unsigned long* n) { return ds.findAndGetUint8Array(DCM_PixelData, *r, n); },
        Uint8{}, false);
  }
  return unsupported("BitsAllocated " + std::to_string(bits_allocated) + " is not 8 or 16");
}

Status read_slice(const fs::path& file, Slice* slice) {
  register_decoders_once();
  DcmFileFormat format;
  const OFCondition loaded = format.loadFile(file.c_str());
  if (loaded.bad()) {
    return corrupt_data(std::string("not a readable DICOM file (") + loaded.text() + ")");
  }
  DcmDataset& ds = *format.getDataset();
  slice->file = file;

  const std::string modality = get_string(ds, DCM_Modality);
  if (modality != "CT") {
    return unsupported("modality is '" + (modality.empty() ? std::string("none") : modality) +
                       "', expected CT");
  }
  slice->series_uid = get_string(ds, DCM_SeriesInstanceUID);
  if (slice->series_uid.empty()) return corrupt_data("missing SeriesInstanceUID");
  const std::string frames = get_string(ds, DCM_NumberOfFrames);
  if (!frames.empty() && frames != "1") {
    return unsupported("multi-frame object (" + frames + " frames); expected one slice per file");
  }

  std::vector<double> v;
  LFTRACK_RETURN_IF_ERROR(required_decimals(ds, DCM_ImagePositionPatient, 3, "ImagePositionPatient", &v));
  slice->position = {v[0], v[1], v[2]};
  LFTRACK_RETURN_IF_ERROR(
      required_decimals(ds, DCM_ImageOrientationPatient, 6, "ImageOrientationPatient", &v));
  slice->row_cosine = {v[0], v[1], v[2]};
  slice->col_cosine = {v[3], v[4], v[5]};
  if (std::abs(slice->row_cosine.norm() - 1.0) > 1e-3 || std::abs(slice->col_cosine.norm() - 1.0) > 1e-3 ||
      std::abs(slice->row_cosine.dot(slice->col_cosine)) > 1e-3) {
    return corrupt_data("ImageOrientationPatient is not two orthonormal vectors");
  }
  slice->row_cosine.normalize();
  slice->col_cosine.normalize();
  LFTRACK_RETURN_IF_ERROR(required_decimals(ds, DCM_PixelSpacing, 2, "PixelSpacing", &v));
  slice->pixel_spacing = {v[0], v[1]};
  if (!(v[0] > 0) || !(v[1] > 0)) return corrupt_data("PixelSpacing is not positive");
  // Both are Type 1 in a CT image: a slice without them is refused, never read as slope 1 and
  // intercept 0 (1024 HU off its neighbours).
  LFTRACK_RETURN_IF_ERROR(required_decimals(ds, DCM_RescaleSlope, 1, "RescaleSlope", &v));
  slice->slope = v[0];
  LFTRACK_RETURN_IF_ERROR(required_decimals(ds, DCM_RescaleIntercept, 1, "RescaleIntercept", &v));
  slice->intercept = v[0];
  if (!(slice->slope >= kMinRescaleSlope) || slice->slope > kMaxRescaleSlope)
    return corrupt_data("RescaleSlope " + number_text(slice->slope) + " is not in [" + number_text(kMinRescaleSlope) +
                        ", " + number_text(kMaxRescaleSlope) + "]");
  if (std::abs(slice->intercept) > kMaxRescaleIntercept)
    return corrupt_data("RescaleIntercept " + number_text(slice->intercept) + " is beyond +-" +
                        number_text(kMaxRescaleIntercept));
  Uint16 rows = 0, cols = 0;
  ds.findAndGetUint16(DCM_Rows, rows);
  ds.findAndGetUint16(DCM_Columns, cols);
  if (rows == 0 || cols == 0) return corrupt_data("image has no rows or columns");
  slice->rows = rows;
  slice->cols = cols;
  return read_pixels(ds, slice);
}

// Checks that slice `s` matches the reference slice in everything but position.
Status check_consistent(const Slice& ref, const Slice& s) {
  const std::string vs = " (" + ref.file.filename().string() + " has ";
  if (s.series_uid != ref.series_uid) {
    return invalid_argument("mixed series: SeriesInstanceUID " + s.series_uid + vs + ref.series_uid + ")");
  }
  if (s.rows != ref.rows || s.cols != ref.cols) {
    return invalid_argument("mixed sizes: " + std::to_string(s.rows) + " x " + std::to_string(s.cols) + vs +
                            std::to_string(ref.rows) + " x " + std::to_string(ref.cols) + ")");
  }
  if ((s.row_cosine - ref.row_cosine).norm() > 1e-4 || (s.col_cosine - ref.col_cosine).norm() > 1e-4) {
    return invalid_argument("mixed orientations: ImageOrientationPatient differs" + vs + "another)");
  }
  if ((s.pixel_spacing - ref.pixel_spacing).norm() > 1e-4) {
    return invalid_argument("mixed pixel spacings" + vs + "another)");
  }
  return {};
}

// Checks that sorted slices are evenly spaced along the normal, with no duplicate, gap or tilt.
// Returns the slice spacing in `spacing_mm`.
Status check_stack(const std::vector<Slice>& slices, const Eigen::Vector3d& normal, double* spacing_mm) {
  std::vector<double> gaps;
  for (std::size_t k = 1; k < slices.size(); ++k) {
    gaps.push_back(slices[k].along_normal_mm - slices[k - 1].along_normal_mm);
  }
  std::vector<double> sorted_gaps = gaps;
  std::nth_element(sorted_gaps.begin(), sorted_gaps.begin() + sorted_gaps.size() / 2, sorted_gaps.end());
  const double nominal = sorted_gaps[sorted_gaps.size() / 2];
  auto pair_name = [&](std::size_t k) {
    return slices[k - 1].file.filename().string() + " and " + slices[k].file.filename().string();
  };
  for (std::size_t k = 1; k < slices.size(); ++k) {
    const double gap = gaps[k - 1];
    std::ostringstream m;
    m.precision(6);
    if (gap < 1e-3) {
      m << "duplicated slice position " << slices[k].along_normal_mm << " mm in " << pair_name(k);
      return invalid_argument(m.str());
    }
    if (std::abs(gap - nominal) > std::max(1e-2, 1e-2 * nominal)) {
      const double ratio = gap / nominal;
      if (ratio > 1.5 && std::abs(ratio - std::round(ratio)) < 0.05) {
        m << "missing slice(s): " << static_cast<int>(std::round(ratio)) - 1 << " slice(s) absent between "
          << pair_name(k) << " (gap " << gap << " mm, spacing " << nominal << " mm)";
      } else {
        m << "uneven slice spacing: gap of " << gap << " mm between " << pair_name(k)
          << ", the series' spacing is " << nominal << " mm";
      }
      return invalid_argument(m.str());
    }
    const Eigen::Vector3d step = slices[k].position - slices[0].position;
    const Eigen::Vector3d sideways = step - step.dot(normal) * normal;
    if (sideways.norm() > 1e-2 + 1e-4 * step.norm()) {
      return unsupported("slices are not stacked along their normal (gantry tilt?) at " +
                         slices[k].file.filename().string());
    }
  }
  *spacing_mm = nominal;
  return {};
}

}  // namespace

Result<CtVolume> read_dicom_series(const fs::path& folder) {
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) {
    return not_found(folder.string() + ": not a folder");
  }
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    const std::string name = entry.path().filename().string();
    if (!entry.is_regular_file() || name.empty() || name[0] == '.' || name == "DICOMDIR") continue;
    files.push_back(entry.path());
  }
  if (ec) return io_error(folder.string() + ": cannot list folder: " + ec.message());
  std::sort(files.begin(), files.end());
  if (files.size() < 2) {
    return invalid_argument(folder.string() + ": a CT series needs at least 2 slice files, found " +
                            std::to_string(files.size()));
  }

  std::vector<Slice> slices(files.size());
  for (std::size_t n = 0; n < files.size(); ++n) {
    Status s = read_slice(files[n], &slices[n]);
    if (s.ok() && n > 0) s = check_consistent(slices[0], slices[n]);
    if (!s.ok()) return s.with_context(files[n].string());
  }

  const Eigen::Vector3d normal = slices[0].row_cosine.cross(slices[0].col_cosine).normalized();
  for (Slice& s : slices) s.along_normal_mm = normal.dot(s.position);
  std::sort(slices.begin(), slices.end(),
            [](const Slice& a, const Slice& b) { return a.along_normal_mm < b.along_normal_mm; });
  double slice_spacing_mm = 0;
  if (Status s = check_stack(slices, normal, &slice_spacing_mm); !s.ok()) {
    return s.with_context(folder.string());
  }

  CtVolume ct;
  VolumeGeometry& g = ct.geometry;
  g.size = {slices[0].cols, slices[0].rows, static_cast<int>(slices.size())};
  g.spacing_mm = {slices[0].pixel_spacing[1], slices[0].pixel_spacing[0], slice_spacing_mm};
  g.origin_mm = slices[0].position;
  g.direction.col(0) = slices[0].row_cosine;
  g.direction.col(1) = slices[0].col_cosine;
  g.direction.col(2) = normal;
  if (Status s = g.validate(); !s.ok()) return s.with_context(folder.string());

  const std::size_t per_slice = std::size_t(g.size.x()) * std::size_t(g.size.y());
  ct.values.resize(per_slice * slices.size());
  for (std::size_t k = 0; k < slices.size(); ++k) {
    std::copy(slices[k].hu.begin(), slices[k].hu.end(), ct.values.begin() + std::ptrdiff_t(k * per_slice));
  }
  return ct;
}

Result<CtVolume> read_ct(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return not_found(path.string() + ": no such file or folder");
  if (fs::is_directory(path, ec)) return read_dicom_series(path);
  const std::string name = path.filename().string();
  auto ends_with = [&](std::string_view suffix) {
    return name.size() >= suffix.size() &&
           name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0;
  };
  if (ends_with(".nii") || ends_with(".nii.gz")) return read_nifti(path);
  return unsupported(path.string() +
                     ": unknown CT format; give a DICOM series folder or a .nii/.nii.gz file");
}

}  // namespace lftrack::tracking

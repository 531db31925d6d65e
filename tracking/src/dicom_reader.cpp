// DICOM CT series reader on GDCM. GDCM parses files and decodes pixel data (including the
// compressed transfer syntaxes it has codecs for); this file checks that the slices form one
// regular volume and places it in the CT frame.

#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmTag.h>

#include <algorithm>
#include <charconv>
#include <cstring>
#include <cmath>
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

std::string element_string(const gdcm::DataSet& ds, uint16_t group, uint16_t element) {
  const gdcm::Tag tag(group, element);
  if (!ds.FindDataElement(tag)) return {};
  const gdcm::DataElement& de = ds.GetDataElement(tag);
  const gdcm::ByteValue* bv = de.GetByteValue();
  if (!bv) return {};
  std::string s(bv->GetPointer(), bv->GetLength());
  const auto first = s.find_first_not_of(" \t\r\n\0");
  const auto last = s.find_last_not_of(std::string(" \t\r\n\0", 5));
  if (first == std::string::npos) return {};
  return s.substr(first, last - first + 1);
}

// Parses a backslash-separated decimal string (DICOM DS) into exactly `n` numbers.
bool parse_decimals(const std::string& text, std::size_t n, std::vector<double>* out) {
  out->clear();
  std::size_t start = 0;
  while (start <= text.size()) {
    std::size_t end = text.find('\\', start);
    if (end == std::string::npos) end = text.size();
    std::string_view part(text.data() + start, end - start);
    while (!part.empty() && part.front() == ' ') part.remove_prefix(1);
    while (!part.empty() && (part.back() == ' ' || part.back() == '\0')) part.remove_suffix(1);
    if (!part.empty() && part.front() == '+') part.remove_prefix(1);
    double v = 0;
    const auto [ptr, ec] = std::from_chars(part.data(), part.data() + part.size(), v);
    if (ec != std::errc() || ptr != part.data() + part.size() || !std::isfinite(v)) return false;
    out->push_back(v);
    start = end + 1;
  }
  return out->size() == n;
}

Status required_decimals(const gdcm::DataSet& ds, uint16_t g, uint16_t e, std::size_t n,
                         const char* name, std::vector<double>* out) {
  const std::string s = element_string(ds, g, e);
  if (s.empty()) return corrupt_data(std::string("missing ") + name);
  if (!parse_decimals(s, n, out)) {
    return corrupt_data(std::string(name) + " is not " + std::to_string(n) +
                        " finite numbers: '" + s + "'");
  }
  return {};
}

template <class T>
void convert_pixels(const char* buffer, std::size_t count, double slope, double intercept,
                    std::vector<float>* hu) {
  hu->resize(count);
  for (std::size_t i = 0; i < count; ++i) {
    T raw;
    std::memcpy(&raw, buffer + i * sizeof(T), sizeof(T));
    (*hu)[i] = static_cast<float>(slope * static_cast<double>(raw) + intercept);
  }
}

Status read_slice(const fs::path& file, Slice* slice) {
  gdcm::ImageReader reader;
  reader.SetFileName(file.c_str());
  if (!reader.Read()) return corrupt_data("not a readable DICOM image (truncated or not DICOM)");
  const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  slice->file = file;

  const std::string modality = element_string(ds, 0x0008, 0x0060);
  if (modality != "CT") {
    return unsupported("modality is '" + (modality.empty() ? std::string("none") : modality) +
                       "', expected CT");
  }
  slice->series_uid = element_string(ds, 0x0020, 0x000E);
  if (slice->series_uid.empty()) return corrupt_data("missing SeriesInstanceUID");
  const std::string frames = element_string(ds, 0x0028, 0x0008);
  if (!frames.empty() && frames != "1") {
    return unsupported("multi-frame object (" + frames + " frames); expected one slice per file");
  }

  std::vector<double> v;
  LFTRACK_RETURN_IF_ERROR(required_decimals(ds, 0x0020, 0x0032, 3, "ImagePositionPatient", &v));
  slice->position = {v[0], v[1], v[2]};
  LFTRACK_RETURN_IF_ERROR(
      required_decimals(ds, 0x0020, 0x0037, 6, "ImageOrientationPatient", &v));
  slice->row_cosine = {v[0], v[1], v[2]};
  slice->col_cosine = {v[3], v[4], v[5]};
  if (std::abs(slice->row_cosine.norm() - 1.0) > 1e-3 ||
      std::abs(slice->col_cosine.norm() - 1.0) > 1e-3 ||
      std::abs(slice->row_cosine.dot(slice->col_cosine)) > 1e-3) {
    return corrupt_data("ImageOrientationPatient is not two orthonormal vectors");
  }
  slice->row_cosine.normalize();
  slice->col_cosine.normalize();
  LFTRACK_RETURN_IF_ERROR(required_decimals(ds, 0x0028, 0x0030, 2, "PixelSpacing", &v));
  slice->pixel_spacing = {v[0], v[1]};
  if (!(v[0] > 0) || !(v[1] > 0)) return corrupt_data("PixelSpacing is not positive");
  if (!element_string(ds, 0x0028, 0x1053).empty()) {
    LFTRACK_RETURN_IF_ERROR(required_decimals(ds, 0x0028, 0x1053, 1, "RescaleSlope", &v));
    slice->slope = v[0];
  }
  if (!element_string(ds, 0x0028, 0x1052).empty()) {
    LFTRACK_RETURN_IF_ERROR(required_decimals(ds, 0x0028, 0x1052, 1, "RescaleIntercept", &v));
    slice->intercept = v[0];
  }

  const gdcm::Image& image = reader.GetImage();
  const unsigned int* dims = image.GetDimensions();
  if (image.GetNumberOfDimensions() < 2 || dims[0] == 0 || dims[1] == 0) {
    return corrupt_data("image has no rows or columns");
  }
  slice->cols = static_cast<int>(dims[0]);
  slice->rows = static_cast<int>(dims[1]);
  const gdcm::PixelFormat& pf = image.GetPixelFormat();
  if (pf.GetSamplesPerPixel() != 1) {
    return unsupported("samples per pixel is " + std::to_string(pf.GetSamplesPerPixel()) +
                       ", expected 1 (greyscale)");
  }
  const std::size_t count = std::size_t(slice->rows) * std::size_t(slice->cols);
  const unsigned long length = image.GetBufferLength();
  if (length != count * pf.GetPixelSize()) {
    return corrupt_data("pixel data holds " + std::to_string(length) + " bytes, expected " +
                        std::to_string(count * pf.GetPixelSize()));
  }
  std::vector<char> buffer(length);
  if (!image.GetBuffer(buffer.data())) {
    return unsupported("pixel data cannot be decoded (transfer syntax " +
                       std::string(gdcm::TransferSyntax::GetTSString(image.GetTransferSyntax())) +
                       " is compressed and not supported by this GDCM build)");
  }
  switch (pf.GetScalarType()) {
    case gdcm::PixelFormat::UINT8: convert_pixels<uint8_t>(buffer.data(), count, slice->slope, slice->intercept, &slice->hu); break;
    case gdcm::PixelFormat::INT8: convert_pixels<int8_t>(buffer.data(), count, slice->slope, slice->intercept, &slice->hu); break;
    case gdcm::PixelFormat::UINT16: convert_pixels<uint16_t>(buffer.data(), count, slice->slope, slice->intercept, &slice->hu); break;
    case gdcm::PixelFormat::INT16: convert_pixels<int16_t>(buffer.data(), count, slice->slope, slice->intercept, &slice->hu); break;
    case gdcm::PixelFormat::UINT32: convert_pixels<uint32_t>(buffer.data(), count, slice->slope, slice->intercept, &slice->hu); break;
    case gdcm::PixelFormat::INT32: convert_pixels<int32_t>(buffer.data(), count, slice->slope, slice->intercept, &slice->hu); break;
    default:
      return unsupported(std::string("pixel type ") + pf.GetScalarTypeAsString() +
                         " is not supported");
  }
  return {};
}

// Checks that slice `s` matches the reference slice in everything but position.
Status check_consistent(const Slice& ref, const Slice& s) {
  const std::string vs = " (" + ref.file.filename().string() + " has ";
  if (s.series_uid != ref.series_uid) {
    return invalid_argument("mixed series: SeriesInstanceUID " + s.series_uid + vs +
                            ref.series_uid + ")");
  }
  if (s.rows != ref.rows || s.cols != ref.cols) {
    return invalid_argument("mixed sizes: " + std::to_string(s.rows) + " x " +
                            std::to_string(s.cols) + vs + std::to_string(ref.rows) + " x " +
                            std::to_string(ref.cols) + ")");
  }
  if ((s.row_cosine - ref.row_cosine).norm() > 1e-4 ||
      (s.col_cosine - ref.col_cosine).norm() > 1e-4) {
    return invalid_argument("mixed orientations: ImageOrientationPatient differs" + vs +
                            "another)");
  }
  if ((s.pixel_spacing - ref.pixel_spacing).norm() > 1e-4) {
    return invalid_argument("mixed pixel spacings" + vs + "another)");
  }
  return {};
}

// Checks that sorted slices are evenly spaced along the normal, with no duplicate, gap or tilt.
// Returns the slice spacing in `spacing_mm`.
Status check_stack(const std::vector<Slice>& slices, const Eigen::Vector3d& normal,
                   double* spacing_mm) {
  std::vector<double> gaps;
  for (std::size_t k = 1; k < slices.size(); ++k) {
    gaps.push_back(slices[k].along_normal_mm - slices[k - 1].along_normal_mm);
  }
  std::vector<double> sorted_gaps = gaps;
  std::nth_element(sorted_gaps.begin(), sorted_gaps.begin() + sorted_gaps.size() / 2,
                   sorted_gaps.end());
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
        m << "missing slice(s): " << static_cast<int>(std::round(ratio)) - 1
          << " slice(s) absent between " << pair_name(k) << " (gap " << gap
          << " mm, spacing " << nominal << " mm)";
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
  std::sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) {
    return a.along_normal_mm < b.along_normal_mm;
  });
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
    return name.size() >= suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0;
  };
  if (ends_with(".nii") || ends_with(".nii.gz")) return read_nifti(path);
  return unsupported(path.string() +
                     ": unknown CT format; give a DICOM series folder or a .nii/.nii.gz file");
}

}  // namespace lftrack::tracking

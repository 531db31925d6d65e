// NIfTI-1/2 reader on nifti_clib (nifti2_io reads both versions, plain or gzipped). nifti_clib
// parses and reads; this file validates the header and turns NIfTI's RAS world into LPS.

#include <nifti2_io.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "lftrack/tracking/volume_io.hpp"

namespace lftrack::tracking {
namespace {

struct NiftiDeleter {
  void operator()(nifti_image* nim) const { nifti_image_free(nim); }
};
using NiftiPtr = std::unique_ptr<nifti_image, NiftiDeleter>;

// Scales the stored values to HU. Returns the index of the first value that is not finite or
// outside the plausible range (volume_io.hpp), or `count` when all are good; *bad_stored is the
// stored value there.
template <class T>
std::size_t copy_scaled(const void* data, std::size_t count, double slope, double inter, std::vector<float>* out,
                        double* bad_stored) {
  const T* p = static_cast<const T*>(data);
  out->resize(count);
  for (std::size_t i = 0; i < count; ++i) {
    const double hu = slope * static_cast<double>(p[i]) + inter;
    if (!(hu >= kLowestPlausibleHu && hu <= kHighestPlausibleHu)) {
      *bad_stored = static_cast<double>(p[i]);
      return i;
    }
    (*out)[i] = static_cast<float>(hu);
  }
  return count;
}

bool is_gzipped(const std::string& name) { return name.size() > 3 && name.compare(name.size() - 3, 3, ".gz") == 0; }

std::string number_text(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

// nifti_clib replaces NaN and infinite float voxels by 0 as it reads them, without a word (a NaN
// slice would silently become air). For float data the stored values are scanned here, as
// stored. Returns the index of the first non-finite voxel (nvox if none), its value in *value.
Result<std::size_t> first_non_finite_stored(const std::string& name, const nifti_image& nim, double* value) {
  const auto total = static_cast<std::size_t>(nim.nvox);
  if (nim.datatype != DT_FLOAT32 && nim.datatype != DT_FLOAT64) return total;
  const bool gz = is_gzipped(name);
  znzFile f = znzopen(name.c_str(), "rb", gz ? 1 : 0);
  if (znz_isnull(f)) return io_error(name + ": cannot open to check its float voxels");
  const std::size_t size = nim.datatype == DT_FLOAT32 ? 4 : 8;
  const bool swap = nim.byteorder != nifti_short_order();
  std::size_t found = total;
  if (znzseek(f, static_cast<znz_off_t>(nim.iname_offset), SEEK_SET) >= 0) {
    std::vector<unsigned char> buffer(size * 65536);
    for (std::size_t at = 0; at < total && found == total;) {
      const std::size_t want = std::min<std::size_t>(65536, total - at);
      const std::size_t got = znzread(buffer.data(), size, want, f);
      for (std::size_t i = 0; i < got && found == total; ++i) {
        unsigned char* bytes = buffer.data() + size * i;
        if (swap) std::reverse(bytes, bytes + size);
        double v;
        if (size == 4) {
          float x;
          std::memcpy(&x, bytes, 4);
          v = x;
        } else {
          std::memcpy(&v, bytes, 8);
        }
        if (!std::isfinite(v)) {
          found = at + i;
          *value = v;
        }
      }
      if (got < want) break;  // a short file is reported by the load itself
      at += got;
    }
  }
  znzclose(f);
  return found;
}

// A gzipped file read to the end of its stream: zlib checks the CRC-32 and length only there,
// and nifti_clib stops reading where the volume ends.
Status check_gzip_stream(const std::string& name) {
  gzFile f = gzopen(name.c_str(), "rb");
  if (f == nullptr) return io_error("cannot open the gzip stream");
  std::vector<char> buffer(1 << 20);
  int n = 0;
  while ((n = gzread(f, buffer.data(), static_cast<unsigned>(buffer.size()))) > 0) {
  }
  int code = Z_OK;
  const char* message = gzerror(f, &code);
  const std::string text = message != nullptr ? message : "";
  const int closed = gzclose_r(f);
  if (n < 0 || (code != Z_OK && code != Z_STREAM_END) || closed != Z_OK)
    return corrupt_data("the gzip stream is damaged (" + (text.empty() ? std::string("zlib error") : text) +
                        "): the file is refused even where the volume reads");
  return {};
}

Status check_header(const nifti_image& nim) {
  if (nim.ndim < 3 || nim.ndim > 4 || (nim.ndim == 4 && nim.nt != 1)) {
    return unsupported("expected a 3-D volume, header has " + std::to_string(nim.ndim) +
                       " dimension(s) with nt = " + std::to_string(nim.nt));
  }
  for (int64_t n : {nim.nx, nim.ny, nim.nz}) {
    if (n < 1 || n > VolumeGeometry::kMaxVoxelsPerAxis) {
      return out_of_range("dimension " + std::to_string(n) + " is outside 1.." +
                          std::to_string(VolumeGeometry::kMaxVoxelsPerAxis));
    }
  }
  for (double d : {nim.dx, nim.dy, nim.dz}) {
    if (!std::isfinite(d)) return corrupt_data("voxel size (pixdim) is not finite");
  }
  return {};
}

// nifti_clib replaces a zero or non-finite pixdim by 1 mm without a word; a header like that is
// corrupt, so the raw header's voxel sizes (and rescale, below) are checked here. They scale the qform and the
// pixdim-only fallback; the sform does not use them.
Status check_raw_header(const std::string& name, const nifti_image& nim) {
  int version = 0;
  void* raw = nifti_read_header(name.c_str(), &version, 0);
  if (!raw) return corrupt_data("header cannot be read");
  double pixdim[4] = {0, 0, 0, 0};
  for (int i = 1; i <= 3; ++i) {
    pixdim[i] = version == 2 ? static_cast<nifti_2_header*>(raw)->pixdim[i]
                             : static_cast<double>(static_cast<nifti_1_header*>(raw)->pixdim[i]);
  }
  // Where the voxels start: in a single-file NIfTI at or after the header (352 bytes for
  // NIfTI-1, 540 for NIfTI-2); nifti_clib takes a NaN, negative or short offset as it comes and
  // reads header bytes as voxels (an outside probe's finding).
  const double vox_offset = version == 2 ? double(static_cast<nifti_2_header*>(raw)->vox_offset)
                                         : static_cast<double>(static_cast<nifti_1_header*>(raw)->vox_offset);
  const double header_bytes = version == 2 ? 540 : 352;
  if (!std::isfinite(vox_offset) || vox_offset < header_bytes || vox_offset > 1e12 ||
      vox_offset != std::floor(vox_offset)) {
    std::free(raw);
    return corrupt_data("vox_offset " + number_text(vox_offset) + " is not a whole number of bytes at or after the " +
                        number_text(header_bytes) + "-byte header");
  }
  // nifti_clib turns a non-finite scl_slope or scl_inter into 0 ("no scaling") without a word.
  const double slope = version == 2 ? static_cast<nifti_2_header*>(raw)->scl_slope
                                    : static_cast<double>(static_cast<nifti_1_header*>(raw)->scl_slope);
  const double inter = version == 2 ? static_cast<nifti_2_header*>(raw)->scl_inter
                                    : static_cast<double>(static_cast<nifti_1_header*>(raw)->scl_inter);
  std::free(raw);
  if (!std::isfinite(slope) || slope < 0 || slope > kMaxRescaleSlope || (slope != 0 && slope < kMinRescaleSlope))
    return corrupt_data("scl_slope " + number_text(slope) + " is not 0 (no scaling) or in [" +
                        number_text(kMinRescaleSlope) + ", " + number_text(kMaxRescaleSlope) + "]");
  if (slope != 0 && (!std::isfinite(inter) || std::abs(inter) > kMaxRescaleIntercept))
    return corrupt_data("scl_inter " + number_text(inter) + " is not finite within +-" +
                        number_text(kMaxRescaleIntercept));
  for (int i = 1; i <= 3; ++i) {
    if (!std::isfinite(pixdim[i])) {
      return corrupt_data("voxel size pixdim[" + std::to_string(i) + "] is not finite");
    }
    if (nim.sform_code <= 0 && !(pixdim[i] > 0)) {
      return corrupt_data("voxel size pixdim[" + std::to_string(i) + "] is not positive");
    }
  }
  return {};
}

// The 4x4 voxel-index -> RAS (mm) affine the file declares, and which form it came from.
Eigen::Matrix4d ras_from_index(const nifti_image& nim, std::string* form) {
  Eigen::Matrix4d a = Eigen::Matrix4d::Identity();
  const nifti_dmat44* m = nullptr;
  if (nim.sform_code > 0) {
    m = &nim.sto_xyz;
    *form = "sform";
  } else if (nim.qform_code > 0) {
    m = &nim.qto_xyz;
    *form = "qform";
  }
  if (m) {
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) a(r, c) = m->m[r][c];
  } else {
    *form = "pixdim only";
    a.diagonal().head<3>() = Eigen::Vector3d(std::abs(nim.dx), std::abs(nim.dy), std::abs(nim.dz));
  }
  return a;
}

}  // namespace

Result<CtVolume> read_nifti(const std::filesystem::path& file) {
  const std::string name = file.string();
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec)) return not_found(name + ": no such file");
  nifti_set_debug_level(0);  // nifti_clib otherwise prints its own errors; ours name the file
  // A damaged gzip stream is named as such before nifti_clib fails on it with a vaguer reason.
  if (is_gzipped(name)) {
    if (Status s = check_gzip_stream(name); !s.ok()) return s.with_context(name);
  }

  NiftiPtr nim(nifti_image_read(name.c_str(), /*read_data=*/0));
  if (!nim) return corrupt_data(name + ": not a readable NIfTI-1/2 file (bad magic, size or header)");
  if (Status s = check_header(*nim); !s.ok()) return s.with_context(name);
  if (Status s = check_raw_header(name, *nim); !s.ok()) return s.with_context(name);

  std::string form;
  const Eigen::Matrix4d ras = ras_from_index(*nim, &form);
  if (!ras.allFinite()) return corrupt_data(name + ": the " + form + " affine is not finite");
  const Eigen::Matrix3d lps_from_ras = Eigen::Vector3d(-1, -1, 1).asDiagonal();
  const Eigen::Matrix3d linear = lps_from_ras * ras.topLeftCorner<3, 3>();

  CtVolume ct;
  VolumeGeometry& g = ct.geometry;
  g.size = {int(nim->nx), int(nim->ny), int(nim->nz)};
  for (int c = 0; c < 3; ++c) {
    g.spacing_mm[c] = linear.col(c).norm();
    g.direction.col(c) =
        g.spacing_mm[c] > 0 ? Eigen::Vector3d(linear.col(c) / g.spacing_mm[c]) : Eigen::Vector3d::Zero();
  }
  g.origin_mm = lps_from_ras * ras.topRightCorner<3, 1>();
  if (Status s = g.validate(); !s.ok()) return s.with_context(name + " (" + form + ")");
  if (form == "pixdim only")
    return corrupt_data(name + ": neither sform nor qform is set, so the patient's orientation (left from right "
                        "included) is unknown; set one (e.g. with fslorient or nibabel) and load it again");

  // nifti_clib allocates the whole volume before reading it: the size the header claims is
  // checked against the file first (found by fuzz_ct: 446 bytes claiming 6.5 GB). A plain file
  // must hold it after the header; a gzipped one cannot inflate it beyond deflate's limit of
  // about 1032 to 1.
  {
    const double claimed = double(nim->nvox) * double(nim->nbyper);
    std::error_code size_error;
    const double file_bytes = double(std::filesystem::file_size(file, size_error));
    const bool gz = is_gzipped(name);
    const double most = gz ? 1032.0 * file_bytes : file_bytes - double(nim->iname_offset);
    if (size_error || claimed > most) {
      std::ostringstream m;
      m << name << ": the header claims " << nim->nx << " x " << nim->ny << " x " << nim->nz << " voxels of "
        << nim->nbyper << " bytes (" << std::uint64_t(claimed) << " bytes from offset " << nim->iname_offset
        << "), more than the file's " << std::uint64_t(file_bytes) << " bytes can hold"
        << (gz ? " even compressed" : "") << ": truncated or a damaged header";
      return corrupt_data(m.str());
    }
  }
  if (nifti_image_load(nim.get()) != 0 || nim->data == nullptr) {
    return corrupt_data(name + ": voxel data is truncated or unreadable (header claims " +
                        std::to_string(nim->nvox) + " voxels)");
  }
  const std::size_t count = static_cast<std::size_t>(g.voxel_count());
  if (static_cast<std::size_t>(nim->nvox) != count) {
    return corrupt_data(name + ": voxel count does not match the dimensions");
  }
  double slope = nim->scl_slope;  // finite and in range (check_raw_header)
  double inter = nim->scl_inter;
  if (slope == 0.0) {  // NIfTI: slope 0 means "no scaling"
    slope = 1.0;
    inter = 0.0;
  }
  double bad_stored = 0;
  auto non_finite = first_non_finite_stored(name, *nim, &bad_stored);
  if (!non_finite.ok()) return non_finite.status();
  std::size_t bad = *non_finite < count ? *non_finite : count;
  if (bad == count) switch (nim->datatype) {
    case DT_INT8:
      bad = copy_scaled<int8_t>(nim->data, count, slope, inter, &ct.values, &bad_stored);
      break;
    case DT_UINT8:
      bad = copy_scaled<uint8_t>(nim->data, count, slope, inter, &ct.values, &bad_stored);
      break;
    case DT_INT16:
      bad = copy_scaled<int16_t>(nim->data, count, slope, inter, &ct.values, &bad_stored);
      break;
    case DT_UINT16:
      bad = copy_scaled<uint16_t>(nim->data, count, slope, inter, &ct.values, &bad_stored);
      break;
    case DT_INT32:
      bad = copy_scaled<int32_t>(nim->data, count, slope, inter, &ct.values, &bad_stored);
      break;
    case DT_UINT32:
      bad = copy_scaled<uint32_t>(nim->data, count, slope, inter, &ct.values, &bad_stored);
      break;
    case DT_FLOAT32:
      bad = copy_scaled<float>(nim->data, count, slope, inter, &ct.values, &bad_stored);
      break;
    case DT_FLOAT64:
      bad = copy_scaled<double>(nim->data, count, slope, inter, &ct.values, &bad_stored);
      break;
    default:
      return unsupported(name + ": NIfTI datatype " + std::string(nifti_datatype_string(nim->datatype)) +
                         " is not a scalar type lftrack reads");
  }
  if (bad < count) {
    const std::size_t nx = std::size_t(g.size[0]), ny = std::size_t(g.size[1]);
    return corrupt_data(name + ": voxel (" + std::to_string(bad % nx) + ", " + std::to_string(bad / nx % ny) + ", " +
                        std::to_string(bad / (nx * ny)) + ") holds " + number_text(bad_stored) +
                        (slope == 1.0 && inter == 0.0 ? std::string()
                                                      : " (x scl_slope " + number_text(slope) + " + scl_inter " +
                                                            number_text(inter) + ")") +
                        ": not a finite CT number in the plausible [" + number_text(kLowestPlausibleHu) + ", " +
                        number_text(kHighestPlausibleHu) + "] HU");
  }
  return ct;
}

}  // namespace lftrack::tracking

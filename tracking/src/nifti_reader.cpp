// NIfTI-1/2 reader on nifti_clib (nifti2_io reads both versions, plain or gzipped). nifti_clib
// parses and reads; this file validates the header and turns NIfTI's RAS world into LPS.

#include <nifti2_io.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <sstream>

#include <spdlog/spdlog.h>

#include "lftrack/tracking/volume_io.hpp"

namespace lftrack::tracking {
namespace {

struct NiftiDeleter {
  void operator()(nifti_image* nim) const { nifti_image_free(nim); }
};
using NiftiPtr = std::unique_ptr<nifti_image, NiftiDeleter>;

template <class T>
void copy_scaled(const void* data, std::size_t count, double slope, double inter, std::vector<float>* out) {
  const T* p = static_cast<const T*>(data);
  out->resize(count);
  for (std::size_t i = 0; i < count; ++i) {
    (*out)[i] = static_cast<float>(slope * static_cast<double>(p[i]) + inter);
  }
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
// corrupt, so the raw header's voxel sizes are checked here. They scale the qform and the
// pixdim-only fallback; the sform does not use them.
Status check_raw_pixdim(const std::string& name, const nifti_image& nim) {
  int version = 0;
  void* raw = nifti_read_header(name.c_str(), &version, 0);
  if (!raw) return corrupt_data("header cannot be read");
  double pixdim[4] = {0, 0, 0, 0};
  for (int i = 1; i <= 3; ++i) {
    pixdim[i] = version == 2 ? static_cast<nifti_2_header*>(raw)->pixdim[i]
                             : static_cast<double>(static_cast<nifti_1_header*>(raw)->pixdim[i]);
  }
  std::free(raw);
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

  NiftiPtr nim(nifti_image_read(name.c_str(), /*read_data=*/0));
  if (!nim) return corrupt_data(name + ": not a readable NIfTI-1/2 file (bad magic, size or header)");
  if (Status s = check_header(*nim); !s.ok()) return s.with_context(name);
  if (Status s = check_raw_pixdim(name, *nim); !s.ok()) return s.with_context(name);

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
  if (form == "pixdim only") {
    spdlog::warn("{}: neither sform nor qform is set; orientation assumed from pixdim alone", name);
  }

  if (nifti_image_load(nim.get()) != 0 || nim->data == nullptr) {
    return corrupt_data(name + ": voxel data is truncated or unreadable (header claims " +
                        std::to_string(nim->nvox) + " voxels)");
  }
  const std::size_t count = static_cast<std::size_t>(g.voxel_count());
  if (static_cast<std::size_t>(nim->nvox) != count) {
    return corrupt_data(name + ": voxel count does not match the dimensions");
  }
  double slope = nim->scl_slope;
  double inter = nim->scl_inter;
  if (slope == 0.0 || !std::isfinite(slope)) {  // NIfTI: slope 0 means "no scaling"
    slope = 1.0;
    inter = 0.0;
  }
  if (!std::isfinite(inter)) inter = 0.0;
  switch (nim->datatype) {
    case DT_INT8:
      copy_scaled<int8_t>(nim->data, count, slope, inter, &ct.values);
      break;
    case DT_UINT8:
      copy_scaled<uint8_t>(nim->data, count, slope, inter, &ct.values);
      break;
    case DT_INT16:
      copy_scaled<int16_t>(nim->data, count, slope, inter, &ct.values);
      break;
    case DT_UINT16:
      copy_scaled<uint16_t>(nim->data, count, slope, inter, &ct.values);
      break;
    case DT_INT32:
      copy_scaled<int32_t>(nim->data, count, slope, inter, &ct.values);
      break;
    case DT_UINT32:
      copy_scaled<uint32_t>(nim->data, count, slope, inter, &ct.values);
      break;
    case DT_FLOAT32:
      copy_scaled<float>(nim->data, count, slope, inter, &ct.values);
      break;
    case DT_FLOAT64:
      copy_scaled<double>(nim->data, count, slope, inter, &ct.values);
      break;
    default:
      return unsupported(name + ": NIfTI datatype " + std::string(nifti_datatype_string(nim->datatype)) +
                         " is not a scalar type lftrack reads");
  }
  std::size_t non_finite = 0;
  for (float v : ct.values) non_finite += std::isfinite(v) ? 0 : 1;
  if (non_finite > 0) {
    return corrupt_data(name + ": " + std::to_string(non_finite) + " voxel(s) are NaN or infinite");
  }
  return ct;
}

}  // namespace lftrack::tracking

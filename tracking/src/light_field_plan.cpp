// Light-field geometry: the two planes, ray coordinates, and the extents a scene requires.

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "lftrack/tracking/checksum.hpp"
#include "lftrack/tracking/light_field.hpp"

namespace lftrack::tracking {

using Eigen::Vector3d;
using Eigen::Vector4d;

const char* to_string(LightFieldStorage storage) {
  switch (storage) {
    case LightFieldStorage::kFloat32:
      return "float";
    case LightFieldStorage::kFixed16:
      return "fixed16";
    case LightFieldStorage::kVq:
      return "vq";
  }
  return "unknown";
}

const char* to_string(LightFieldIntegration integration) {
  switch (integration) {
    case LightFieldIntegration::kSlices:
      return "slices";
    case LightFieldIntegration::kSiddon:
      return "siddon";
  }
  return "unknown";
}

std::optional<Vector4d> LightFieldGeometry::coordinates(const Vector3d& a, const Vector3d& b) const {
  const Vector3d d = b - a;
  const double dn = d.dot(axis);
  if (!(std::abs(dn) > 1e-9 * d.norm())) return std::nullopt;
  const Vector3d on_uv = a + ((source_ct_mm - a).dot(axis) / dn) * d - source_ct_mm;
  const Vector3d on_st = a + ((roi_centre_ct_mm - a).dot(axis) / dn) * d - roi_centre_ct_mm;
  return Vector4d(on_uv.dot(e1), on_uv.dot(e2), on_st.dot(e1), on_st.dot(e2));
}

void LightFieldGeometry::ray(const Vector4d& uvst, Vector3d* on_uv, Vector3d* on_st) const {
  *on_uv = source_ct_mm + uvst[0] * e1 + uvst[1] * e2;
  *on_st = roi_centre_ct_mm + uvst[2] * e1 + uvst[3] * e2;
}

Status LightFieldGeometry::validate() const {
  for (int a = 0; a < 4; ++a) {
    if (size[a] < 2 || size[a] > 4096) return out_of_range("light-field axis sizes must be in 2..4096");
    if (!std::isfinite(lo[a]) || !std::isfinite(hi[a]) || !(hi[a] > lo[a])) {
      return invalid_argument("light-field extent is empty or not finite");
    }
  }
  if (sample_count() > (std::int64_t{1} << 32)) return out_of_range("light field of more than 2^32 samples");
  if (!source_ct_mm.allFinite() || !roi_centre_ct_mm.allFinite() || !axis.allFinite() || !e1.allFinite() ||
      !e2.allFinite()) {
    return invalid_argument("light-field planes are not finite");
  }
  if ((roi_centre_ct_mm - source_ct_mm).norm() < 1.0)
    return invalid_argument("ROI centre sits on the source");
  return {};
}

namespace {

// Widens [lo, hi], sampled at n points, as little as possible so that 0 is one of the points.
// For u and v, 0 is the nominal source: every ray of the nominal pose then has exact (u, v)
// samples and only the (s, t) interpolation is left. (With the extents symmetric about the
// source and an even n, the nominal pose fell midway between samples, the worst place: on the
// lumbar CT it was the least faithful pose, NCC 0.9981 against Siddon.) Unchanged when 0 is
// outside the range or n < 3.
void put_sample_at_zero(double* lo, double* hi, int n) {
  if (n < 3 || !(*lo < 0 && *hi > 0)) return;
  double best = std::numeric_limits<double>::infinity();
  int best_k = 0;
  for (int k = 1; k <= n - 2; ++k) {  // k samples below 0, n - 1 - k above
    const double spacing = std::max(-*lo / k, *hi / (n - 1 - k));
    if (spacing < best) best = spacing, best_k = k;
  }
  *lo = -best_k * best;
  *hi = (n - 1 - best_k) * best;
}

}  // namespace

Result<LightFieldGeometry> plan_light_field(const LightFieldPlanInput& in, const LightFieldSpec& spec) {
  LFTRACK_RETURN_IF_ERROR(in.view_room.validate());
  if (!in.roi_window.inside(in.view_room.rows, in.view_room.cols)) {
    return out_of_range("the ROI window is not inside view '" + in.view_room.name + "'");
  }
  if (!(spec.margin_fraction >= 0 && spec.margin_fraction <= 1)) {
    return out_of_range("light-field margin must be a fraction in [0, 1]");
  }
  LightFieldGeometry g;
  g.view_name = in.view_room.name;
  g.size = spec.resolution;
  const XrayView view_ct = in.view_room.transformed(in.nominal_T_room_from_ct.inverse());
  g.source_ct_mm = view_ct.source_mm;
  g.roi_centre_ct_mm = in.roi_centre_ct_mm;
  g.axis = (g.roi_centre_ct_mm - g.source_ct_mm).normalized();
  // e2 (t, the samples' innermost axis) follows the detector's rows, so that neighbouring pixels
  // of a row read neighbouring samples (the AVX-512 kernel reads them as runs).
  g.e1 = (view_ct.row_axis - view_ct.row_axis.dot(g.axis) * g.axis).normalized();
  g.e2 = g.axis.cross(g.e1);
  if (g.e2.dot(view_ct.col_axis) < 0) g.e2 = -g.e2;

  // Rays of the ROI window's outline (its outer pixel edges) at the envelope's 3^6 poses.
  std::vector<Eigen::Vector2d> outline;  // (row, col)
  const PixelWindow& w = in.roi_window;
  const double r0 = w.row0 - 0.5, r1 = w.row0 + w.rows - 0.5, c0 = w.col0 - 0.5, c1 = w.col0 + w.cols - 0.5;
  constexpr int kSteps = 32;
  for (int k = 0; k <= kSteps; ++k) {
    const double f = double(k) / kSteps;
    outline.emplace_back(r0 + f * (r1 - r0), c0);
    outline.emplace_back(r0 + f * (r1 - r0), c1);
    outline.emplace_back(r0, c0 + f * (c1 - c0));
    outline.emplace_back(r1, c0 + f * (c1 - c0));
  }
  Vector4d lo = Vector4d::Constant(1e300), hi = Vector4d::Constant(-1e300);
  const double t = in.envelope.translation_mm, r = deg_to_rad(in.envelope.rotation_deg);
  for (int code = 0; code < 729; ++code) {
    int digits = code;
    PoseDelta delta;
    for (int a = 0; a < 6; ++a) {
      const double level = double(digits % 3 - 1);
      digits /= 3;
      if (a < 3)
        delta.translation_mm[a] = level * t;
      else
        delta.rotation_rad[a - 3] = level * r;
    }
    const Pose pose = apply_delta(in.nominal_T_room_from_ct, delta, in.registration_origin_room_mm);
    const Pose ct_from_room = pose.inverse();
    const Vector3d source = ct_from_room * in.view_room.source_mm;
    for (const auto& rc : outline) {
      const auto uvst = g.coordinates(source, ct_from_room * in.view_room.pixel_centre_mm(rc.x(), rc.y()));
      if (!uvst)
        return invalid_argument("a ray of view '" + g.view_name +
                                "' runs parallel to its light-field planes");
      lo = lo.cwiseMin(*uvst);
      hi = hi.cwiseMax(*uvst);
    }
  }
  for (int a = 0; a < 4; ++a) {
    double extent = hi[a] - lo[a];
    if (extent < 2.0) {  // no motion along this axis (an empty envelope): keep a 2 mm cell
      const double mid = 0.5 * (lo[a] + hi[a]);
      lo[a] = mid - 1.0;
      hi[a] = mid + 1.0;
      extent = 2.0;
    }
    g.lo[a] = lo[a] - spec.margin_fraction * extent;
    g.hi[a] = hi[a] + spec.margin_fraction * extent;
  }
  for (int a = 0; a < 2; ++a) put_sample_at_zero(&g.lo[a], &g.hi[a], g.size[a]);
  LFTRACK_RETURN_IF_ERROR(g.validate());
  return g;
}

namespace {

template <class T>
void feed(uLong* crc, const T& value) {
  *crc = crc32(*crc, reinterpret_cast<const Bytef*>(&value), sizeof(T));
}

void feed_vector(uLong* crc, const Vector3d& v) {
  for (int i = 0; i < 3; ++i) feed(crc, v[i]);
}

std::uint64_t combine(uLong a, uLong b) {
  return (std::uint64_t{a} << 32) | (std::uint64_t{b} & 0xffffffffu);
}

}  // namespace

std::uint64_t volume_hash(const MuVolume& mu) {
  uLong geometry = crc32(0L, Z_NULL, 0);
  const VolumeGeometry& g = mu.geometry;
  for (int i = 0; i < 3; ++i) feed(&geometry, g.size[i]);
  feed_vector(&geometry, g.spacing_mm);
  feed_vector(&geometry, g.origin_mm);
  for (int i = 0; i < 9; ++i) feed(&geometry, g.direction.data()[i]);
  const uLong data = crc32_of(mu.values.data(), mu.values.size() * sizeof(float));
  return combine(geometry, data);
}

// How plan_light_field lays a field out, in the plan hash so that files planned otherwise are
// rebuilt. 2: t along the detector's rows and a (u, v) sample at the nominal source.
constexpr std::uint32_t kPlanConvention = 2;

std::uint64_t plan_hash(const LightFieldPlanInput& in, const LightFieldSpec& spec) {
  uLong view = crc32(0L, Z_NULL, 0);
  feed(&view, kPlanConvention);
  const XrayView& v = in.view_room;
  view = crc32(view, reinterpret_cast<const Bytef*>(v.name.data()), static_cast<uInt>(v.name.size()));
  feed_vector(&view, v.source_mm);
  feed_vector(&view, v.pixel00_mm);
  feed_vector(&view, v.col_axis);
  feed_vector(&view, v.row_axis);
  feed(&view, v.pitch_col_mm);
  feed(&view, v.pitch_row_mm);
  feed(&view, v.rows);
  feed(&view, v.cols);
  feed(&view, in.roi_window.row0);
  feed(&view, in.roi_window.col0);
  feed(&view, in.roi_window.rows);
  feed(&view, in.roi_window.cols);
  uLong rest = crc32(0L, Z_NULL, 0);
  for (int i = 0; i < 16; ++i) feed(&rest, in.nominal_T_room_from_ct.matrix().data()[i]);
  feed_vector(&rest, in.registration_origin_room_mm);
  feed_vector(&rest, in.roi_centre_ct_mm);
  feed(&rest, in.envelope.translation_mm);
  feed(&rest, in.envelope.rotation_deg);
  for (int a = 0; a < 4; ++a) feed(&rest, spec.resolution[a]);
  feed(&rest, spec.margin_fraction);
  // (Slices fall back to the walk where they cannot be used, so whatever the integration.)
  if (spec.skip_air_below_hu > -1000) feed(&rest, spec.skip_air_below_hu);
  if (spec.integration != LightFieldIntegration::kSiddon) {
    feed(&rest, spec.integration);
    feed(&rest, spec.slice_step_mm > 0 && std::isfinite(spec.slice_step_mm) ? spec.slice_step_mm : 0.0);
  }
  return combine(view, rest);
}

}  // namespace lftrack::tracking

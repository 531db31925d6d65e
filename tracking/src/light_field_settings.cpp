// What a light field was built with, against what is asked for now: the detector's identity and
// the differences a stale field names (light_field.hpp).

#include <zlib.h>

#include <cmath>
#include <cstdio>
#include <sstream>

#include "lftrack/tracking/light_field.hpp"

namespace lftrack::tracking {
namespace {

template <class T>
void feed(uLong* crc, const T& value) {
  *crc = crc32(*crc, reinterpret_cast<const Bytef*>(&value), sizeof(T));
}

std::string number(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

std::string vector_text(const Eigen::Vector3d& v) {
  std::ostringstream s;
  s << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return s.str();
}

std::string window_text(const PixelWindow& w) {
  std::ostringstream s;
  s << "rows " << w.row0 << "+" << w.rows << ", cols " << w.col0 << "+" << w.cols;
  return s.str();
}

std::string resolution_text(const std::array<int, 4>& r) {
  std::ostringstream s;
  s << r[0] << "x" << r[1] << "x" << r[2] << "x" << r[3];
  return s.str();
}

std::string hex(std::uint64_t v) {
  char buf[20];
  std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
  return buf;
}

// The slice step as the plan hash counts it: 0 when not a positive finite step.
double step_of(double step_mm) { return step_mm > 0 && std::isfinite(step_mm) ? step_mm : 0.0; }

}  // namespace

std::uint64_t detector_geometry_hash(const XrayView& v) {
  uLong a = crc32(0L, Z_NULL, 0), b = crc32(0L, Z_NULL, 0);
  a = crc32(a, reinterpret_cast<const Bytef*>(v.name.data()), static_cast<uInt>(v.name.size()));
  for (const Eigen::Vector3d* p : {&v.source_mm, &v.pixel00_mm})
    for (int i = 0; i < 3; ++i) feed(&a, (*p)[i]);
  for (const Eigen::Vector3d* p : {&v.col_axis, &v.row_axis})
    for (int i = 0; i < 3; ++i) feed(&b, (*p)[i]);
  feed(&b, v.pitch_col_mm);
  feed(&b, v.pitch_row_mm);
  feed(&b, v.rows);
  feed(&b, v.cols);
  return (std::uint64_t{a} << 32) | (std::uint64_t{b} & 0xffffffffu);
}

std::vector<std::string> light_field_differences(const LightField::Header& h, std::uint64_t ct_hash,
                                                 const LightFieldPlanInput& in, const LightFieldSpec& spec) {
  std::vector<std::string> d;
  const auto differs = [&](const std::string& what, const std::string& file, const std::string& now) {
    std::ostringstream s;
    s << what << " (" << file << " in the file, " << now << " now)";
    d.push_back(s.str());
  };
  const LightFieldGeometry& g = h.geometry;
  if (h.ct_hash != ct_hash) differs("CT", "volume hash " + hex(h.ct_hash), hex(ct_hash));
  if (g.view_name != in.view_room.name) differs("view", g.view_name, in.view_room.name);
  if (h.settings_recorded && h.detector_hash != detector_geometry_hash(in.view_room))
    d.push_back("detector geometry of view " + in.view_room.name + " (source, panel position, axes, pitch or size)");
  if (h.settings_recorded && (h.roi_window.row0 != in.roi_window.row0 || h.roi_window.col0 != in.roi_window.col0 ||
                              h.roi_window.rows != in.roi_window.rows || h.roi_window.cols != in.roi_window.cols))
    differs("ROI window (roi)", window_text(h.roi_window), window_text(in.roi_window));
  if (g.roi_centre_ct_mm != in.roi_centre_ct_mm)
    differs("ROI centre (roi.centre_mm)", vector_text(g.roi_centre_ct_mm), vector_text(in.roi_centre_ct_mm));
  if (h.nominal_T_room_from_ct.matrix() != in.nominal_T_room_from_ct.matrix())
    differs("nominal pose", "translation " + vector_text(h.nominal_T_room_from_ct.translation()),
            "translation " + vector_text(in.nominal_T_room_from_ct.translation()));
  if (h.registration_origin_room_mm != in.registration_origin_room_mm)
    differs("registration origin", vector_text(h.registration_origin_room_mm), vector_text(in.registration_origin_room_mm));
  if (h.envelope.translation_mm != in.envelope.translation_mm)
    differs("envelope translation_mm", number(h.envelope.translation_mm), number(in.envelope.translation_mm));
  if (h.envelope.rotation_deg != in.envelope.rotation_deg)
    differs("envelope rotation_deg", number(h.envelope.rotation_deg), number(in.envelope.rotation_deg));
  if (g.size != spec.resolution) differs("resolution", resolution_text(g.size), resolution_text(spec.resolution));
  if (h.settings_recorded) {
    if (h.margin_fraction != spec.margin_fraction)
      differs("margin", number(h.margin_fraction), number(spec.margin_fraction));
    if (h.integration != spec.integration)
      differs("integration", to_string(h.integration), to_string(spec.integration));
    const bool sliced = h.integration == LightFieldIntegration::kSlices || spec.integration == LightFieldIntegration::kSlices;
    if (sliced && step_of(h.slice_step_mm) != step_of(spec.slice_step_mm)) {
      const auto text = [](double step) { return step > 0 ? number(step) : std::string("0 (the CT's finest spacing)"); };
      differs("slice_step_mm", text(step_of(h.slice_step_mm)), text(step_of(spec.slice_step_mm)));
    }
  }
  if (h.storage != spec.storage) differs("storage", to_string(h.storage), to_string(spec.storage));
  if (h.storage == LightFieldStorage::kVq && spec.storage == LightFieldStorage::kVq) {
    if (h.codebook_size != spec.vq_codebook_size)
      differs("codebook", std::to_string(h.codebook_size), std::to_string(spec.vq_codebook_size));
    if (h.settings_recorded && h.vq_training_tiles != spec.vq_training_tiles)
      differs("VQ training tiles", std::to_string(h.vq_training_tiles), std::to_string(spec.vq_training_tiles));
    if (h.settings_recorded && h.vq_seed != spec.vq_seed)
      differs("VQ seed", std::to_string(h.vq_seed), std::to_string(spec.vq_seed));
  }
  if (d.empty() && h.plan_hash != plan_hash(in, spec))
    d.push_back(h.settings_recorded
                    ? "the way fields are planned (an older lftrack planned it)"
                    : "a setting an older lftrack did not record in the file (ROI window, detector geometry, margin, "
                      "integration or slice_step_mm), or the way it planned fields");
  return d;
}

}  // namespace lftrack::tracking

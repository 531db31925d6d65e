// The scene's detectors: detectors[i] (its view geometry, pixel pitch and grid, the light field it
// is registered with) and the light-field settings of the tracking and simulated renderers. Every
// value is checked here, at load, with file:line:col (scene_yaml.hpp). Their frames and calibration
// are the devices' (scene_device_parser.cpp).

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <sstream>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/registration.hpp"
#include "scene_yaml.hpp"

namespace lftrack::session {

Status SceneParser::parse_light_field(const YAML::Node& n, const std::string& what,
                                      tracking::LightFieldSpec* spec) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(
      n, what,
      {"resolution", "storage", "codebook", "margin", "integration", "slice_step_mm", "skip_air_below_hu"}));
  if (const YAML::Node r = n["resolution"]) {
    if (!r.IsSequence() || r.size() != 4) return error(r, what + ".resolution must be [u, v, s, t]");
    for (std::size_t a = 0; a < 4; ++a) {
      long value = 0;
      LFTRACK_RETURN_IF_ERROR(integer(r[a], what + ".resolution", 2, 4096, &value));
      spec->resolution[a] = static_cast<int>(value);
    }
    // Each view's field is built as 32-bit floats before any compression: refused here, before
    // anything is allocated, where that exceeds 4 GiB (2^30 samples).
    double samples = 1;
    for (int v : spec->resolution) samples *= double(v);
    if (samples > double(1u << 30)) {
      std::ostringstream m;
      m << what << ".resolution [" << spec->resolution[0] << ", " << spec->resolution[1] << ", "
        << spec->resolution[2] << ", " << spec->resolution[3] << "] is "
        << static_cast<unsigned long long>(samples) << " samples: " << std::fixed << std::setprecision(1)
        << samples * 4 / double(1u << 30) << " GiB per view to build, more than the 4 GiB allowed";
      return error(r, m.str());
    }
  }
  if (const YAML::Node s = n["storage"]) {
    std::string storage;
    LFTRACK_RETURN_IF_ERROR(text(s, what + ".storage", &storage));
    if (storage == "float")
      spec->storage = tracking::LightFieldStorage::kFloat32;
    else if (storage == "fixed16")
      spec->storage = tracking::LightFieldStorage::kFixed16;
    else if (storage == "vq")
      spec->storage = tracking::LightFieldStorage::kVq;
    else
      return error(s, what + ".storage must be one of float, fixed16, vq; got '" + storage + "'");
  }
  if (const YAML::Node c = n["codebook"]) {
    long size = 0;
    LFTRACK_RETURN_IF_ERROR(integer(c, what + ".codebook", 2, 65536, &size));
    spec->vq_codebook_size = static_cast<int>(size);
  }
  if (const YAML::Node i = n["integration"]) {
    std::string integration;
    LFTRACK_RETURN_IF_ERROR(text(i, what + ".integration", &integration));
    if (integration == "slices")
      spec->integration = tracking::LightFieldIntegration::kSlices;
    else if (integration == "siddon")
      spec->integration = tracking::LightFieldIntegration::kSiddon;
    else
      return error(i, what + ".integration must be slices or siddon; got '" + integration + "'");
  }
  if (const YAML::Node step = n["slice_step_mm"]) {
    LFTRACK_RETURN_IF_ERROR(number(step, what + ".slice_step_mm", &spec->slice_step_mm));
    if (!(spec->slice_step_mm >= 0.01 && spec->slice_step_mm <= 10))
      return error(step, what + ".slice_step_mm is the depth between slices, in [0.01, 10] mm");
  }
  if (const YAML::Node air = n["skip_air_below_hu"]) {
    LFTRACK_RETURN_IF_ERROR(number(air, what + ".skip_air_below_hu", &spec->skip_air_below_hu));
    if (!(spec->skip_air_below_hu >= -1000 && spec->skip_air_below_hu <= -500))
      return error(air, what +
                            ".skip_air_below_hu is the CT number below which the air around the body is left "
                            "out of the walk, in [-1000, -500] HU (-1000: walk the whole grid)");
  }
  if (const YAML::Node m = n["margin"]) {
    LFTRACK_RETURN_IF_ERROR(number(m, what + ".margin", &spec->margin_fraction));
    if (spec->margin_fraction < 0 || spec->margin_fraction > 1) {
      return error(m, what + ".margin is a fraction of each extent, in [0, 1]");
    }
  }
  return {};
}

Status SceneParser::parse_detector(const YAML::Node& n, int index, DetectorSpec* d) const {
  const std::string what = "detectors[" + std::to_string(index) + "]";
  LFTRACK_RETURN_IF_ERROR(check_keys(n, what,
                                     {"name", "frames", "calibration", "bits", "rows", "cols", "pitch_mm",
                                      "isocentric", "source_mm", "pixel00_mm", "col_axis", "row_axis"}));
  YAML::Node node;
  std::string name;
  LFTRACK_RETURN_IF_ERROR(need(n, "name", what, &node));
  LFTRACK_RETURN_IF_ERROR(text(node, what + ".name", &name));
  // A detector's name becomes part of file names (its light field, its archive's frames, its
  // calibration): the rule `calibrate detector --detector` has (issue 50 probe: a name with
  // "../" wrote light fields outside --lf-dir).
  if (!is_detector_name(name))
    return error(node, what + ".name '" + name.substr(0, 80) +
                           "': a detector name is 1 to 64 letters, digits, '_', '-' or '.' (not first)");
  if (n["frames"]) LFTRACK_RETURN_IF_ERROR(parse_frames(n["frames"], what + ".frames", &d->frames));
  if (n["calibration"]) {
    LFTRACK_RETURN_IF_ERROR(
        parse_detector_calibration(n["calibration"], what + ".calibration", &d->calibration_file));
    d->simulator_calibration = d->calibration_file.empty();
  }
  long bits = 12, rows = 0, cols = 0;
  if (n["bits"]) LFTRACK_RETURN_IF_ERROR(integer(n["bits"], what + ".bits", 8, 16, &bits));
  LFTRACK_RETURN_IF_ERROR(need(n, "rows", what, &node));
  LFTRACK_RETURN_IF_ERROR(integer(node, what + ".rows", 1, 16384, &rows));
  LFTRACK_RETURN_IF_ERROR(need(n, "cols", what, &node));
  LFTRACK_RETURN_IF_ERROR(integer(node, what + ".cols", 1, 16384, &cols));
  YAML::Node pitch_node;
  LFTRACK_RETURN_IF_ERROR(need(n, "pitch_mm", what, &pitch_node));
  double pitch_row = 0, pitch_col = 0;
  if (pitch_node.IsSequence() && pitch_node.size() == 2) {
    LFTRACK_RETURN_IF_ERROR(positive(pitch_node[0], what + ".pitch_mm[row]", &pitch_row));
    LFTRACK_RETURN_IF_ERROR(positive(pitch_node[1], what + ".pitch_mm[col]", &pitch_col));
  } else {
    LFTRACK_RETURN_IF_ERROR(positive(pitch_node, what + ".pitch_mm", &pitch_row));
    pitch_col = pitch_row;
  }
  d->bits = static_cast<int>(bits);

  const bool explicit_form = n["source_mm"] || n["pixel00_mm"] || n["col_axis"] || n["row_axis"];
  if (n["isocentric"] && explicit_form) {
    return error(n, what + " gives both 'isocentric' and explicit geometry; use one");
  }
  if (n["isocentric"]) {
    const YAML::Node iso = n["isocentric"];
    const std::string w = what + ".isocentric";
    LFTRACK_RETURN_IF_ERROR(check_keys(
        iso, w,
        {"isocentre_mm", "source_direction", "up", "source_to_isocentre_mm", "source_to_detector_mm"}));
    Vector3d centre = Vector3d::Zero(), dir, up;
    double sad = 0, sid = 0;
    if (iso["isocentre_mm"]) LFTRACK_RETURN_IF_ERROR(vec3(iso["isocentre_mm"], w + ".isocentre_mm", &centre));
    LFTRACK_RETURN_IF_ERROR(need(iso, "source_direction", w, &node));
    LFTRACK_RETURN_IF_ERROR(unit_vec3(node, w + ".source_direction", &dir));
    LFTRACK_RETURN_IF_ERROR(need(iso, "up", w, &node));
    LFTRACK_RETURN_IF_ERROR(unit_vec3(node, w + ".up", &up));
    LFTRACK_RETURN_IF_ERROR(need(iso, "source_to_isocentre_mm", w, &node));
    LFTRACK_RETURN_IF_ERROR(positive(node, w + ".source_to_isocentre_mm", &sad));
    LFTRACK_RETURN_IF_ERROR(need(iso, "source_to_detector_mm", w, &node));
    LFTRACK_RETURN_IF_ERROR(positive(node, w + ".source_to_detector_mm", &sid));
    auto view = tracking::XrayView::isocentric(name, centre, dir, up, sad, sid, static_cast<int>(rows),
                                               static_cast<int>(cols), pitch_row);
    if (!view.ok()) return error(iso, view.status().message());
    d->view = *view;
    d->view.pitch_col_mm = pitch_col;
    d->view.pitch_row_mm = pitch_row;
    if (pitch_col != pitch_row) {  // keep the detector centred on the axis
      const double mid_row = 0.5 * static_cast<double>(rows - 1),
                   mid_col = 0.5 * static_cast<double>(cols - 1);
      d->view.pixel00_mm +=
          view->pixel_centre_mm(mid_row, mid_col) - d->view.pixel_centre_mm(mid_row, mid_col);
    }
  } else if (explicit_form) {
    tracking::XrayView& v = d->view;
    LFTRACK_RETURN_IF_ERROR(need(n, "source_mm", what, &node));
    LFTRACK_RETURN_IF_ERROR(vec3(node, what + ".source_mm", &v.source_mm));
    LFTRACK_RETURN_IF_ERROR(need(n, "pixel00_mm", what, &node));
    LFTRACK_RETURN_IF_ERROR(vec3(node, what + ".pixel00_mm", &v.pixel00_mm));
    LFTRACK_RETURN_IF_ERROR(need(n, "col_axis", what, &node));
    LFTRACK_RETURN_IF_ERROR(unit_vec3(node, what + ".col_axis", &v.col_axis));
    LFTRACK_RETURN_IF_ERROR(need(n, "row_axis", what, &node));
    LFTRACK_RETURN_IF_ERROR(unit_vec3(node, what + ".row_axis", &v.row_axis));
    v.name = name;
    v.rows = int(rows);
    v.cols = int(cols);
    v.pitch_row_mm = pitch_row;
    v.pitch_col_mm = pitch_col;
  } else {
    return error(
        n, what + " needs its geometry: either 'isocentric' or source_mm, pixel00_mm, col_axis, row_axis");
  }
  if (Status s = d->view.validate(); !s.ok()) return error(n, s.message());
  return {};
}

}  // namespace lftrack::session

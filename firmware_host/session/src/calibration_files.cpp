#include "lftrack/session/calibration_files.hpp"
#include "lftrack/session/scene_devices.hpp"

#include <fstream>
#include <sstream>

#include "lftrack/tracking/pose.hpp"
#include "scene_yaml.hpp"

namespace lftrack::session {

namespace {

// The YAML document in `file`, or a message naming the file (and line, for a syntax error).
Result<YAML::Node> read_yaml(const std::string& file, const std::string& what) {
  auto text = read_yaml_text(file, what);
  if (!text.ok()) return text.status();
  try {
    return YAML::Load(*text);
  } catch (const YAML::Exception& e) {
    return SceneParser(file, fs::path(file).parent_path()).error_at(e.mark, "not valid YAML: " + e.msg);
  }
}

}  // namespace

Result<calib::CalibrationPhantom> load_calibration_phantom(const std::string& file_or_builtin) {
  if (file_or_builtin == "builtin") return calib::builtin_calibration_phantom();
  const fs::path path(file_or_builtin);
  auto document = read_yaml(file_or_builtin, "phantom file");
  if (!document.ok()) return document.status();
  const YAML::Node root = *document;
  const SceneParser p(file_or_builtin, path.parent_path());
  if (!root.IsMap()) return invalid_argument(file_or_builtin + ": a phantom file is a mapping");
  LFTRACK_RETURN_IF_ERROR(p.check_keys(
      root, "the phantom",
      {"name", "marker_diameter_mm", "body_size_mm", "markers_mm", "marker_mu_per_mm", "body_mu_per_mm"}));
  calib::CalibrationPhantom phantom;
  phantom.name = fs::path(file_or_builtin).stem().string();
  if (root["name"]) LFTRACK_RETURN_IF_ERROR(p.text(root["name"], "name", &phantom.name));
  if (root["marker_diameter_mm"]) {
    LFTRACK_RETURN_IF_ERROR(
        p.positive(root["marker_diameter_mm"], "marker_diameter_mm", &phantom.marker_diameter_mm));
  }
  if (root["marker_mu_per_mm"]) {
    LFTRACK_RETURN_IF_ERROR(
        p.positive(root["marker_mu_per_mm"], "marker_mu_per_mm", &phantom.marker_mu_per_mm));
  }
  if (root["body_mu_per_mm"]) {
    LFTRACK_RETURN_IF_ERROR(p.number(root["body_mu_per_mm"], "body_mu_per_mm", &phantom.body_mu_per_mm));
  }
  if (root["body_size_mm"])
    LFTRACK_RETURN_IF_ERROR(p.vec3(root["body_size_mm"], "body_size_mm", &phantom.body_size_mm));
  YAML::Node markers;
  LFTRACK_RETURN_IF_ERROR(p.need(root, "markers_mm", "the phantom", &markers));
  if (!markers.IsSequence()) return p.error(markers, "markers_mm must be a list of [x, y, z]");
  for (std::size_t i = 0; i < markers.size(); ++i) {
    Eigen::Vector3d m;
    LFTRACK_RETURN_IF_ERROR(p.vec3(markers[i], "markers_mm[" + std::to_string(i) + "]", &m));
    phantom.markers_mm.push_back(m);
  }
  if (Status s = phantom.validate(); !s.ok()) return s.with_context(file_or_builtin);
  return phantom;
}

namespace {

std::string vec(const Eigen::Vector3d& v, int precision) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(precision);
  s << "[" << v.x() << ", " << v.y() << ", " << v.z() << "]";
  return s.str();
}

}  // namespace

std::string calibrated_detectors_yaml(const std::vector<DetectorSpec>& specs,
                                      const calib::TwoViewCalibration& cal, const std::string& provenance) {
  std::ostringstream y;
  y << "# Detector geometry from a phantom calibration (lftrack calibrate views), room frame:\n"
    << "# isocentre at the midpoint of the two central rays' common perpendicular, z = s_B x s_A,\n"
    << "# y away from the sources (calib/room_frame.hpp). Paste the detectors section into a scene.\n"
    << "# " << provenance << "\n"
    << "detectors:\n";
  for (std::size_t k = 0; k < 2; ++k) {
    const tracking::XrayView& v = cal.views_room[k];
    y << "  - name: " << v.name << "\n"
      << "    frames: " << (k < specs.size() ? frames_yaml(specs[k].frames) : std::string("sim")) << "\n"
      << "    bits: " << (k < specs.size() ? specs[k].bits : 12) << "\n"
      << "    rows: " << v.rows << "\n"
      << "    cols: " << v.cols << "\n";
    y.precision(8);
    y << "    pitch_mm: " << v.pitch_col_mm << "\n"
      << "    source_mm: " << vec(v.source_mm, 4) << "\n"
      << "    pixel00_mm: " << vec(v.pixel00_mm, 4) << "\n"
      << "    col_axis: " << vec(v.col_axis, 9) << "\n"
      << "    row_axis: " << vec(v.row_axis, 9) << "\n";
  }
  y << "calibration:\n"
    << "  central_ray_gap_mm: " << cal.room.central_ray_gap_mm << "\n"
    << "  angle_between_views_deg: " << cal.room.angle_between_views_deg << "\n"
    << "  views:\n";
  for (std::size_t k = 0; k < 2; ++k) {
    const calib::ViewCalibration& c = cal.in_phantom[k];
    y << "    - name: " << c.view.name << "\n"
      << "      rms_px: " << c.rms_px << "\n"
      << "      markers_matched: " << c.markers_matched << "\n"
      << "      markers_expected: " << c.markers_projected << "\n"
      << "      detections: " << c.detections << "\n"
      << "      source_sd_mm: " << vec(c.source_sd_mm, 4) << "   # 1 sigma, phantom axes\n"
      << "      pixel00_sd_mm: " << vec(c.pixel00_sd_mm, 4) << "\n"
      << "      orientation_sd_deg: " << vec(c.orientation_sd_deg, 5) << "\n"
      << "      source_to_detector_mm: " << c.source_to_detector_mm << "\n"
      << "      source_to_detector_sd_mm: " << c.source_to_detector_sd_mm << "\n"
      << "      pitch_mm: " << c.pitch_col_mm << "\n"
      << "      pitch_sd_mm: " << c.pitch_sd_mm << "\n"
      << "      residuals_px:   # marker: [col, row] detected, [dcol, drow] predicted - detected\n";
    for (const calib::MarkerResidual& r : c.residuals) {
      std::ostringstream line;
      line.setf(std::ios::fixed);
      line.precision(3);
      line << "        - {marker: " << r.marker << ", detected: [" << r.detected_px.x() << ", "
           << r.detected_px.y() << "], residual: [" << r.residual_px.x() << ", " << r.residual_px.y()
           << "]}\n";
      y << line.str();
    }
  }
  return y.str();
}

Result<CouchMountingSpec> read_couch_calibration(const std::string& file) {
  auto document = read_yaml(file, "couch calibration");
  if (!document.ok()) return document.status();
  const YAML::Node root = *document;
  const SceneParser p(file, fs::path(file).parent_path());
  if (!root.IsMap() || !root["couch_calibration"]) {
    return invalid_argument(file + ": not a couch calibration (no 'couch_calibration' section)");
  }
  LFTRACK_RETURN_IF_ERROR(p.check_keys(root, "a couch calibration file", {"couch_calibration"}));
  const YAML::Node c = root["couch_calibration"];
  if (!c.IsMap()) return p.error(c, "couch_calibration must be a mapping");
  // Every key the writer writes and no other (a typo must not pass), and a report that could
  // have come from the solver: an rms and standard deviations that are finite and not negative,
  // at least the 3 moves it needs.
  LFTRACK_RETURN_IF_ERROR(p.check_keys(c, "couch_calibration",
                                       {"rotation_deg", "centre_mm", "rms_mm", "rotation_sd_deg", "centre_sd_mm",
                                        "centre_determined", "moves", "source"}));
  double rms = 0;
  YAML::Node rms_node;
  LFTRACK_RETURN_IF_ERROR(p.need(c, "rms_mm", "couch_calibration", &rms_node));
  LFTRACK_RETURN_IF_ERROR(p.number(rms_node, "couch_calibration.rms_mm", &rms));
  if (rms < 0) return p.error(rms_node, "couch_calibration.rms_mm must not be negative, got " + rms_node.Scalar());
  if (rms > 5)
    return p.error(rms_node, "couch_calibration.rms_mm " + rms_node.Scalar() +
                                 ": a calibration that fits its moves this badly (over 5 mm) is no calibration");
  for (const char* key : {"rotation_sd_deg", "centre_sd_mm"}) {
    if (!c[key]) continue;
    Eigen::Vector3d sd;
    LFTRACK_RETURN_IF_ERROR(p.vec3(c[key], std::string("couch_calibration.") + key, &sd));
    if (sd.minCoeff() < 0) return p.error(c[key], std::string("couch_calibration.") + key + " must not be negative");
  }
  if (c["moves"]) {
    long moves = 0;
    LFTRACK_RETURN_IF_ERROR(p.integer(c["moves"], "couch_calibration.moves", 3, 100000, &moves));
  }
  if (c["centre_determined"]) {
    bool determined = false;
    if (!YAML::convert<bool>::decode(c["centre_determined"], determined))
      return p.error(c["centre_determined"], "couch_calibration.centre_determined must be true or false");
  }
  CouchMountingSpec out;
  YAML::Node node;
  LFTRACK_RETURN_IF_ERROR(p.need(c, "rotation_deg", "couch_calibration", &node));
  LFTRACK_RETURN_IF_ERROR(p.vec3(node, "couch_calibration.rotation_deg", &out.rotation_rad));
  if (out.rotation_rad.norm() > 20)
    return p.error(node, "couch_calibration.rotation_deg: at most 20 degrees");
  out.rotation_rad *= 3.14159265358979323846 / 180;
  Eigen::Vector3d centre;
  LFTRACK_RETURN_IF_ERROR(p.need(c, "centre_mm", "couch_calibration", &node));
  LFTRACK_RETURN_IF_ERROR(p.vec3(node, "couch_calibration.centre_mm", &centre));
  if (centre.norm() > 5000)
    return p.error(node, "couch_calibration.centre_mm: the rotation centre is more than 5 m from the isocentre");
  out.centre_room_mm = centre;
  return out;
}

Result<std::vector<tracking::Vector6d>> read_couch_moves(const std::string& file) {
  auto document = read_yaml(file, "moves file");
  if (!document.ok()) return document.status();
  const YAML::Node root = *document;
  const SceneParser p(file, fs::path(file).parent_path());
  if (!root.IsMap() || !root["moves"] || !root["moves"].IsSequence()) {
    return invalid_argument(file + ": a moves file has a 'moves' list");
  }
  std::vector<tracking::Vector6d> moves;
  const YAML::Node list = root["moves"];
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string what = "moves[" + std::to_string(i) + "]";
    LFTRACK_RETURN_IF_ERROR(p.check_keys(list[i], what, {"translation_mm", "rotation_deg"}));
    Eigen::Vector3d t = Eigen::Vector3d::Zero(), r = Eigen::Vector3d::Zero();
    if (list[i]["translation_mm"])
      LFTRACK_RETURN_IF_ERROR(p.vec3(list[i]["translation_mm"], what + ".translation_mm", &t));
    if (list[i]["rotation_deg"])
      LFTRACK_RETURN_IF_ERROR(p.vec3(list[i]["rotation_deg"], what + ".rotation_deg", &r));
    tracking::Vector6d q;
    q << t, r * (3.14159265358979323846 / 180);
    moves.push_back(q);
  }
  if (moves.size() < 3)
    return invalid_argument(file + ": needs at least 3 moves, has " + std::to_string(moves.size()));
  return moves;
}

std::string couch_calibration_yaml(const calib::CouchCalibration& c, std::size_t moves,
                                   const std::string& provenance) {
  const Eigen::Isometry3d& T_room_from_couch = c.T_room_from_couch;
  const Eigen::Vector3d r =
      tracking::rotation_log(T_room_from_couch.linear()) * (180 / 3.14159265358979323846);
  std::ostringstream y;
  y << "# The couch in the room (lftrack calibrate couch): the couch's translation axes and rotation\n"
    << "# centre, room frame. Name this file in a scene as actuator.calibration.\n"
    << "couch_calibration:\n"
    << "  rotation_deg: " << vec(r, 6) << "   # rotation vector, room from couch\n"
    << "  centre_mm: " << vec(T_room_from_couch.translation(), 4) << "\n"
    << "  rms_mm: " << c.rms_mm << "\n"
    << "  rotation_sd_deg: " << vec(c.rotation_sd_deg, 6) << "\n"
    << "  centre_sd_mm: " << vec(c.centre_sd_mm, 4) << "\n"
    << "  centre_determined: " << (c.centre_determined ? "true" : "false") << "\n"
    << "  moves: " << moves << "\n"
    << "  source: " << provenance << "\n";
  return y.str();
}

}  // namespace lftrack::session

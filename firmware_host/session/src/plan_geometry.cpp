// What the treatment plan's DICOM says in the room's terms (patient_setup.hpp): the target's
// contours from the structure set, and the rotation of the plan's patient position.

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <map>
#include <sstream>

#include "lftrack/session/patient_setup.hpp"

namespace lftrack::session {

namespace fs = std::filesystem;
using Eigen::Matrix3d;
using Eigen::Vector3d;

Result<TargetContours> target_from_structure_set(const fs::path& rtstruct, const std::string& name,
                                                 const CtDicomIdentity& ct,
                                                 const tracking::VolumeGeometry& grid) {
  auto set = read_rt_structure_set(rtstruct);
  if (!set.ok()) return set.status();
  const std::string& for_uid = ct.frame_of_reference_uid;
  const std::string& series = ct.series_uid;
  const auto join = [](const std::vector<std::string>& v) {
    std::string out;
    for (const auto& s : v) out += (out.empty() ? "" : ", ") + s;
    return out.empty() ? std::string("none") : out;
  };
  if (std::find(set->frame_of_reference_uids.begin(), set->frame_of_reference_uids.end(), for_uid) ==
      set->frame_of_reference_uids.end()) {
    return failed_precondition(rtstruct.string() + ": the structure set is in Frame of Reference " +
                               join(set->frame_of_reference_uids) + ", the CT in " + for_uid +
                               ": it was contoured on another CT (or another patient)");
  }
  if (std::find(set->referenced_series_uids.begin(), set->referenced_series_uids.end(), series) ==
      set->referenced_series_uids.end()) {
    return failed_precondition(rtstruct.string() + ": the structure set references series " +
                               join(set->referenced_series_uids) + ", the CT is series " + series +
                               ": it was contoured on another series of this Frame of Reference");
  }
  const auto it = std::find_if(set->structures.begin(), set->structures.end(),
                               [&](const RtStructure& s) { return s.name == name; });
  if (it == set->structures.end())
    return not_found(rtstruct.string() + ": no structure named '" + name + "'; the structures are:\n" +
                     structure_list(*set));
  if (std::count_if(set->structures.begin(), set->structures.end(),
                    [&](const RtStructure& s) { return s.name == name; }) > 1)
    return failed_precondition(rtstruct.string() + ": more than one structure is named '" + name +
                               "'; which is the target is not for lftrack to guess:\n" +
                               structure_list(*set));
  if (!it->frame_of_reference_uid.empty() && it->frame_of_reference_uid != for_uid) {
    return failed_precondition(rtstruct.string() + ": structure '" + it->name +
                               "' is in Frame of Reference " + it->frame_of_reference_uid + ", the CT in " +
                               for_uid);
  }
  TargetContours target;
  target.patient_id = set->patient_id;
  target.name = it->name;
  target.roi_number = it->roi_number;
  std::map<std::string, int> other_types;
  for (const RtContour& c : it->contours) {
    if (c.geometric_type == "CLOSED_PLANAR")
      target.polygons.push_back({c.points_ct_mm});
    else
      ++other_types[c.geometric_type.empty() ? "(no type)" : c.geometric_type];
  }
  if (target.polygons.empty()) {
    std::string types;
    for (const auto& [type, n] : other_types)
      types += (types.empty() ? "" : ", ") + std::to_string(n) + " " + type;
    return failed_precondition(rtstruct.string() + ": target '" + it->name +
                               "' has no closed planar contour" +
                               (types.empty() ? "" : " (it has " + types + ")") +
                               ": a target is a volume, contoured slice by slice");
  }
  if (Status s = check_target_polygons(target.polygons, target.name); !s.ok())
    return Status(s.code(), rtstruct.string() + ": " + s.message());
  auto mask = rasterise_target(target.polygons, grid, target.name);
  if (!mask.ok()) return Status(mask.status().code(), rtstruct.string() + ": " + mask.status().message());
  if (mask->contours_beyond_scan > 0)
    return failed_precondition(
        rtstruct.string() + ": target '" + target.name + "' reaches beyond the scanned slices (" +
        std::to_string(mask->contours_beyond_scan) + " of its " + std::to_string(target.polygons.size()) +
        " contours lie outside the CT): it was contoured on another scan, or the CT is cut short");
  if (mask->voxels_inside == 0)
    return failed_precondition(rtstruct.string() + ": target '" + target.name +
                               "' covers no voxel of the CT: its contours enclose no voxel centre");
  if (mask->most_off_slice_mm > 0.25 * grid.spacing_mm.z()) {
    std::ostringstream m;
    m << std::fixed << std::setprecision(2) << "target '" << target.name << "': a contour lies "
      << mask->most_off_slice_mm << " mm from the CT slice it is filled on (slices " << grid.spacing_mm.z()
      << " mm apart): it was contoured on another grid; check the picture";
    target.warnings.push_back(m.str());
  }
  target.mask = std::move(*mask);
  target.box = target_box(target.polygons);
  return target;
}

Result<Matrix3d> room_from_patient_rotation(const std::string& position) {
  const Matrix3d turn_y = Eigen::Vector3d(-1, 1, -1).asDiagonal();  // feet first: 180 degrees about vertical
  Matrix3d left_down;                                               // x (patient's left) to +y (the floor)
  left_down << 0, -1, 0, 1, 0, 0, 0, 0, 1;
  if (position == "HFS") return Matrix3d(Matrix3d::Identity());
  if (position == "FFS") return turn_y;
  if (position == "HFP") return Matrix3d(Eigen::Vector3d(-1, -1, 1).asDiagonal());
  if (position == "FFP") return Matrix3d(Eigen::Vector3d(1, -1, -1).asDiagonal());
  if (position == "HFDL") return left_down;
  if (position == "HFDR") return Matrix3d(left_down.transpose());
  if (position == "FFDL") return Matrix3d(turn_y * left_down);
  if (position == "FFDR") return Matrix3d(turn_y * left_down.transpose());
  return invalid_argument("patient position '" + position +
                          "' is none of HFS, FFS, HFP, FFP, HFDL, HFDR, FFDL, FFDR (DICOM (0018,5100))");
}

}  // namespace lftrack::session

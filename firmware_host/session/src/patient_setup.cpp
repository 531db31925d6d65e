// A new patient's scene from the treatment plan (issue 53): see patient_setup.hpp.

#include "lftrack/session/patient_setup.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <iomanip>
#include <map>
#include <sstream>
#include "scene_yaml.hpp"

namespace lftrack::session {

namespace fs = std::filesystem;
using Eigen::Matrix3d;
using Eigen::Vector3d;

namespace {

std::string mm3(const Vector3d& v, int digits = 2) {
  std::ostringstream s;
  if (v.cwiseAbs().maxCoeff() < 1e6)
    s << std::fixed << std::setprecision(digits);
  else
    s << std::setprecision(6);  // 1e300 as 1e+300, not 300 digits
  s << '(' << v.x() << ", " << v.y() << ", " << v.z() << ')';
  return s.str();
}

// A YAML list [x, y, z], to 0.01 mm: the scene says what it means, not 17 digits.
std::string yaml3(const Vector3d& v) {
  std::ostringstream s;
  const auto num = [&](double x) {
    std::ostringstream n;
    n << std::fixed << std::setprecision(2) << (std::abs(x) < 0.005 ? 0.0 : x);
    std::string t = n.str();
    while (t.back() == '0') t.pop_back();
    if (t.back() == '.') t.pop_back();
    return t;
  };
  s << '[' << num(v.x()) << ", " << num(v.y()) << ", " << num(v.z()) << ']';
  return s.str();
}

// Text for a comment: one line, whatever a user or a DICOM file wrote.
std::string comment(const std::string& text) {
  std::string out;
  for (unsigned char c : text) out += (c < 0x20 || c == 0x7f) ? '?' : char(c);
  return out;
}

// The shortest text that reads back as `x` (12.345, not 12.34500000000000064); -0 as 0.
std::string shortest(double x) {
  char text[32];
  const auto [end, ec] = std::to_chars(text, text + sizeof text, x == 0 ? 0.0 : x);
  return ec == std::errc() ? std::string(text, end) : std::to_string(x);
}

std::string relative_to(const fs::path& file, const fs::path& folder) {
  // From the real folders: a link in either path must not make the way between them wrong.
  std::error_code ec;
  const fs::path target = fs::weakly_canonical(fs::absolute(file, ec), ec);
  const fs::path base = fs::weakly_canonical(fs::absolute(folder.empty() ? fs::path(".") : folder, ec), ec);
  // A folder reached through a link: a reader joins the relative path to the folder as written,
  // not as it really is, so the path is written whole.
  const fs::path given = fs::absolute(folder.empty() ? fs::path(".") : folder, ec).lexically_normal();
  if (given != base) return target.string();
  const fs::path rel = target.lexically_relative(base);
  // Relative where the two stay together (a scene beside its CT and room); absolute where the way
  // between them climbs to the root, which no one reads or moves as one.
  int up = 0;
  for (const fs::path& part : rel) up += part == "..";
  return rel.empty() || up > 2 ? target.string() : rel.string();
}

// The isocentre, where it came from, and what the plan adds (patient position, tolerances).
struct Isocentre {
  Vector3d ct_mm = Vector3d::Zero();
  std::string from;
  std::string patient_position;
  std::string patient_id;  // the plan's
  std::optional<RtPlanSetup> plan;
};

Status need_identity(const NewSceneCt& ct, const fs::path& file, const char* what) {
  if (ct.identity) return {};
  return failed_precondition(file.string() + ": a " + what +
                             " is tied to its CT by the Frame of Reference UID (0020,0052), and a NIfTI CT has none; "
                             "set up from the DICOM series the plan was made on, or give --isocentre X,Y,Z read off the "
                             "plan");
}

Result<Isocentre> choose_isocentre(const NewSceneRequest& r, const NewSceneCt& ct) {
  Isocentre iso;
  if (!r.rtplan.empty()) {
    LFTRACK_RETURN_IF_ERROR(need_identity(ct, r.rtplan, "plan"));
    auto plan = read_rt_plan(r.rtplan, r.beam);
    if (!plan.ok()) return plan.status();
    if (plan->frame_of_reference_uid != ct.identity->frame_of_reference_uid) {
      return failed_precondition(r.rtplan.string() + ": the plan is in Frame of Reference " +
                                 plan->frame_of_reference_uid + ", the CT in " + ct.identity->frame_of_reference_uid +
                                 ": it was planned on another CT (or another patient)");
    }
    iso.ct_mm = plan->beam.isocentre_ct_mm;
    iso.from = "plan '" + plan->label + "' (" + r.rtplan.filename().string() + "), beam " +
               std::to_string(plan->beam.number) + " '" + plan->beam.name +
               "': Isocenter Position (300A,012C) of its first control point";
    iso.patient_position = plan->patient_position;
    iso.patient_id = plan->patient_id;
    iso.plan = std::move(*plan);
    return iso;
  }
  if (r.isocentre_ct_mm) {
    if (!r.isocentre_ct_mm->allFinite()) return invalid_argument("--isocentre must be three finite numbers (mm)");
    iso.ct_mm = *r.isocentre_ct_mm;
    iso.from = "--isocentre (CT frame, mm)";
    return iso;
  }
  return iso;  // from the target, or refused by the caller
}

Status check_inside_ct(const Vector3d& point, const tracking::VolumeGeometry& grid, const std::string& what) {
  const Vector3d index = grid.index_from_ct() * point;
  const Vector3d lo = grid.ct_from_index() * Vector3d(-0.5, -0.5, -0.5);
  const Vector3d hi = grid.ct_from_index() * (grid.size.cast<double>() - Vector3d::Constant(0.5));
  for (int a = 0; a < 3; ++a) {
    if (!(index[a] >= -0.5 && index[a] <= grid.size[a] - 0.5)) {
      return out_of_range(what + " " + mm3(point) + " mm lies outside the CT, which spans " + mm3(lo.cwiseMin(hi), 1) +
                          " to " + mm3(lo.cwiseMax(hi), 1) + " mm (CT frame): it belongs to another CT, or its "
                          "coordinates are not the CT's patient frame");
    }
  }
  return {};
}

Result<TargetContours> read_target(const NewSceneRequest& r, const NewSceneCt& ct) {
  LFTRACK_RETURN_IF_ERROR(need_identity(ct, r.rtstruct, "structure set"));
  if (r.target.empty()) {
    auto set = read_rt_structure_set(r.rtstruct);
    if (!set.ok()) return set.status();
    return invalid_argument("--rtstruct needs --target NAME; the structures are:\n" + structure_list(*set));
  }
  return target_from_structure_set(r.rtstruct, r.target, *ct.identity, ct.volume->geometry);
}

// The envelope the plan's table-top tolerances allow: the smaller of ours and theirs.
struct Envelope {
  double translation_mm = 10;
  double rotation_deg = 5;
  std::string translation_from = "lftrack's default";
  std::string rotation_from = "lftrack's default";
};

Envelope envelope_from(const std::optional<RtPlanSetup>& plan, std::vector<std::string>* warnings) {
  Envelope e;
  if (!plan || plan->tolerances.table_number == 0) return e;
  const TableTopTolerances& t = plan->tolerances;
  std::string numbers;
  for (int n : t.table_numbers) numbers += (numbers.empty() ? "" : ", ") + std::to_string(n);
  const std::string table =
      (t.table_numbers.size() > 1 ? "tolerance tables " + numbers + " of the plan (the tightest)"
                                  : "tolerance table " + std::to_string(t.table_number) + " of the plan");
  const auto bound = [&](const std::optional<double>& value, const char* what, double* out, std::string* from) {
    if (!value) return;
    if (!(*value > 0) || !std::isfinite(*value)) {
      std::ostringstream m;
      m << table << ": " << what << " tolerance " << *value << " is not a positive bound; lftrack's default kept";
      warnings->push_back(m.str());
      return;
    }
    if (*value < *out) {
      *out = *value;
      *from = table + ", " + what;
    }
  };
  bound(t.lateral_mm, "table-top lateral position (300A,0053)", &e.translation_mm, &e.translation_from);
  bound(t.longitudinal_mm, "table-top longitudinal position (300A,0052)", &e.translation_mm, &e.translation_from);
  bound(t.vertical_mm, "table-top vertical position (300A,0051)", &e.translation_mm, &e.translation_from);
  bound(t.pitch_deg, "table-top pitch angle (300A,004F)", &e.rotation_deg, &e.rotation_from);
  bound(t.roll_deg, "table-top roll angle (300A,0050)", &e.rotation_deg, &e.rotation_from);
  bound(t.patient_support_deg, "patient support angle (300A,004C)", &e.rotation_deg, &e.rotation_from);
  return e;
}

}  // namespace

std::string structure_list(const RtStructureSet& set) {
  std::ostringstream s;
  for (const RtStructure& st : set.structures) {
    std::size_t points = 0, closed = 0;
    for (const RtContour& c : st.contours) {
      points += c.points_ct_mm.size();
      closed += c.geometric_type == "CLOSED_PLANAR";
    }
    std::string name = "'";  // (built in steps: GCC 12 warns of "'" + string, -Wrestrict)
    name += comment(st.name);
    name += '\'';
    s << "  " << std::setw(4) << st.roi_number << "  " << std::left << std::setw(24) << name
      << std::right << ' ' << st.contours.size() << " contours (" << closed << " closed planar), " << points
      << " points\n";
  }
  if (set.structures.empty()) s << "  (none)\n";
  return s.str();
}

std::string printable(const std::string& text) { return comment(text); }

Result<NewScene> compose_new_scene(const NewSceneRequest& r, const NewSceneCt& ct) {
  if (!ct.volume) return invalid_argument("compose_new_scene: no CT");
  if (!r.rtplan.empty() && r.isocentre_ct_mm)
    return invalid_argument("--rtplan and --isocentre both give the isocentre; give one");
  if (!r.target.empty() && r.rtstruct.empty()) return invalid_argument("--target names a structure of --rtstruct FILE");
  if (!(r.roi_margin_mm >= 0 && r.roi_margin_mm <= 100))
    return invalid_argument("the ROI margin must be in [0, 100] mm");
  if (r.roi_mask_margin_mm && r.rtstruct.empty()) return invalid_argument("--roi-mask-mm needs --rtstruct and --target");
  if (r.roi_mask_margin_mm && !(*r.roi_mask_margin_mm >= 0 && *r.roi_mask_margin_mm <= 50))
    return invalid_argument("the ROI mask's margin must be in [0, 50] mm");
  const tracking::VolumeGeometry& grid = ct.volume->geometry;
  NewScene out;
  auto iso = choose_isocentre(r, ct);
  if (!iso.ok()) return iso.status();
  std::optional<TargetContours> target;
  if (!r.rtstruct.empty()) {
    auto t = read_target(r, ct);
    if (!t.ok()) return t.status();
    target = std::move(*t);
  }
  if (iso->from.empty()) {
    if (!target)
      return invalid_argument("no isocentre: give --rtplan FILE (its isocentre), --isocentre X,Y,Z (mm, CT frame), or "
                              "--rtstruct FILE --target NAME (the target's centre)");
    iso->ct_mm = target->box.centre_ct_mm();
    iso->from = "the centre of target '" + target->name + "''s box (no plan and no --isocentre given)";
  }
  LFTRACK_RETURN_IF_ERROR(check_inside_ct(iso->ct_mm, grid, "the isocentre (" + comment(iso->from) + ")"));
  out.isocentre_ct_mm = iso->ct_mm;
  out.isocentre_from = iso->from;

  if (target) {
    out.roi_centre_ct_mm = target->box.centre_ct_mm();
    out.roi_size_mm = target->box.size_mm() + Vector3d::Constant(2 * r.roi_margin_mm);
    out.roi_size_mm = out.roi_size_mm.cwiseMax(Vector3d::Constant(10));  // a flat target still has a box
    const Vector3d off = ((iso->ct_mm - out.roi_centre_ct_mm).cwiseAbs() - 0.5 * out.roi_size_mm).cwiseMax(0);
    if (off.norm() > 0) {
      std::ostringstream m;
      m << std::fixed << std::setprecision(1) << "the isocentre " << mm3(iso->ct_mm) << " mm (" << iso->from
        << ") lies " << off.norm() << " mm outside target '" << target->name << "''s box plus its "
        << r.roi_margin_mm << " mm margin: the plan and the structure set disagree about where the target is "
        << "(another target, or another plan?); a wider --roi-margin-mm takes both in";
      return failed_precondition(m.str());
    }
    for (const std::string& w : target->warnings) out.warnings.push_back(w);
    if (r.roi_mask_margin_mm &&
        std::any_of(target->name.begin(), target->name.end(), [](unsigned char ch) { return ch < 0x20 || ch == 0x7f; }))
      return invalid_argument("target '" + comment(target->name) +
                              "' holds a line break or a control character: roi.mask names its target, and such a "
                              "name is not one a scene should carry (rename the structure)");
    out.target_name = target->name;
    out.target_polygons = target->polygons;
    out.target = std::move(target->mask);
  } else {
    out.roi_centre_ct_mm = iso->ct_mm;
    out.roi_size_mm = r.roi_size_without_target_mm;
  }

  out.patient_position = iso->patient_position.empty() ? "HFS" : iso->patient_position;
  auto rotation = room_from_patient_rotation(out.patient_position);
  if (!rotation.ok()) return Status(rotation.status().code(), r.rtplan.string() + ": " + rotation.status().message());
  out.nominal_T_room_from_ct.linear() = *rotation;
  out.nominal_T_room_from_ct.translation() = -(*rotation * iso->ct_mm);
  // One scan (one Frame of Reference) under two patient IDs: the CT, the plan or the structure set
  // was renamed (anonymised) without the others. Said, with both IDs; the UIDs decide.
  if (ct.identity && !ct.identity->patient_id.empty()) {
    const auto differs = [&](const std::string& id, const std::string& what) {
      if (!id.empty() && id != ct.identity->patient_id)
        out.warnings.push_back(what + " is for patient ID '" + comment(id) + "', the CT for '" +
                               comment(ct.identity->patient_id) +
                               "' (the same scan by its Frame of Reference UID: renamed or anonymised apart?)");
    };
    differs(iso->patient_id, "the plan");
    if (target) differs(target->patient_id, "the structure set");
  }
  if (iso->plan && iso->patient_position.empty())
    out.warnings.push_back("the plan gives no patient position (0018,5100): head-first supine (HFS) assumed");
  const Envelope envelope = envelope_from(iso->plan, &out.warnings);
  if (r.roi_mask_margin_mm && *r.roi_mask_margin_mm <= envelope.translation_mm) {
    std::ostringstream m;
    m << "roi.mask's margin (" << *r.roi_mask_margin_mm << " mm) does not exceed the envelope (" << envelope.translation_mm
      << " mm): a patient that far off leaves the target's edge outside what the registration looks at";
    out.warnings.push_back(m.str());
  }
  for (const std::string& w : ct_fitness_warnings(*ct.volume, iso->ct_mm, out.roi_centre_ct_mm, out.roi_size_mm))
    out.warnings.push_back(w);

  // The scene, commented with where each value came from.
  const fs::path folder = r.output.parent_path();
  const std::string stem = r.output.stem().string();
  std::ostringstream y;
  y << "# A patient's scene, written by `lftrack scene new`";
  if (!r.command_line.empty()) y << ":\n#   " << comment(r.command_line);
  y << "\n# Look at " << comment(stem) << "-setup.png beside it before the first beam: each view's DRR with the isocentre's\n"
    << "# cross (green), the ROI (yellow), the target (red) and roi.mask's edge (cyan), and three slices\n"
    << "# through the isocentre. Then:\n"
    << "#   lftrack precompute --scene " << comment(r.output.filename().string()) << "     (the light fields)\n"
    << "#   lftrack commission --scene " << comment(r.output.filename().string())
    << "     (the verdict's floors; the loop refuses the scene until then)\n";
  for (const std::string& w : out.warnings) y << "# Warning: " << comment(w) << "\n";
  y << std::defaultfloat << std::setprecision(6) << "version: 1\n";
  y << "name: " << yaml_quoted(r.name.empty() ? stem : r.name) << "\n";
  y << "room: " << yaml_quoted(relative_to(r.room, folder)) << "   # the views, detectors, couch, imaging and loop\n";
  y << "ct:\n  path: " << yaml_quoted(relative_to(r.ct, folder)) << "   # " << grid.size.x() << " x " << grid.size.y() << " x "
    << grid.size.z() << " voxels of " << std::fixed << std::setprecision(2) << grid.spacing_mm.x() << " x "
    << grid.spacing_mm.y() << " x " << grid.spacing_mm.z() << " mm";
  if (ct.identity)
    y << "\n  # Frame of Reference " << comment(ct.identity->frame_of_reference_uid) << ", series "
      << comment(ct.identity->series_uid);
  y << "\nroi:                  # CT frame (patient LPS), mm\n";
  if (target) {
    y << "  centre_mm: " << yaml3(out.roi_centre_ct_mm) << "   # target '" << comment(target->name) << "' (ROI number "
      << target->roi_number << " of " << comment(r.rtstruct.filename().string()) << "): the centre of its box\n";
    y << "  size_mm: " << yaml3(out.roi_size_mm) << "   # its box " << yaml3(target->box.size_mm()) << " plus "
      << r.roi_margin_mm << " mm on each side; " << std::setprecision(1) << target->mask.volume_cc()
      << " cc on the CT's grid\n";
    if (r.roi_mask_margin_mm) {
      y << "  mask:                # the measures look only at the target and " << *r.roi_mask_margin_mm
        << " mm around it, in each view\n"
        << "    rtstruct: " << yaml_quoted(relative_to(r.rtstruct, folder)) << "\n"
        << "    target: " << yaml_quoted(target->name) << "\n"
        << "    margin_mm: " << shortest(*r.roi_mask_margin_mm) << "\n";
    }
  } else {
    y << "  centre_mm: " << yaml3(out.roi_centre_ct_mm) << "   # on the isocentre (no structure set)\n";
    y << "  size_mm: " << yaml3(out.roi_size_mm) << "   # lftrack's default box about a vertebra\n";
  }
  y << "registration_origin_mm: " << yaml3(iso->ct_mm) << "   # the isocentre: " << comment(iso->from) << "\n";
  if (out.patient_position != "HFS") {
    const auto euler = tracking::euler_from_rotation(*rotation);
    y << "nominal_pose:          # patient position " << out.patient_position
      << " (0018,5100): the room from the CT frame, the isocentre on the room's\n"
      << "  rotation_deg: "
      << yaml3(Vector3d(tracking::rad_to_deg(euler.roll), tracking::rad_to_deg(euler.pitch), tracking::rad_to_deg(euler.yaw)))
      << "   # [roll, pitch, yaw]\n"
      << "  translation_mm: " << yaml3(out.nominal_T_room_from_ct.translation()) << "\n";
  } else {
    y << "# Patient head-first supine (HFS): the CT frame is the room's, shifted to put the isocentre on the room's.\n";
  }
  y << std::defaultfloat << std::setprecision(6) << "envelope:\n"
    << "  translation_mm: " << envelope.translation_mm << "   # " << comment(envelope.translation_from)
    << "\n  rotation_deg: " << envelope.rotation_deg << "   # " << comment(envelope.rotation_from) << "\n";
  y << "safety:\n  commissioning: " << yaml_quoted(stem + ".commissioning.yaml") << "   # written by: lftrack commission --scene "
    << comment(r.output.filename().string()) << "\n";
  y << "motion:                # the simulated patient (sim only): set up off the plan, then drifting\n"
    << "  setup_error: {translation_mm: [3, -2, 2], rotation_deg: [1, -0.5, 1]}\n"
    << "  drift: {translation_mm_per_s: [0.02, 0.01, -0.02]}\n";
  out.yaml = y.str();
  return out;
}

}  // namespace lftrack::session

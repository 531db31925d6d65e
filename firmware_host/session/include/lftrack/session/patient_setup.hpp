#pragma once
// A new patient's scene from the treatment plan (issue 53, `lftrack scene new`): the isocentre
// from the RT Plan (or given), the target from the RT Structure Set, the room from a room file,
// all checked against the CT they must belong to, and written as a commented scene that says where
// each value came from. Nothing here draws or writes files; the command does (cli/cmd_scene_new.cpp).

#include <Eigen/Core>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/session/dicom_registration.hpp"
#include "lftrack/session/dicom_rt.hpp"
#include "lftrack/session/target_contours.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::session {

struct NewSceneRequest {
  std::filesystem::path ct;      // a DICOM CT folder or a NIfTI file
  std::filesystem::path room;    // a room file (scenes/room/...)
  std::filesystem::path output;  // the scene to write (paths in it are relative to its folder)
  std::filesystem::path rtplan;  // "": no plan
  std::string beam;              // the plan's beam (number or name); "": every beam, one isocentre
  std::filesystem::path rtstruct;
  std::string target;                              // a structure's name in rtstruct
  std::optional<Eigen::Vector3d> isocentre_ct_mm;  // given instead of a plan (a NIfTI CT)
  double roi_margin_mm = 10;                       // around the target's box, each side
  std::optional<double> roi_mask_margin_mm;  // set: roi.mask (the target's neighbourhood only), this margin
  Eigen::Vector3d roi_size_without_target_mm{64, 64, 40};
  std::string name;          // the scene's name ("": from the output's file name)
  std::string command_line;  // for the scene's header comment
};

// The CT the scene is for: its grid and HU (read), and its DICOM identity (absent for NIfTI).
struct NewSceneCt {
  const tracking::CtVolume* volume = nullptr;
  std::optional<CtDicomIdentity> identity;
};

struct NewScene {
  std::string yaml;  // the scene, commented
  Eigen::Vector3d isocentre_ct_mm = Eigen::Vector3d::Zero();
  std::string isocentre_from;  // "plan P, beam 1 'AP' (300A,012C)", "--isocentre", ...
  Eigen::Vector3d roi_centre_ct_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d roi_size_mm = Eigen::Vector3d::Zero();
  std::string patient_position = "HFS";
  tracking::Pose nominal_T_room_from_ct = tracking::Pose::Identity();
  std::string target_name;                     // "" without a structure set
  std::vector<TargetPolygon> target_polygons;  // CT frame
  std::optional<TargetMask> target;            // on the CT's grid
  std::vector<std::string> warnings;           // fitness for tracking, each with its figure
};

// A target of a structure set, checked against the CT it must belong to: the set's Frame of
// Reference and referenced series are the CT's, one structure has the name, its closed planar
// contours are sound (target_contours.hpp) and cover voxels of the CT. Each refusal says why.
struct TargetContours {
  std::string name;
  int roi_number = 0;
  std::vector<TargetPolygon> polygons;  // CT frame
  TargetMask mask;                      // on the CT's grid
  TargetBox box;
  std::vector<std::string> warnings;  // e.g. contours off the CT's slices, with the figure
  std::string patient_id;             // the structure set's Patient ID (0010,0020)
};
Result<TargetContours> target_from_structure_set(const std::filesystem::path& rtstruct,
                                                 const std::string& name, const CtDicomIdentity& ct,
                                                 const tracking::VolumeGeometry& grid);

// The room's axes from the patient's (the CT frame, LPS), for a DICOM Patient Position
// (0018,5100). The room frame is the CT frame of a head-first supine patient (DESIGN.md, "Frames"):
// HFS is the identity; FFS turns the patient 180 degrees about the vertical (room y), HFP about the
// long axis (room z), FFP both; the decubitus positions (HFDL, HFDR, FFDL, FFDR) lie the patient
// on their left or right side. Anything else is refused.
Result<Eigen::Matrix3d> room_from_patient_rotation(const std::string& patient_position);

// Reads the plan and the structure set the request names, checks them against the CT (Frame of
// Reference, series, isocentre inside the volume, the target's contours) and composes the scene.
Result<NewScene> compose_new_scene(const NewSceneRequest& request, const NewSceneCt& ct);

// Whether the CT is fit for tracking at this isocentre and ROI: slice thickness, pixel size, the
// ROI's distance from the volume's edges, metal near the target. One line per concern, with its
// figure; empty when none.
std::vector<std::string> ct_fitness_warnings(const tracking::CtVolume& ct,
                                             const Eigen::Vector3d& isocentre_ct_mm,
                                             const Eigen::Vector3d& roi_centre_ct_mm,
                                             const Eigen::Vector3d& roi_size_mm);

// Said beside a simulation's accuracy (sim, register --sim) when the CT is coarser than
// radiosurgery plans on (slices over 2 mm apart or pixels over 1.2 mm): the simulator draws its
// frames from the same CT, so the figures are optimistic for this patient. Empty otherwise.
std::string simulated_accuracy_caveat(const tracking::CtVolume& ct);

// `text` on one line for a terminal or a comment: every control character (line breaks, escape
// sequences) shown as '?'. Names a DICOM file or a user wrote pass through it before they are printed.
std::string printable(const std::string& text);

// The structures of a structure set, one line each: number, name, contours, points.
std::string structure_list(const RtStructureSet& set);

}  // namespace lftrack::session

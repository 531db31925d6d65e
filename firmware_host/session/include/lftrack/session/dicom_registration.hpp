#pragma once
// A registration as a DICOM Spatial Registration object (SOP class 1.2.840.10008.5.1.4.1.1.66.1,
// PS3.3 A.39), written with DCMTK, so a treatment-planning system or 3D Slicer (SlicerRT) can
// load it beside the planning CT (`lftrack register --dicom-sro`, `lftrack journal export
// --dicom-sro`).
//
// What it says: the object's own Frame of Reference is the treatment room's (the room frame of
// the scene's calibration); its Registration Sequence holds
//   1. the room's Frame of Reference with the identity matrix, and
//   2. the planning CT's Frame of Reference and its slices with T_room_from_ct, a RIGID 4x4 matrix that maps
//      the CT's patient coordinates (mm, DICOM's LPS) to room coordinates (mm), which is what
//      DICOM's "Frame of Reference Transformation Matrix" means (source to registered RCS).
// The Common Instance Reference module lists the CT series and every slice (SOP class and
// instance UIDs); the patient and study are the CT's, so the object files with the CT's study.
//
// The room's Frame of Reference UID is derived from the room's geometry (the scene's detectors
// and their calibration): "2.25." and a 128-bit hash, so every registration in one calibrated
// room names the same room frame, and another calibration names another.

#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::session {

// The planning CT's identity as DICOM names it, read from the series' headers (pixel data is
// not read).
struct CtDicomIdentity {
  std::string patient_name, patient_id, patient_birth_date, patient_sex;
  std::string study_uid, study_id, study_date, study_time, accession_number, referring_physician;
  std::string series_uid, frame_of_reference_uid;
  std::vector<std::pair<std::string, std::string>> instances;  // (SOP class UID, SOP instance UID) per slice
};

// Reads the identity of the DICOM series in `folder` (one series, as read_dicom_series takes
// it). Refuses a folder without DICOM files, files of more than one series or Frame of
// Reference, and a series without a Frame of Reference UID.
Result<CtDicomIdentity> read_ct_dicom_identity(const std::filesystem::path& folder);

// The identity of the scene's planning CT; refused with the reason when the scene's CT is not a
// DICOM series (NIfTI or the built-in phantom: no Frame of Reference to reference).
Result<CtDicomIdentity> scene_ct_dicom_identity(const Scene& scene);

// "2.25.<decimal>" from the room's geometry (every detector's view), a valid DICOM UID.
std::string room_frame_of_reference_uid(const Scene& scene);

struct SpatialRegistration {
  tracking::Pose T_room_from_ct = tracking::Pose::Identity();
  std::string room_frame_of_reference_uid;
  std::string description;  // Content Description, e.g. "lftrack register: quadratic, MI 0.41"
};

// Whether a registration may be written at `file`: nothing there (not even a dangling link), in a
// folder that exists. For checking before a registration runs; the writer checks again.
Status check_registration_path(const std::filesystem::path& file);

// Writes the object to `file`; refuses a file that exists (nothing is overwritten) and a pose
// that is not finite or not rigid. The object is written into a new file of its own (O_EXCL)
// beside the target and linked into place: link() refuses a target that appeared meanwhile, and
// no link or earlier file of any name is ever written through.
Status write_spatial_registration(const std::filesystem::path& file, const CtDicomIdentity& ct,
                                  const SpatialRegistration& registration);

}  // namespace lftrack::session

#pragma once
// DICOM RT objects a patient's set-up comes from: the plan's isocentre, the structure set's
// contours (the CT series' identity, which they must match, is read_ct_dicom_identity's in
// dicom_registration.hpp). Read with DCMTK (dcmrt's DRTPlanIOD and DRTStructureSetIOD);
// coordinates are DICOM's patient frame (LPS), in mm, as the objects store them. Every error names the file
// (or folder) it is about. Not real-time safe: these read files and allocate; they are called while a run is
// prepared.

#include <Eigen/Core>

#include <cstddef>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"

namespace lftrack::session {

// Each the same in every slice (refused otherwise, naming both files and both values).
// Of the tolerance table the chosen beam references (300A,00A0), where it references one; a
// tolerance the table leaves out stays empty.
struct TableTopTolerances {
  std::optional<double> lateral_mm, longitudinal_mm, vertical_mm;  // (300A,0053) (300A,0052) (300A,0051)
  std::optional<double> pitch_deg, roll_deg, patient_support_deg;  // (300A,004F) (300A,0050) (300A,004C)
  int table_number = 0;  // 0: the beam references none; else the first table taken
  std::vector<int>
      table_numbers;  // every table taken (the chosen beams'), each tolerance the tightest of them
};

struct RtPlanBeam {
  int number = 0;                                             // Beam Number (300A,00C0)
  std::string name;                                           // Beam Name (300A,00C2), "" if absent
  Eigen::Vector3d isocentre_ct_mm = Eigen::Vector3d::Zero();  // of the first control point, LPS mm
};

struct RtPlanSetup {
  std::string file;
  std::string label;                   // RTPlanLabel (300A,0002)
  std::string patient_id;              // Patient ID (0010,0020), "" if absent
  std::string frame_of_reference_uid;  // (0020,0052)
  RtPlanBeam beam;                     // the chosen beam
  std::vector<RtPlanBeam> beams;       // every beam in the plan, in the plan's order
  // (0018,5100) of the patient setup the chosen beam references (300C,006A), or of the plan's
  // only patient setup when the beam references none: HFS, FFS, HFP, FFP, HFDL, HFDR, FFDL,
  // FFDR; "" when there is no such setup or it gives no position.
  std::string patient_position;
  TableTopTolerances tolerances;
};

// Reads an RT Plan (SOP Class 1.2.840.10008.5.1.4.1.1.481.5; a file without a SOP Class UID is
// taken as one when its Modality is RTPLAN).
// Each beam's isocentre is Isocenter Position (300A,012C) of its FIRST control point; refused if
// any beam's first control point has none, or it is not 3 finite numbers.
// `beam` empty: every beam; refused if the plan has no beam, or if two beams' isocentres differ
// by more than 0.01 mm ("the plan has 2 isocentres: beam 1 'A' at (x, y, z), beam 2 'B' at
// (...): name one with --beam"), or if the beams reference patient setups of different
// positions. The chosen beam is then the first.
// `beam` non-empty: a beam number ("2") or a beam name; refused when no beam has it, listing the
// beams.
// Also refused: no such file, a file that is not DICOM, not an RT Plan, an RT Ion Plan (not
// supported), no FrameOfReferenceUID, an unknown patient position, a beam referencing a patient
// setup or tolerance table the plan does not have, a tolerance that is not a finite number.
// Attributes dcmrt reports missing but this does not use (most type 1 and 2 ones) are not
// checked: a plan is refused only for what it needs.
Result<RtPlanSetup> read_rt_plan(const std::filesystem::path& file, const std::string& beam);

struct RtContour {
  std::string geometric_type;                 // (3006,0042) CLOSED_PLANAR, POINT, OPEN_PLANAR ...
  std::vector<Eigen::Vector3d> points_ct_mm;  // (3006,0050), patient frame (LPS), mm
};

struct RtStructure {
  int roi_number = 0;  // (3006,0022)
  std::string name;    // (3006,0026)
  // ReferencedFrameOfReferenceUID (3006,0024) of its StructureSetROI item.
  std::string frame_of_reference_uid;
  // Of every ROIContourSequence item whose ReferencedROINumber matches, in order (may be empty).
  std::vector<RtContour> contours;
};

struct RtStructureSet {
  std::string file;
  std::string label;                                 // StructureSetLabel (3006,0002)
  std::string patient_id;                            // Patient ID (0010,0020), "" if absent
  std::vector<std::string> frame_of_reference_uids;  // of ReferencedFrameOfReferenceSequence (3006,0010)
  // SeriesInstanceUID of every RTReferencedSeriesSequence item under them.
  std::vector<std::string> referenced_series_uids;
  std::vector<RtStructure> structures;  // in StructureSetROISequence's order
};

// Limits on what one structure set may hold.
inline constexpr std::size_t kMaxPointsPerContour = 100'000;
inline constexpr std::size_t kMaxPointsPerStructureSet = 10'000'000;

// Reads an RT Structure Set (SOP Class 1.2.840.10008.5.1.4.1.1.481.3; a file without a SOP Class
// UID is taken as one when its Modality is RTSTRUCT). Refused: no such file, not DICOM, not an
// RT Structure Set, two structures with one ROI number, a contour whose ContourData is not a
// multiple of 3 numbers or has a value that is not a finite decimal number, or whose
// NumberOfContourPoints (3006,0046) disagrees with its data, more than kMaxPointsPerContour
// points in one contour or kMaxPointsPerStructureSet in all. Every error names the file (and the
// structure and contour, counted from 1, where it is about one). ROIContourSequence items that
// reference no structure are ignored.
Result<RtStructureSet> read_rt_structure_set(const std::filesystem::path& file);

}  // namespace lftrack::session

#pragma once
// Writes small DICOM RT Plans and RT Structure Sets with DCMTK, for the RT readers' tests: every
// attribute the readers use is under the test's control, and the modules the IODs make mandatory
// are filled in so that dicom3tools' dciodvfy accepts the files. Coordinates are LPS mm.
// Throws std::runtime_error when DCMTK refuses to build or save a file (a broken test, not a
// finding).

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace lftrack::test {

struct RtPlanSpec {
  std::string frame_of_reference_uid = "1.2.826.0.1.3680043.2.1125.5";  // empty: none written
  std::string patient_position = "HFS";  // of the one patient setup; empty: the setup gives none
  std::string label = "lftrack test";
  struct Beam {
    int number = 1;
    std::string name;
    Eigen::Vector3d isocentre_mm = Eigen::Vector3d::Zero();
    bool isocentre_in_first_control_point = true;  // false: only the second control point has it
  };
  std::vector<Beam> beams;
  // One tolerance table, number 1, that every beam references: lateral, longitudinal, vertical
  // (mm), pitch, roll, patient support (degrees). Empty: no table.
  std::optional<std::array<double, 6>> tolerances;
};
void write_rt_plan(const std::filesystem::path& file, const RtPlanSpec& spec);

struct RtStructSpec {
  std::string frame_of_reference_uid = "1.2.826.0.1.3680043.2.1125.5";
  std::string series_uid = "1.2.826.0.1.3680043.2.1125.1";  // the CT series the set references
  std::string study_uid = "1.2.826.0.1.3680043.2.1125.2";
  std::string label = "lftrack test";
  struct Structure {
    int number = 1;
    std::string name;
    std::vector<std::vector<Eigen::Vector3d>> contours;
    std::string geometric_type = "CLOSED_PLANAR";
  };
  std::vector<Structure> structures;
};
void write_rt_structure_set(const std::filesystem::path& file, const RtStructSpec& spec);

// The shipped lumbar DICOM CT's L3 vertebral body (scenes/lumbar-ct.yaml's registration origin,
// (6, 107, 183) mm, at its centre): an ellipse of 36 x 28 mm (48 points) on each of the 11 CT
// slices from z 169.91 to 199.91 mm (the slices are 3 mm apart from 85.91 mm).
std::vector<std::vector<Eigen::Vector3d>> lumbar_ct_vertebral_body();

// Edits a DICOM file in place: the first element with tag (group, element), searched depth-first
// through sequences, gets `value` (inserted at the top level when there is none), or is removed
// when `value` is empty.
void edit_dicom_value(const std::filesystem::path& file, std::uint16_t group, std::uint16_t element,
                      const std::optional<std::string>& value);

}  // namespace lftrack::test

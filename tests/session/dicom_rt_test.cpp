// The DICOM RT readers (dicom_rt.hpp): the real CT's identity; plans and structure sets written
// by tests/support/rt_writer (DCMTK's dcmdata, not the dcmrt classes the readers use) read back;
// pydicom's RT test files (Debian's python3-pydicom) as foreign input; and what is refused, each
// refusal naming the file.

#include "lftrack/session/dicom_rt.hpp"

#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <sstream>

#include "dicom_writer.hpp"
#include "lftrack/session/dicom_registration.hpp"
#include "rt_writer.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;

// Where Debian's python3-pydicom keeps its test files.
const fs::path kPydicomFiles = "/usr/lib/python3/dist-packages/pydicom/data/test_files";

#define LFTRACK_REQUIRE_PYDICOM_FILES()                                   \
  do {                                                                    \
    if (!fs::exists(kPydicomFiles / "rtplan.dcm"))                        \
      GTEST_SKIP() << "pydicom's test files are not at " << kPydicomFiles \
                   << " (apt install python3-pydicom)";                   \
  } while (false)

// Refused, with a message that names the file and says `says`.
template <class T>
void expect_refused(const Result<T>& r, const fs::path& file, const std::string& says = "") {
  ASSERT_FALSE(r.ok()) << file;
  EXPECT_NE(r.status().message().find(file.string()), std::string::npos) << r.status().message();
  EXPECT_NE(r.status().message().find(says), std::string::npos) << r.status().message();
}

test::RtPlanSpec two_beam_plan() {
  test::RtPlanSpec spec;
  spec.frame_of_reference_uid = "1.2.826.0.1.3680043.2.1125.77";
  spec.label = "Pancreas SBRT";
  spec.beams = {{1, "A", {12.5, -40.25, 100.0}}, {2, "B", {12.5, -40.25, 100.0}}};
  return spec;
}

test::RtStructSpec two_structures() {
  test::RtStructSpec spec;
  spec.frame_of_reference_uid = "1.2.826.0.1.3680043.2.1125.77";
  spec.series_uid = "1.2.826.0.1.3680043.2.1125.78";
  spec.label = "Pancreas ROIs";
  const std::vector<Eigen::Vector3d> square = {{0, 0, 10}, {20, 0, 10}, {20, 20, 10}, {0, 20, 10}};
  const std::vector<Eigen::Vector3d> triangle = {{1.25, -3.5, 12.5}, {5, -3.5, 12.5}, {5, 2, 12.5}};
  spec.structures = {
      {7, "PTV", {square, triangle}}, {3, "Isocenter", {{{10, 10, 11}}}, "POINT"}, {9, "Empty", {}}};
  return spec;
}

std::string dciodvfy_errors(const fs::path& file) {
  FILE* pipe = ::popen(("dciodvfy " + file.string() + " 2>&1").c_str(), "r");
  if (!pipe) return "cannot run dciodvfy";
  std::string said;
  std::array<char, 4096> chunk{};
  while (std::fgets(chunk.data(), int(chunk.size()), pipe)) said += chunk.data();
  ::pclose(pipe);
  std::string errors;
  std::istringstream lines(said);
  for (std::string line; std::getline(lines, line);)
    if (line.rfind("Error", 0) == 0) errors += line + "\n";
  return errors;
}

TEST(DicomRtPlan, AWrittenPlanReadsBack) {
  test::TempDir dir;
  test::RtPlanSpec spec = two_beam_plan();
  spec.patient_position = "FFP";
  spec.tolerances = std::array<double, 6>{5, 6.5, 7, 1.5, 2, 3};
  const fs::path file = dir.path() / "plan.dcm";
  test::write_rt_plan(file, spec);

  auto plan = read_rt_plan(file, "");
  ASSERT_TRUE(plan.ok()) << plan.status().to_string();
  EXPECT_EQ(plan->file, file.string());
  EXPECT_EQ(plan->label, "Pancreas SBRT");
  EXPECT_EQ(plan->frame_of_reference_uid, spec.frame_of_reference_uid);
  EXPECT_EQ(plan->patient_position, "FFP");
  EXPECT_EQ(plan->beam.number, 1);
  EXPECT_EQ(plan->beam.name, "A");
  EXPECT_TRUE(plan->beam.isocentre_ct_mm.isApprox(Eigen::Vector3d(12.5, -40.25, 100.0)));
  ASSERT_EQ(plan->beams.size(), 2u);
  EXPECT_EQ(plan->beams[1].number, 2);
  EXPECT_EQ(plan->beams[1].name, "B");
  const TableTopTolerances& t = plan->tolerances;
  EXPECT_EQ(t.table_number, 1);
  EXPECT_EQ(t.lateral_mm, 5.0);
  EXPECT_EQ(t.longitudinal_mm, 6.5);
  EXPECT_EQ(t.vertical_mm, 7.0);
  EXPECT_EQ(t.pitch_deg, 1.5);
  EXPECT_EQ(t.roll_deg, 2.0);
  EXPECT_EQ(t.patient_support_deg, 3.0);

  // Without a tolerance table and a patient position: none, and no refusal.
  spec.tolerances.reset();
  spec.patient_position.clear();
  test::write_rt_plan(file, spec);
  auto bare = read_rt_plan(file, "");
  ASSERT_TRUE(bare.ok()) << bare.status().to_string();
  EXPECT_EQ(bare->tolerances.table_number, 0);
  EXPECT_FALSE(bare->tolerances.lateral_mm.has_value());
  EXPECT_EQ(bare->patient_position, "");

  // A plan without SOP Class UID whose Modality is RTPLAN is a plan.
  test::edit_dicom_value(file, 0x0008, 0x0016, std::nullopt);
  EXPECT_TRUE(read_rt_plan(file, "").ok());
}

TEST(DicomRtPlan, TwoIsocentresNeedABeamNamedByNumberOrName) {
  test::TempDir dir;
  test::RtPlanSpec spec = two_beam_plan();
  spec.beams[1].isocentre_mm += Eigen::Vector3d(0, 0, 0.005);  // within 0.01 mm: one isocentre
  const fs::path file = dir.path() / "plan.dcm";
  test::write_rt_plan(file, spec);
  EXPECT_TRUE(read_rt_plan(file, "").ok());

  spec.beams[1].isocentre_mm = {-30, 15, 90};
  test::write_rt_plan(file, spec);
  auto refused = read_rt_plan(file, "");
  expect_refused(refused, file, "the plan has 2 isocentres");
  for (const char* says : {"beam 1 'A' at (12.5, -40.25, 100)", "beam 2 'B' at (-30, 15, 90)", "--beam"})
    EXPECT_NE(refused.status().message().find(says), std::string::npos) << refused.status().message();

  for (const char* beam : {"2", "B"}) {
    auto chosen = read_rt_plan(file, beam);
    ASSERT_TRUE(chosen.ok()) << chosen.status().to_string();
    EXPECT_EQ(chosen->beam.number, 2);
    EXPECT_EQ(chosen->beam.name, "B");
    EXPECT_TRUE(chosen->beam.isocentre_ct_mm.isApprox(Eigen::Vector3d(-30, 15, 90)));
    EXPECT_EQ(chosen->beams.size(), 2u);
  }
  auto a = read_rt_plan(file, "A");
  ASSERT_TRUE(a.ok()) << a.status().to_string();
  EXPECT_EQ(a->beam.number, 1);

  auto unknown = read_rt_plan(file, "3");
  expect_refused(unknown, file, "no beam '3'");
  EXPECT_NE(unknown.status().message().find("1 'A', 2 'B'"), std::string::npos) << unknown.status().message();
  expect_refused(read_rt_plan(file, "C"), file, "1 'A', 2 'B'");
}

TEST(DicomRtPlan, RefusesAPlanWithoutWhatTheSetUpNeeds) {
  test::TempDir dir;
  const fs::path file = dir.path() / "plan.dcm";
  test::RtPlanSpec spec = two_beam_plan();
  spec.beams[1].isocentre_in_first_control_point = false;
  test::write_rt_plan(file, spec);
  expect_refused(read_rt_plan(file, "1"), file,
                 "beam 2 'B' has no Isocenter Position (300A,012C) in its first");

  spec = two_beam_plan();
  spec.frame_of_reference_uid.clear();
  test::write_rt_plan(file, spec);
  expect_refused(read_rt_plan(file, ""), file, "no Frame of Reference UID");

  spec = two_beam_plan();
  spec.beams.clear();
  test::write_rt_plan(file, spec);
  expect_refused(read_rt_plan(file, ""), file, "no beam");

  spec = two_beam_plan();
  spec.patient_position = "HFX";
  test::write_rt_plan(file, spec);
  expect_refused(read_rt_plan(file, ""), file, "'HFX'");

  for (const std::string isocentre : {"1\\2", "1\\2\\nan", "1\\2\\3abc", "1\\2\\inf"}) {
    test::write_rt_plan(file, two_beam_plan());
    test::edit_dicom_value(file, 0x300A, 0x012C, isocentre);
    expect_refused(read_rt_plan(file, "1"), file, "is not 3 finite numbers");
  }

  test::write_rt_plan(file, two_beam_plan());
  test::edit_dicom_value(file, 0x0008, 0x0016, std::string("1.2.840.10008.5.1.4.1.1.481.8"));  // RT Ion Plan
  expect_refused(read_rt_plan(file, ""), file, "ion plans are not supported");
}

TEST(DicomRtStructureSet, AWrittenStructureSetReadsBack) {
  test::TempDir dir;
  const test::RtStructSpec spec = two_structures();
  const fs::path file = dir.path() / "structures.dcm";
  test::write_rt_structure_set(file, spec);

  auto set = read_rt_structure_set(file);
  ASSERT_TRUE(set.ok()) << set.status().to_string();
  EXPECT_EQ(set->file, file.string());
  EXPECT_EQ(set->label, "Pancreas ROIs");
  EXPECT_EQ(set->frame_of_reference_uids, std::vector<std::string>{spec.frame_of_reference_uid});
  EXPECT_EQ(set->referenced_series_uids, std::vector<std::string>{spec.series_uid});
  ASSERT_EQ(set->structures.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    const RtStructure& s = set->structures[i];
    const test::RtStructSpec::Structure& written = spec.structures[i];
    EXPECT_EQ(s.roi_number, written.number);
    EXPECT_EQ(s.name, written.name);
    EXPECT_EQ(s.frame_of_reference_uid, spec.frame_of_reference_uid);
    ASSERT_EQ(s.contours.size(), written.contours.size()) << s.name;
    for (std::size_t k = 0; k < s.contours.size(); ++k) {
      EXPECT_EQ(s.contours[k].geometric_type, written.geometric_type);
      ASSERT_EQ(s.contours[k].points_ct_mm.size(), written.contours[k].size());
      for (std::size_t p = 0; p < written.contours[k].size(); ++p)
        EXPECT_EQ(s.contours[k].points_ct_mm[p], written.contours[k][p])
            << s.name << " contour " << k << " point " << p;
    }
  }
}

TEST(DicomRtStructureSet, RefusesContoursThatDisagreeWithThemselves) {
  test::TempDir dir;
  const fs::path file = dir.path() / "structures.dcm";
  const std::pair<std::uint16_t, std::string> edits[] = {
      {0x0046, "5"},                     // NumberOfContourPoints: the first contour has 4
      {0x0050, "1\\2\\3\\4"},            // ContourData: not a multiple of 3
      {0x0050, "1\\2\\3\\4\\5\\nan"},    // not finite
      {0x0050, "1\\2\\3\\4\\5\\6abc"}};  // not a number
  const char* says[] = {"NumberOfContourPoints (3006,0046) is 5 but ContourData holds 4 points",
                        "holds 4 numbers, not a multiple of 3", "not a finite decimal number",
                        "not a finite decimal number"};
  for (std::size_t i = 0; i < std::size(edits); ++i) {
    test::write_rt_structure_set(file, two_structures());
    // A ContourData edit leaves the first contour without NumberOfContourPoints, to reach the data's checks.
    if (edits[i].first == 0x0050) test::edit_dicom_value(file, 0x3006, 0x0046, std::nullopt);
    test::edit_dicom_value(file, 0x3006, edits[i].first, edits[i].second);
    auto set = read_rt_structure_set(file);
    expect_refused(set, file, says[i]);
    EXPECT_NE(set.status().message().find("structure 'PTV' (ROI 7), contour 1"), std::string::npos)
        << set.status().message();
  }

  test::RtStructSpec huge = two_structures();
  huge.structures[1].contours[0].assign(kMaxPointsPerContour + 1, Eigen::Vector3d(1, 2, 3));
  test::write_rt_structure_set(file, huge);
  expect_refused(read_rt_structure_set(file), file, "100001 points");
}

TEST(DicomRtFiles, WhatIsNeitherIsRefusedNamingTheFile) {
  test::TempDir dir;
  const fs::path plan = dir.path() / "plan.dcm", structures = dir.path() / "structures.dcm";
  test::write_rt_plan(plan, two_beam_plan());
  test::write_rt_structure_set(structures, two_structures());
  expect_refused(read_rt_plan(structures, ""), structures, "not an RT Plan");
  expect_refused(read_rt_structure_set(plan), plan, "not an RT Structure Set");

  const fs::path slice = dir.path() / "slice.dcm";
  ASSERT_TRUE(test::write_synthetic_slice(slice, test::SyntheticSlice{}));
  expect_refused(read_rt_plan(slice, ""), slice, "not an RT Plan");
  expect_refused(read_rt_structure_set(slice), slice, "not an RT Structure Set");

  const fs::path text = dir.path() / "plan.txt", empty = dir.path() / "empty.dcm",
                 cut = dir.path() / "cut.dcm";
  std::ofstream(text) << "isocentre 12.5 -40.25 100\nbeam A\n";
  { std::ofstream touch(empty); }
  {
    std::ifstream in(plan, std::ios::binary);
    std::string head(200, '\0');
    in.read(head.data(), 200);
    std::ofstream(cut, std::ios::binary) << head;
  }
  for (const fs::path& file : {text, empty, cut, dir.path() / "nowhere.dcm"}) {
    expect_refused(read_rt_plan(file, ""), file);
    expect_refused(read_rt_structure_set(file), file);
  }
}

TEST(DicomRtFiles, WrittenFilesPassDciodvfy) {
  if (std::system("command -v dciodvfy >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "dciodvfy (dicom3tools) is not installed";
  test::TempDir dir;
  test::RtPlanSpec plan = two_beam_plan();
  plan.tolerances = std::array<double, 6>{5, 5, 5, 1, 1, 1};
  test::write_rt_plan(dir.path() / "plan.dcm", plan);
  test::write_rt_structure_set(dir.path() / "structures.dcm", two_structures());
  EXPECT_EQ(dciodvfy_errors(dir.path() / "plan.dcm"), "");
  EXPECT_EQ(dciodvfy_errors(dir.path() / "structures.dcm"), "");
}

// pydicom's rtplan.dcm has no Frame of Reference (it is optional in an RT Plan): refused for that;
// with one added, its one beam and isocentre read as pydicom's dump shows them.
TEST(DicomRtForeign, PydicomsPlan) {
  LFTRACK_REQUIRE_PYDICOM_FILES();
  const fs::path original = kPydicomFiles / "rtplan.dcm";
  expect_refused(read_rt_plan(original, ""), original, "no Frame of Reference UID");
  test::TempDir dir;
  const fs::path file = dir.path() / "rtplan.dcm";
  fs::copy_file(original, file);
  test::edit_dicom_value(file, 0x0020, 0x0052, std::string("1.2.826.0.1.3680043.2.1125.42"));
  auto plan = read_rt_plan(file, "");
  ASSERT_TRUE(plan.ok()) << plan.status().to_string();
  EXPECT_EQ(plan->label, "Plan1");
  EXPECT_EQ(plan->frame_of_reference_uid, "1.2.826.0.1.3680043.2.1125.42");
  ASSERT_EQ(plan->beams.size(), 1u);
  EXPECT_EQ(plan->beam.number, 1);
  EXPECT_EQ(plan->beam.name, "Field 1");
  EXPECT_TRUE(plan->beam.isocentre_ct_mm.isApprox(
      Eigen::Vector3d(235.711172833292, 244.135437110782, -724.97815409918)));
  EXPECT_EQ(plan->patient_position, "HFS");
  EXPECT_EQ(plan->tolerances.table_number, 0);
  auto by_name = read_rt_plan(file, "Field 1");
  ASSERT_TRUE(by_name.ok()) << by_name.status().to_string();
  EXPECT_EQ(by_name->beam.number, 1);

  const fs::path truncated = kPydicomFiles / "rtplan_truncated.dcm";
  if (fs::exists(truncated)) expect_refused(read_rt_plan(truncated, ""), truncated);
}

TEST(DicomRtForeign, PydicomsStructureSet) {
  LFTRACK_REQUIRE_PYDICOM_FILES();
  const fs::path file = kPydicomFiles / "rtstruct.dcm";  // no preamble and no meta header
  auto set = read_rt_structure_set(file);
  ASSERT_TRUE(set.ok()) << set.status().to_string();
  EXPECT_EQ(set->label, "sep30");
  EXPECT_EQ(set->frame_of_reference_uids,
            std::vector<std::string>{"1.2.826.0.1.3680043.8.498.2010020400001.2"});
  EXPECT_EQ(set->referenced_series_uids,
            std::vector<std::string>{"1.2.826.0.1.3680043.8.498.2010020400001.2.1.1"});
  ASSERT_EQ(set->structures.size(), 3u);
  const RtStructure& patient = set->structures[0];
  EXPECT_EQ(patient.roi_number, 1);
  EXPECT_EQ(patient.name, "patient");
  ASSERT_EQ(patient.contours.size(), 3u);
  EXPECT_EQ(patient.contours[0].geometric_type, "CLOSED_PLANAR");
  EXPECT_EQ(patient.contours[0].points_ct_mm.size(), 5u);
  EXPECT_EQ(patient.contours[0].points_ct_mm[0], Eigen::Vector3d(-200, 150, -200));
  EXPECT_EQ(patient.contours[1].points_ct_mm.size(), 6u);
  EXPECT_EQ(patient.contours[2].points_ct_mm.back(), Eigen::Vector3d(200, 0, -180));
  for (int i : {1, 2}) {
    const RtStructure& iso = set->structures[std::size_t(i)];
    EXPECT_EQ(iso.roi_number, i + 1);
    EXPECT_EQ(iso.name, "Isocenter " + std::to_string(i));
    ASSERT_EQ(iso.contours.size(), 1u);
    EXPECT_EQ(iso.contours[0].geometric_type, "POINT");
    EXPECT_EQ(iso.contours[0].points_ct_mm, std::vector<Eigen::Vector3d>{Eigen::Vector3d::Zero()});
  }
}

TEST(DicomRtForeign, PydicomsDoseIsNeither) {
  LFTRACK_REQUIRE_PYDICOM_FILES();
  const fs::path file = kPydicomFiles / "rtdose.dcm";
  expect_refused(read_rt_plan(file, ""), file, "not an RT Plan");
  expect_refused(read_rt_structure_set(file), file, "not an RT Structure Set");
}

}  // namespace
}  // namespace lftrack::session

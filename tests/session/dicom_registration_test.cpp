// The registration as a DICOM Spatial Registration object (dicom_registration.hpp), read back with
// DCMTK: the matrix, the Frames of Reference, the CT's series and slices, the patient and study;
// validated by dicom3tools' dciodvfy where it is installed; and what is refused.

#include "lftrack/session/dicom_registration.hpp"

#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "lftrack/tracking/pose.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;

std::string text(DcmItem* item, const DcmTagKey& tag, unsigned long index = 0) {
  OFString v;
  item->findAndGetOFString(tag, v, index);
  return v.c_str();
}

DcmItem* item_of(DcmItem* parent, const DcmTagKey& sequence, unsigned long index) {
  DcmItem* item = nullptr;
  parent->findAndGetSequenceItem(sequence, item, static_cast<signed long>(index));
  return item;
}

tracking::Pose sample_pose() {
  tracking::Pose T = tracking::Pose::Identity();
  T.linear() = tracking::rotation_exp(Eigen::Vector3d(0.02, -0.3, 1.2));
  T.translation() << -123.456789, 45.6789012, 1234.5678901;
  return T;
}

TEST(DicomRegistration, ReadsTheCtsIdentityFromItsHeaders) {
  LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
  auto id = read_ct_dicom_identity(test::pancreas_dicom());
  ASSERT_TRUE(id.ok()) << id.status().message();
  EXPECT_EQ(id->instances.size(), 134u) << "every slice";
  EXPECT_FALSE(id->frame_of_reference_uid.empty());
  EXPECT_FALSE(id->series_uid.empty());
  EXPECT_FALSE(id->study_uid.empty());
  EXPECT_EQ(id->instances.front().first, UID_CTImageStorage);
}

TEST(DicomRegistration, WritesTheMatrixAndReferencesTheCt) {
  LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
  auto ct = read_ct_dicom_identity(test::pancreas_dicom());
  ASSERT_TRUE(ct.ok());
  test::TempDir dir;
  const fs::path file = dir.path() / "reg.dcm";
  SpatialRegistration reg;
  reg.T_room_from_ct = sample_pose();
  reg.room_frame_of_reference_uid = "2.25.1234567890";
  reg.description = "test";
  ASSERT_TRUE(write_spatial_registration(file, *ct, reg).ok());
  DcmFileFormat format;
  ASSERT_TRUE(format.loadFile(file.c_str()).good());
  DcmDataset* ds = format.getDataset();
  EXPECT_EQ(text(ds, DCM_SOPClassUID), UID_SpatialRegistrationStorage);
  EXPECT_EQ(text(ds, DCM_Modality), "REG");
  EXPECT_EQ(text(ds, DCM_FrameOfReferenceUID), "2.25.1234567890") << "the registered frame: the room's";
  EXPECT_EQ(text(ds, DCM_StudyInstanceUID), ct->study_uid) << "filed with the CT's study";
  EXPECT_EQ(text(ds, DCM_PatientID), ct->patient_id);
  EXPECT_NE(text(ds, DCM_SeriesInstanceUID), ct->series_uid) << "a series of its own";
  DcmItem* room = item_of(ds, DCM_RegistrationSequence, 0);
  DcmItem* ct_item = item_of(ds, DCM_RegistrationSequence, 1);
  ASSERT_NE(room, nullptr);
  ASSERT_NE(ct_item, nullptr);
  EXPECT_EQ(text(room, DCM_FrameOfReferenceUID), "2.25.1234567890");
  EXPECT_EQ(text(ct_item, DCM_FrameOfReferenceUID), ct->frame_of_reference_uid);
  DcmItem* matrix = item_of(item_of(ct_item, DCM_MatrixRegistrationSequence, 0), DCM_MatrixSequence, 0);
  ASSERT_NE(matrix, nullptr);
  EXPECT_EQ(text(matrix, DCM_FrameOfReferenceTransformationMatrixType), "RIGID");
  const Eigen::Matrix4d expected = sample_pose().matrix();
  for (unsigned long i = 0; i < 16; ++i) {
    Float64 v = 0;
    ASSERT_TRUE(matrix->findAndGetFloat64(DCM_FrameOfReferenceTransformationMatrix, v, i).good()) << i;
    EXPECT_NEAR(v, expected(int(i / 4), int(i % 4)), 1e-9 * std::max(1.0, std::abs(v))) << "element " << i;
  }
  DcmItem* identity = item_of(item_of(room, DCM_MatrixRegistrationSequence, 0), DCM_MatrixSequence, 0);
  Float64 diagonal = 0;
  identity->findAndGetFloat64(DCM_FrameOfReferenceTransformationMatrix, diagonal, 5);
  EXPECT_EQ(diagonal, 1.0);
  DcmItem* series = item_of(ds, DCM_ReferencedSeriesSequence, 0);
  ASSERT_NE(series, nullptr);
  EXPECT_EQ(text(series, DCM_SeriesInstanceUID), ct->series_uid);
  DcmSequenceOfItems* instances = nullptr;
  ASSERT_TRUE(series->findAndGetSequence(DCM_ReferencedInstanceSequence, instances).good());
  EXPECT_EQ(instances->card(), ct->instances.size());
  EXPECT_EQ(text(item_of(series, DCM_ReferencedInstanceSequence, 7), DCM_ReferencedSOPInstanceUID),
            ct->instances[7].second);
  // Never over a file, whatever is there.
  EXPECT_FALSE(write_spatial_registration(file, *ct, reg).ok());
  fs::create_symlink(dir.path() / "nowhere", dir.path() / "link.dcm");
  EXPECT_FALSE(write_spatial_registration(dir.path() / "link.dcm", *ct, reg).ok());
  EXPECT_FALSE(fs::exists(dir.path() / "nowhere"));

  // dicom3tools' validator, when Debian's package is installed: no errors.
  if (std::system("command -v dciodvfy >/dev/null 2>&1") != 0) GTEST_SKIP() << "dciodvfy (dicom3tools) is not installed";
  const std::string command = "dciodvfy " + file.string() + " 2>&1";
  FILE* pipe = ::popen(command.c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  std::string said;
  std::array<char, 4096> chunk{};
  while (std::fgets(chunk.data(), int(chunk.size()), pipe)) said += chunk.data();
  ::pclose(pipe);
  std::istringstream lines(said);
  for (std::string line; std::getline(lines, line);) EXPECT_NE(line.rfind("Error", 0), 0u) << line;
  EXPECT_NE(said.find("SpatialRegistration"), std::string::npos) << said;
}

TEST(DicomRegistration, RefusesWhatIsNoRegistration) {
  LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
  auto ct = read_ct_dicom_identity(test::pancreas_dicom());
  ASSERT_TRUE(ct.ok());
  test::TempDir dir;
  SpatialRegistration reg;
  reg.room_frame_of_reference_uid = "2.25.1";
  reg.T_room_from_ct.translation().x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(write_spatial_registration(dir.path() / "a.dcm", *ct, reg).ok());
  reg.T_room_from_ct = tracking::Pose::Identity();
  reg.T_room_from_ct.matrix()(0, 0) = 2;  // a scaling, not a rigid pose
  EXPECT_FALSE(write_spatial_registration(dir.path() / "b.dcm", *ct, reg).ok());
  reg.T_room_from_ct = tracking::Pose::Identity();
  reg.T_room_from_ct.translation().x() = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(write_spatial_registration(dir.path() / "c.dcm", *ct, reg).ok());
  reg.T_room_from_ct = tracking::Pose::Identity();
  reg.room_frame_of_reference_uid.clear();
  EXPECT_FALSE(write_spatial_registration(dir.path() / "d.dcm", *ct, reg).ok());
  EXPECT_TRUE(fs::is_empty(dir.path())) << "nothing written when refused";
}

TEST(DicomRegistration, NeedsADicomPlanningCt) {
  Scene scene;
  scene.ct.path = kBuiltinPhantom;
  EXPECT_NE(scene_ct_dicom_identity(scene).status().message().find("built-in phantom"), std::string::npos);
  scene.ct.path = test::totalseg_example().string();
  EXPECT_NE(scene_ct_dicom_identity(scene).status().message().find("NIfTI"), std::string::npos);
  test::TempDir dir;
  EXPECT_FALSE(read_ct_dicom_identity(dir.path()).ok()) << "no DICOM files";
  std::ofstream(dir.path() / "notes.txt") << "not DICOM";
  EXPECT_FALSE(read_ct_dicom_identity(dir.path()).ok());
  EXPECT_FALSE(read_ct_dicom_identity(dir.path() / "missing").ok());
}

TEST(DicomRegistration, TheRoomsFrameOfReferenceFollowsItsGeometry) {
  Scene a;
  DetectorSpec d;
  d.view.name = "A";
  d.view.rows = d.view.cols = 512;
  d.view.source_mm = Eigen::Vector3d(1000, 0, 0);
  a.detectors.push_back(d);
  const std::string uid = room_frame_of_reference_uid(a);
  EXPECT_EQ(uid.rfind("2.25.", 0), 0u);
  EXPECT_LE(uid.size(), 64u) << "a DICOM UID";
  EXPECT_EQ(uid.find_first_not_of("0123456789.", 0), std::string::npos);
  EXPECT_NE(uid[5], '0') << "no leading zero in a UID component";
  EXPECT_EQ(room_frame_of_reference_uid(a), uid) << "the same room, the same frame";
  a.detectors[0].view.source_mm.x() += 0.001;
  EXPECT_NE(room_frame_of_reference_uid(a), uid) << "another calibration, another frame";
}

}  // namespace
}  // namespace lftrack::session

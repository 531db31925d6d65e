// A new patient's scene from an RT Plan and Structure Set written for the shipped DICOM CT
// (patient_setup.cpp, setup_picture.cpp): the set-up, every refusal, and the picture's marks.

#include "lftrack/session/patient_setup.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <memory>

#include "lftrack/session/scene.hpp"
#include "lftrack/session/setup_picture.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "lftrack/tracking/volume_io.hpp"
#include "rt_writer.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;
using Eigen::Vector3d;

// The lumbar scene's vertebral body (scenes/lumbar-ct.yaml): the isocentre at its centre, the target
// an ellipse 36 x 28 mm on the 11 slices from z 169.91 to 199.91 mm (the CT's slices are 3 mm apart
// from 85.91 mm).
const Vector3d kIsocentre(6, 107, 183);
constexpr double kFirstSliceZ = 85.91;

std::vector<std::vector<Vector3d>> vertebral_body() { return test::lumbar_ct_vertebral_body(); }

class PatientSetup : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (!fs::exists(test::pancreas_dicom())) return;
    auto ct = tracking::read_ct(test::pancreas_dicom());
    ASSERT_TRUE(ct.ok()) << ct.status().message();
    ct_ = std::make_unique<tracking::CtVolume>(std::move(*ct));
    auto identity = read_ct_dicom_identity(test::pancreas_dicom());
    ASSERT_TRUE(identity.ok()) << identity.status().message();
    identity_ = *identity;
  }
  static void TearDownTestSuite() { ct_.reset(); }
  void SetUp() override {
    LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
    plan_.frame_of_reference_uid = identity_.frame_of_reference_uid;
    plan_.label = "L3 SBRT";
    plan_.beams = {{1, "setup", kIsocentre, true}, {2, "arc 1", kIsocentre, true}};
    structures_.frame_of_reference_uid = identity_.frame_of_reference_uid;
    structures_.series_uid = identity_.series_uid;
    structures_.study_uid = identity_.study_uid;
    structures_.structures = {{1, "BODY", {{{-100, 0, 180}, {100, 0, 180}, {100, 200, 180}, {-100, 200, 180}}}},
                              {2, "L3 body", vertebral_body()}};
  }
  // Writes the plan and the structure set, and composes the scene from them.
  Result<NewScene> compose(NewSceneRequest r = {}) {
    if (r.rtplan.empty() && !r.isocentre_ct_mm) {
      r.rtplan = dir_.path() / "plan.dcm";
      test::write_rt_plan(r.rtplan, plan_);
    }
    if (r.rtstruct.empty()) {
      r.rtstruct = dir_.path() / "structures.dcm";
      test::write_rt_structure_set(r.rtstruct, structures_);
      if (r.target.empty()) r.target = "L3 body";
    }
    r.ct = test::pancreas_dicom();
    r.room = fs::path(LFTRACK_SOURCE_DIR) / "scenes/room/oblique-pair.yaml";
    if (r.output.empty()) r.output = dir_.path() / "patient.yaml";
    return compose_new_scene(r, {ct_.get(), identity_});
  }
  std::string refusal(NewSceneRequest r = {}) {
    auto scene = compose(std::move(r));
    EXPECT_FALSE(scene.ok());
    return scene.ok() ? std::string() : scene.status().message();
  }

  static std::unique_ptr<tracking::CtVolume> ct_;
  static CtDicomIdentity identity_;
  test::TempDir dir_;
  test::RtPlanSpec plan_;
  test::RtStructSpec structures_;
};
std::unique_ptr<tracking::CtVolume> PatientSetup::ct_;
CtDicomIdentity PatientSetup::identity_;

TEST_F(PatientSetup, TheIsocentreFromThePlanAndTheRoiFromTheTargetMakeASceneThatLoads) {
  plan_.tolerances = std::array<double, 6>{5, 6, 7, 2, 3, 4};
  auto setup = compose();
  ASSERT_TRUE(setup.ok()) << setup.status().message();
  EXPECT_TRUE(setup->isocentre_ct_mm.isApprox(kIsocentre));
  EXPECT_NE(setup->isocentre_from.find("plan 'L3 SBRT'"), std::string::npos) << setup->isocentre_from;
  EXPECT_NE(setup->isocentre_from.find("300A,012C"), std::string::npos);
  // The ROI: the target's box (36 x 28 x 30 mm about (6, 107, 184.91)) plus 10 mm each side.
  EXPECT_TRUE(setup->roi_centre_ct_mm.isApprox(Vector3d(6, 107, kFirstSliceZ + 3 * 33), 1e-3))
      << setup->roi_centre_ct_mm.transpose();
  EXPECT_NEAR(setup->roi_size_mm.x(), 56, 0.1);
  EXPECT_NEAR(setup->roi_size_mm.y(), 48, 0.1);
  EXPECT_NEAR(setup->roi_size_mm.z(), 50, 0.1);
  ASSERT_TRUE(setup->target.has_value());
  // An ellipse of 36 x 28 mm on 11 slices of 3 mm: pi * 18 * 14 * 33 mm^3.
  EXPECT_NEAR(setup->target->volume_cc(), M_PI * 18 * 14 * 33 / 1000, 0.08 * M_PI * 18 * 14 * 33 / 1000);

  auto scene = parse_scene(setup->yaml, (dir_.path() / "patient.yaml").string(), dir_.path());
  ASSERT_TRUE(scene.ok()) << scene.status().message() << "\n" << setup->yaml;
  ASSERT_TRUE(scene->registration_origin_ct_mm.has_value());
  EXPECT_TRUE(scene->registration_origin_ct_mm->isApprox(kIsocentre));
  EXPECT_EQ(scene->ct.path, test::pancreas_dicom().lexically_normal().string());
  EXPECT_DOUBLE_EQ(scene->envelope.translation_mm, 5) << "the plan's tightest table-top tolerance";
  EXPECT_DOUBLE_EQ(scene->envelope.rotation_deg, 2);
  EXPECT_EQ(scene->commissioning_file, (dir_.path() / "patient.commissioning.yaml").string());
  EXPECT_EQ(scene->detectors.size(), 2u) << "from the room";
  // Where each value came from is written beside it.
  // The test's RT objects carry another patient ID than the CT: said, not refused (the UIDs decide).
  EXPECT_NE(setup->yaml.find("the plan is for patient ID 'LFTRACK-TEST', the CT for 'Pancreas-CT-CB_001'"),
            std::string::npos)
      << setup->yaml;
  EXPECT_NE(setup->yaml.find("the structure set is for patient ID 'LFTRACK-TEST'"), std::string::npos);
  for (const char* said : {"target 'L3 body' (ROI number 2", "tolerance table 1 of the plan", "Frame of Reference " ,
                           "the CT's slices are 3.00 mm apart"})
    EXPECT_NE(setup->yaml.find(said), std::string::npos) << said << "\n" << setup->yaml;

  tracking::ThreadPool pool(2);
  auto prepared = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(prepared.ok()) << prepared.status().message();
  EXPECT_TRUE(prepared->registration_origin_room_mm().isZero(1e-9)) << "the isocentre on the room's";
}

TEST_F(PatientSetup, ThePicturesMarksAreDrawnWhereTheTargetIs) {
  auto setup = compose();
  ASSERT_TRUE(setup.ok()) << setup.status().message();
  auto scene = parse_scene(setup->yaml, (dir_.path() / "patient.yaml").string(), dir_.path());
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  tracking::ThreadPool pool(2);
  auto prepared = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(prepared.ok()) << prepared.status().message();
  SetupMarks marks{setup->isocentre_ct_mm, setup->roi_centre_ct_mm, setup->roi_size_mm, setup->target_polygons,
                   &*setup->target};
  constexpr int kPanel = 128;
  auto picture = setup_picture(*prepared, marks, &pool, kPanel);
  ASSERT_TRUE(picture.ok()) << picture.status().message();
  ASSERT_EQ(picture->rows, 2 * kPanel + 4);
  // Each panel has the isocentre's cross at its centre (the isocentre projects to the detector's
  // centre in an isocentric room, and every slice is centred on it), and the target's red near it.
  const auto colour_at = [&](int row, int col) {
    const std::uint8_t* p = &picture->rgb[(std::size_t(row) * std::size_t(picture->cols) + std::size_t(col)) * 3];
    return std::array<int, 3>{p[0], p[1], p[2]};
  };
  for (int panel = 0; panel < 3; ++panel) {
    for (int row0 : {0, kPanel + 4}) {
      if (row0 == 0 && panel == 2) continue;  // two views
      const int r = row0 + kPanel / 2, c = panel * (kPanel + 4) + kPanel / 2;
      int green = 0, red = 0;
      // The target's outline lies 14-18 mm from the isocentre: within 24 pixels of 1.1 mm (views)
      // and, at 0.5 mm a pixel, partly beyond the slices' 32 (which the outline crosses all the same).
      for (int dr = -32; dr <= 32; ++dr)
        for (int dc = -32; dc <= 32; ++dc) {
          const auto px = colour_at(r + dr, c + dc);
          green += px == std::array<int, 3>{0, 255, 0};
          red += px == std::array<int, 3>{255, 0, 0};
        }
      EXPECT_GE(green, 10) << "panel " << panel << " row " << row0;
      EXPECT_GE(red, 4) << "panel " << panel << " row " << row0;
    }
  }
  EXPECT_GT(count_colour(*picture, 255, 255, 0), 100) << "the ROI's box";
}

TEST_F(PatientSetup, APlanOrStructureSetOfAnotherCtIsRefusedNamingBothUids) {
  plan_.frame_of_reference_uid = "1.2.3.4.5";
  std::string m = refusal();
  EXPECT_NE(m.find("Frame of Reference 1.2.3.4.5, the CT in " + identity_.frame_of_reference_uid), std::string::npos) << m;
  plan_.frame_of_reference_uid = identity_.frame_of_reference_uid;
  structures_.frame_of_reference_uid = "1.2.3.4.6";
  m = refusal();
  EXPECT_NE(m.find("structure set is in Frame of Reference 1.2.3.4.6"), std::string::npos) << m;
  structures_.frame_of_reference_uid = identity_.frame_of_reference_uid;
  structures_.series_uid = "1.2.3.4.7";
  m = refusal();
  EXPECT_NE(m.find("references series 1.2.3.4.7, the CT is series " + identity_.series_uid),
            std::string::npos)
      << m;
}

TEST_F(PatientSetup, AnIsocentreOutsideTheCtOrAwayFromTheTargetIsRefused) {
  for (auto& beam : plan_.beams) beam.isocentre_mm = Vector3d(6, 107, 1000);
  std::string m = refusal();
  EXPECT_NE(m.find("lies outside the CT"), std::string::npos) << m;
  for (auto& beam : plan_.beams) beam.isocentre_mm = Vector3d(6, 107, 130);  // in the CT, 40 mm below the target
  m = refusal();
  EXPECT_NE(m.find("the plan and the structure set disagree"), std::string::npos) << m;
  NewSceneRequest given;
  given.isocentre_ct_mm = Vector3d(NAN, 0, 0);
  EXPECT_NE(refusal(given).find("finite"), std::string::npos);
}

TEST_F(PatientSetup, TwoIsocentresNeedABeam) {
  plan_.beams[1].isocentre_mm = kIsocentre + Vector3d(0, 0, 6);
  EXPECT_NE(refusal().find("--beam"), std::string::npos);
  NewSceneRequest r;
  r.beam = "arc 1";
  auto setup = compose(r);
  ASSERT_TRUE(setup.ok()) << setup.status().message();
  EXPECT_TRUE(setup->isocentre_ct_mm.isApprox(kIsocentre + Vector3d(0, 0, 6)));
}

TEST_F(PatientSetup, ATargetThatEnclosesNothingOrIsNotThereIsRefused) {
  NewSceneRequest r;
  r.target = "L4 body";
  std::string m = refusal(r);
  EXPECT_NE(m.find("no structure named 'L4 body'"), std::string::npos) << m;
  EXPECT_NE(m.find("'L3 body'"), std::string::npos) << "the names listed: " << m;
  structures_.structures.push_back({3, "L3 body", vertebral_body()});
  m = refusal();
  EXPECT_NE(m.find("more than one structure is named 'L3 body'"), std::string::npos) << m;
  structures_.structures.pop_back();
  structures_.structures[1].contours = {{kIsocentre}};
  structures_.structures[1].geometric_type = "POINT";
  m = refusal();
  EXPECT_NE(m.find("no closed planar contour (it has 1 POINT)"), std::string::npos) << m;
  structures_.structures[1].geometric_type = "CLOSED_PLANAR";
  structures_.structures[1].contours = {{{0, 100, 181.91}, {20, 120, 181.91}, {20, 100, 181.91}, {0, 120, 181.91}}};
  m = refusal();
  EXPECT_NE(m.find("crosses itself"), std::string::npos) << m;
  structures_.structures[1].contours = {{{0, 100, 181.91}, {20, 120, 181.91}}};
  m = refusal();
  EXPECT_NE(m.find("2 distinct point(s)"), std::string::npos) << m;
  structures_.structures[1].contours = {};
  m = refusal();
  EXPECT_NE(m.find("no closed planar contour"), std::string::npos) << m;
  // A target beyond the scanned slices.
  structures_.structures[1].contours = {{{0, 100, 900}, {20, 100, 900}, {20, 120, 900}}};
  NewSceneRequest iso_given;
  iso_given.isocentre_ct_mm = kIsocentre;
  m = refusal(iso_given);
  EXPECT_NE(m.find("reaches beyond the scanned slices (1 of its 1 contours lie outside the CT)"), std::string::npos) << m;
  // Part of it beyond the last slice is as refused: the CT does not hold the whole target.
  structures_.structures[1].contours = vertebral_body();
  structures_.structures[1].contours.push_back({{0, 100, 900}, {20, 100, 900}, {20, 120, 900}});
  m = refusal();
  EXPECT_NE(m.find("(1 of its 12 contours lie outside the CT)"), std::string::npos) << m;
  // A contour repeated on its slice: refused as what it is, with the file named.
  structures_.structures[1].contours = vertebral_body();
  structures_.structures[1].contours.push_back(structures_.structures[1].contours[3]);
  m = refusal();
  EXPECT_NE(m.find("structures.dcm: target 'L3 body', contour 12 repeats another contour of its slice"),
            std::string::npos)
      << m;
  // Contours 1 mm off the CT's slices (3 mm apart): taken, and said.
  structures_.structures[1].contours = vertebral_body();
  for (auto& ring : structures_.structures[1].contours)
    for (Vector3d& q : ring) q.z() += 1;
  auto off = compose();
  ASSERT_TRUE(off.ok()) << off.status().message();
  ASSERT_FALSE(off->warnings.empty());
  EXPECT_NE(off->warnings.front().find("a contour lies 1.00 mm from the CT slice"), std::string::npos)
      << off->warnings.front();
}

TEST_F(PatientSetup, ANiftiCtTakesAGivenIsocentreButNeverAPlan) {
  LFTRACK_REQUIRE_SHARED_DATA(test::totalseg_example());
  auto nifti = tracking::read_ct(test::totalseg_example());
  ASSERT_TRUE(nifti.ok());
  NewSceneRequest r;
  r.ct = test::totalseg_example();
  r.room = fs::path(LFTRACK_SOURCE_DIR) / "scenes/room/oblique-pair.yaml";
  r.output = dir_.path() / "nifti.yaml";
  r.rtplan = dir_.path() / "plan.dcm";
  test::write_rt_plan(r.rtplan, plan_);
  auto refused = compose_new_scene(r, {&*nifti, std::nullopt});
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("a NIfTI CT has none"), std::string::npos) << refused.status().message();
  r.rtplan.clear();
  r.isocentre_ct_mm = Vector3d(0, -148, 281);
  auto setup = compose_new_scene(r, {&*nifti, std::nullopt});
  ASSERT_TRUE(setup.ok()) << setup.status().message();
  EXPECT_TRUE(setup->roi_centre_ct_mm.isApprox(Vector3d(0, -148, 281)));
  EXPECT_TRUE(setup->roi_size_mm.isApprox(Vector3d(64, 64, 40)));
  // 3 mm voxels: said, with the figure.
  ASSERT_GE(setup->warnings.size(), 2u);
  EXPECT_NE(setup->warnings[0].find("3.00 mm apart"), std::string::npos) << setup->warnings[0];
  auto scene = parse_scene(setup->yaml, r.output.string(), dir_.path());
  ASSERT_TRUE(scene.ok()) << scene.status().message() << "\n" << setup->yaml;
}

TEST_F(PatientSetup, ThePatientPositionTurnsTheRoomAboutTheIsocentre) {
  plan_.patient_position = "FFS";
  auto setup = compose();
  ASSERT_TRUE(setup.ok()) << setup.status().message();
  EXPECT_EQ(setup->patient_position, "FFS");
  auto scene = parse_scene(setup->yaml, (dir_.path() / "patient.yaml").string(), dir_.path());
  ASSERT_TRUE(scene.ok()) << scene.status().message() << "\n" << setup->yaml;
  ASSERT_TRUE(scene->nominal_T_room_from_ct.has_value()) << setup->yaml;
  const tracking::Pose& T = *scene->nominal_T_room_from_ct;
  EXPECT_TRUE((T * kIsocentre).isZero(0.02)) << (T * kIsocentre).transpose();
  // Feet first: the patient's head (+z, superior) towards the room's -z, their left (+x) to the room's -x.
  EXPECT_TRUE((T.linear() * Vector3d::UnitZ()).isApprox(-Vector3d::UnitZ(), 1e-4));
  EXPECT_TRUE((T.linear() * Vector3d::UnitX()).isApprox(-Vector3d::UnitX(), 1e-4));
  plan_.patient_position = "SITTING";
  EXPECT_NE(refusal().find("SITTING"), std::string::npos);
}

TEST_F(PatientSetup, AMaskedTargetMustHaveANameASceneCanCarry) {
  structures_.structures[1].name = "L3\nbody";
  NewSceneRequest r;
  r.target = structures_.structures[1].name;
  r.roi_mask_margin_mm = 12;
  EXPECT_NE(refusal(r).find("holds a line break or a control character"), std::string::npos);
  r.roi_mask_margin_mm.reset();
  EXPECT_TRUE(compose(r).ok()) << "without the mask the name is only a comment";
}

TEST_F(PatientSetup, ASimulationOnACoarseCtSaysItsAccuracyIsOptimistic) {
  const std::string caveat = simulated_accuracy_caveat(*ct_);
  EXPECT_NE(caveat.find("1.07 x 1.07 x 3.00 mm"), std::string::npos) << caveat;
  tracking::CtVolume fine;
  fine.geometry.size = Eigen::Vector3i(4, 4, 4);
  fine.geometry.spacing_mm = Vector3d(0.8, 0.8, 1.0);
  fine.values.assign(64, 0.f);
  EXPECT_EQ(simulated_accuracy_caveat(fine), "");
}

TEST(PatientPosition, EveryPositionIsARotationThatPutsThePatientWhereItSays) {
  for (const char* p : {"HFS", "FFS", "HFP", "FFP", "HFDL", "HFDR", "FFDL", "FFDR"}) {
    auto R = room_from_patient_rotation(p);
    ASSERT_TRUE(R.ok()) << p;
    EXPECT_TRUE((*R * R->transpose()).isIdentity(1e-12)) << p;
    EXPECT_NEAR(R->determinant(), 1, 1e-12) << p;
  }
  // Supine: posterior (+y) down (room +y); prone: posterior up; decubitus left: the left (+x) down.
  EXPECT_TRUE((*room_from_patient_rotation("HFS")).isIdentity());
  EXPECT_TRUE((*room_from_patient_rotation("HFP") * Vector3d::UnitY()).isApprox(-Vector3d::UnitY()));
  EXPECT_TRUE((*room_from_patient_rotation("FFP") * Vector3d::UnitY()).isApprox(-Vector3d::UnitY()));
  EXPECT_TRUE((*room_from_patient_rotation("HFDL") * Vector3d::UnitX()).isApprox(Vector3d::UnitY()));
  EXPECT_TRUE((*room_from_patient_rotation("HFDR") * Vector3d::UnitX()).isApprox(-Vector3d::UnitY()));
  EXPECT_TRUE((*room_from_patient_rotation("FFDL") * Vector3d::UnitX()).isApprox(Vector3d::UnitY()));
  EXPECT_TRUE((*room_from_patient_rotation("FFDL") * Vector3d::UnitZ()).isApprox(-Vector3d::UnitZ()));
  EXPECT_FALSE(room_from_patient_rotation("hfs").ok());
  EXPECT_FALSE(room_from_patient_rotation("").ok());
}

TEST_F(PatientSetup, WhatAUserOrAFileWritesNeverBecomesAKeyOfTheScene) {
  NewSceneRequest r;
  r.name = "x\nct: {path: /etc}\n# \"quoted\" \\ back";
  r.command_line = "lftrack scene new --name 'x\nsafety: {}'";
  structures_.structures[1].name = "L3: #1 'x' \"y\"";
  r.target = structures_.structures[1].name;
  auto setup = compose(r);
  ASSERT_TRUE(setup.ok()) << setup.status().message();
  auto scene = parse_scene(setup->yaml, (dir_.path() / "patient.yaml").string(), dir_.path());
  ASSERT_TRUE(scene.ok()) << scene.status().message() << "\n" << setup->yaml;
  EXPECT_EQ(scene->name, r.name);
  EXPECT_EQ(scene->ct.path, test::pancreas_dicom().lexically_normal().string());
}

}  // namespace
}  // namespace lftrack::session

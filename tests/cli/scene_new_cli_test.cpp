// `lftrack scene new` as a physicist runs it (issue 53): a new patient's scene from the CT, an RT
// Plan and an RT Structure Set (written here with DCMTK for the shipped DICOM CT), its picture, its
// refusals, foreign RT files; and, in the slow tier, a new patient from the plan to TRACK in the
// README's commands.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "cli_text.hpp"
#include "lftrack/session/dicom_registration.hpp"
#include "lftrack/session/dicom_rt.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"
#include "rt_writer.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;
namespace {

namespace fs = std::filesystem;
using Eigen::Vector3d;

Status lftrack(std::vector<std::string> args, std::string* out) {
  std::vector<std::string> argv = {test::lftrack_bin()};
  argv.insert(argv.end(), args.begin(), args.end());
  return run_process(argv, out);
}

fs::path room_file() { return fs::path(LFTRACK_SOURCE_DIR) / "scenes/room/oblique-pair.yaml"; }

// A plan with its isocentre in the lumbar CT's vertebral body (scenes/lumbar-ct.yaml) and a
// structure set contouring that body on 11 of the CT's slices (3 mm apart from 85.91 mm).
void write_rt_for_the_lumbar_ct(const fs::path& dir, const CtDicomIdentity& ct) {
  test::RtPlanSpec plan;
  plan.frame_of_reference_uid = ct.frame_of_reference_uid;
  plan.label = "L3 SBRT";
  plan.beams = {{1, "setup", Vector3d(6, 107, 183), true}};
  plan.tolerances = std::array<double, 6>{8, 8, 8, 4, 4, 4};
  test::write_rt_plan(dir / "plan.dcm", plan);
  test::RtStructSpec set;
  set.frame_of_reference_uid = ct.frame_of_reference_uid;
  set.series_uid = ct.series_uid;
  set.study_uid = ct.study_uid;
  set.structures = {{1, "BODY", {{{-100, 0, 180}, {100, 0, 180}, {100, 200, 180}, {-100, 200, 180}}}},
                    {2, "L3 body", test::lumbar_ct_vertebral_body()}};
  test::write_rt_structure_set(dir / "structures.dcm", set);
}

class SceneNewCli : public ::testing::Test {
 protected:
  void SetUp() override {
    LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
    auto ct = read_ct_dicom_identity(test::pancreas_dicom());
    ASSERT_TRUE(ct.ok()) << ct.status().message();
    ct_ = *ct;
    write_rt_for_the_lumbar_ct(dir_.path(), ct_);
  }
  std::vector<std::string> scene_new(const std::string& out, std::vector<std::string> more = {}) {
    std::vector<std::string> args = {"scene", "new", "--ct", test::pancreas_dicom().string(), "--room",
                                     room_file().string(), "-o", (dir_.path() / out).string(), "--rtplan",
                                     (dir_.path() / "plan.dcm").string(), "--rtstruct",
                                     (dir_.path() / "structures.dcm").string(), "--target", "L3 body"};
    args.insert(args.end(), more.begin(), more.end());
    return args;
  }
  test::TempDir dir_;
  CtDicomIdentity ct_;
};

TEST_F(SceneNewCli, WritesTheSceneAndItsPictureAndNeverWritesOverEither) {
  std::string out;
  ASSERT_TRUE(lftrack(scene_new("patient.yaml"), &out).ok()) << out;
  const fs::path scene = dir_.path() / "patient.yaml";
  ASSERT_TRUE(fs::exists(scene)) << out;
  EXPECT_GT(fs::file_size(dir_.path() / "patient-setup.png"), 10000u);
  EXPECT_NE(out.find("isocentre   (6.00, 107.00, 183.00) mm (CT frame), from plan 'L3 SBRT'"), std::string::npos) << out;
  EXPECT_NE(out.find("about target 'L3 body'"), std::string::npos) << out;
  EXPECT_NE(out.find("the CT's slices are 3.00 mm apart"), std::string::npos) << "the CT's fitness said: " << out;
  EXPECT_NE(out.find("lftrack commission --scene"), std::string::npos) << out;
  // It loads as any scene: `info` reads it, the isocentre on the room's.
  ASSERT_TRUE(lftrack({"info", "--scene", scene.string()}, &out).ok()) << out;
  EXPECT_NE(out.find("registration    origin (6.00, 107.00, 183.00) mm (CT) = (0.00, 0.00, 0.00) mm (room)"),
            std::string::npos)
      << out;
  EXPECT_NE(out.find("envelope        +-8.0 mm, +-4.0 deg"), std::string::npos) << "the plan's tolerances: " << out;
  // A second run refuses, and the first scene is as it was.
  const std::string first = test::contents(scene);
  EXPECT_FALSE(lftrack(scene_new("patient.yaml"), &out).ok());
  EXPECT_NE(out.find("never written over"), std::string::npos) << out;
  EXPECT_EQ(test::contents(scene), first);
  // A picture already there (an earlier scene's) is never replaced: refused, nothing written.
  std::ofstream(dir_.path() / "second-setup.png") << "an earlier picture";
  EXPECT_FALSE(lftrack(scene_new("second.yaml"), &out).ok());
  EXPECT_NE(out.find("second-setup.png: already there"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(dir_.path() / "second.yaml"));
  EXPECT_EQ(test::contents(dir_.path() / "second-setup.png"), "an earlier picture");
  for (const auto& entry : fs::directory_iterator(dir_.path()))
    EXPECT_EQ(entry.path().filename().string().rfind(".lftrack-scene-new-", 0), std::string::npos)
        << "a temporary file left: " << entry.path();
  // Into the CT's DICOM folder (where every file is read as a slice): refused.
  std::vector<std::string> into_ct = scene_new("x.yaml");
  into_ct[3] = dir_.path().string();
  EXPECT_FALSE(lftrack(into_ct, &out).ok());
  EXPECT_NE(out.find("in the CT's DICOM folder"), std::string::npos) << out;
  // Not a .yaml, or in no folder: refused before anything is read.
  EXPECT_FALSE(lftrack(scene_new("patient.txt"), &out).ok());
  EXPECT_NE(out.find("a scene is a .yaml file"), std::string::npos) << out;
  EXPECT_FALSE(lftrack(scene_new("none/patient.yaml"), &out).ok());
  EXPECT_NE(out.find("no folder"), std::string::npos) << out;
}

TEST_F(SceneNewCli, TheMaskIsWrittenShownAndRefusedWhereTheRoomsPlansCannotUseIt) {
  std::string out;
  ASSERT_TRUE(lftrack(scene_new("masked.yaml", {"--roi-mask-mm", "12.345"}), &out).ok()) << out;
  const std::string scene = test::contents(dir_.path() / "masked.yaml");
  EXPECT_NE(scene.find("margin_mm: 12.345\n"), std::string::npos) << "the margin as asked: " << scene;
  ASSERT_TRUE(lftrack({"info", "--scene", (dir_.path() / "masked.yaml").string()}, &out).ok()) << out;
  EXPECT_NE(out.find("roi mask        target 'L3 body' of "), std::string::npos) << out;
  // A margin within the envelope (the plan's 8 mm) is said.
  ASSERT_TRUE(lftrack(scene_new("narrow.yaml", {"--roi-mask-mm", "5"}), &out).ok()) << out;
  EXPECT_NE(out.find("roi.mask's margin (5 mm) does not exceed the envelope (8 mm)"), std::string::npos) << out;
  // A 2 mm target with 2 mm around it: 21 x 21 pixels, which the room's warm tracking plan bins
  // 8 x 8 into 6: refused before anything is written, naming the plan.
  test::RtStructSpec tiny;
  tiny.frame_of_reference_uid = ct_.frame_of_reference_uid;
  tiny.series_uid = ct_.series_uid;
  tiny.study_uid = ct_.study_uid;
  tiny.structures = {{1, "tiny", {{{5, 106, 181.91}, {7, 106, 181.91}, {7, 108, 181.91}, {5, 108, 181.91}}}}};
  test::write_rt_structure_set(dir_.path() / "tiny.dcm", tiny);
  std::vector<std::string> args = scene_new("tiny.yaml", {"--roi-mask-mm", "2"});
  args[11] = (dir_.path() / "tiny.dcm").string();
  args[13] = "tiny";
  EXPECT_FALSE(lftrack(args, &out).ok());
  EXPECT_NE(out.find("roi.mask: the room's loop.track_plan 'warm' cannot register what the mask keeps"),
            std::string::npos)
      << out;
  EXPECT_FALSE(fs::exists(dir_.path() / "tiny.yaml"));
}

TEST_F(SceneNewCli, ListsTheStructuresAndRefusesAnUnknownTargetListingThem) {
  std::string out;
  ASSERT_TRUE(lftrack({"scene", "new", "--rtstruct", (dir_.path() / "structures.dcm").string(), "--list-structures"},
                      &out)
                  .ok())
      << out;
  EXPECT_NE(out.find("'BODY'"), std::string::npos) << out;
  const auto line = out.find("'L3 body'");
  ASSERT_NE(line, std::string::npos) << out;
  EXPECT_NE(out.find("11 contours (11 closed planar), 528 points", line), std::string::npos) << out;
  std::vector<std::string> args = scene_new("patient.yaml");
  args.back() = "L4 body";
  EXPECT_FALSE(lftrack(args, &out).ok());
  EXPECT_NE(out.find("no structure named 'L4 body'"), std::string::npos) << out;
  EXPECT_FALSE(fs::exists(dir_.path() / "patient.yaml"));
}

TEST_F(SceneNewCli, ConflictingOrAbsurdOptionsAreUsageErrors) {
  const std::vector<std::vector<std::string>> cases = {
      {"--isocentre", "1,2,3"},                 // and --rtplan
      {"--roi-margin-mm", "-1"},
      {"--roi-margin-mm", "nan"},
      {"--roi-margin-mm", "1e12"},
  };
  std::string out;
  for (const auto& extra : cases) {
    const Status s = lftrack(scene_new("patient.yaml", extra), &out);
    EXPECT_FALSE(s.ok()) << extra[0] << " " << extra[1];
    EXPECT_NE(s.message().find("(status 512)"), std::string::npos) << s.message() << "\n" << out;
  }
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {"scene", "new", "--beam", "1"},
           {"scene", "new", "--target", "x"},
           {"scene", "new", "--list-structures"},
           {"scene", "new", "--ct", "x", "--isocentre", "1,2"},
           {"scene", "new", "--ct", "x", "--isocentre", "inf,0,0"},
           {"scene", "new", "--room", "r.yaml", "-o", "x.yaml", "--isocentre", "1,2,3"},  // no --ct
           {"scene", "new", "--ct", "x", "-o", "x.yaml", "--isocentre", "1,2,3"},        // no --room
           {"scene", "new", "--rtstruct", "s.dcm", "--target", "t", "--ct", "x", "-o", "y.yaml"},  // no --room
           {"scene", "new", "--ct", "x", "--room", "r.yaml", "-o", "x.yaml", "--roi-mask-mm", "5"},  // no --rtstruct
           {"scene"}}) {
    const Status s = lftrack(args, &out);
    EXPECT_NE(s.message().find("(status 512)"), std::string::npos) << args.back() << ": " << s.message() << "\n" << out;
  }
  EXPECT_FALSE(fs::exists(dir_.path() / "patient.yaml"));
}

// Debian's python3-pydicom ships RT objects of another patient: a user may hand them over.
TEST_F(SceneNewCli, ForeignRtFilesAreRefusedWithTheReasonNeverACrash) {
  const fs::path pydicom = "/usr/lib/python3/dist-packages/pydicom/data/test_files";
  if (!fs::exists(pydicom / "rtstruct.dcm")) GTEST_SKIP() << "python3-pydicom's test files are not installed";
  std::string out;
  std::vector<std::string> args = scene_new("patient.yaml");
  args[9] = (pydicom / "rtplan.dcm").string();
  Status s = lftrack(args, &out);
  EXPECT_FALSE(s.ok());
  EXPECT_EQ(s.message().find("signal"), std::string::npos) << s.message();
  EXPECT_NE(out.find("rtplan.dcm: the plan has no Frame of Reference UID"), std::string::npos) << out;
  args = scene_new("patient.yaml");
  args[11] = (pydicom / "rtstruct.dcm").string();
  s = lftrack(args, &out);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(out.find("the structure set is in Frame of Reference"), std::string::npos) << out;
  EXPECT_NE(out.find(ct_.frame_of_reference_uid), std::string::npos) << "both UIDs named: " << out;
  args[11] = (pydicom / "rtdose.dcm").string();
  s = lftrack(args, &out);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(out.find("rtdose.dcm: not an RT Structure Set"), std::string::npos) << out;
  EXPECT_EQ(s.message().find("signal"), std::string::npos) << s.message();
  EXPECT_FALSE(fs::exists(dir_.path() / "patient.yaml"));
}

// The README's "a new patient": scene new, precompute, commission, register --sim, sim. The loop
// aligns and tracks the new patient; the residual's p95 on the ideal room is within 0.5 mm.
void walk_to_track(const fs::path& dir, const std::vector<std::string>& scene_new_args, const fs::path& scene) {
  std::string out;
  ASSERT_TRUE(lftrack(scene_new_args, &out).ok()) << out;
  const std::string lf = (dir / "lf").string();
  ASSERT_TRUE(lftrack({"precompute", "--scene", scene.string(), "-o", lf}, &out).ok()) << out;
  // Before it is commissioned, the loop refuses the new patient, saying how.
  EXPECT_FALSE(lftrack({"-q", "register", "--scene", scene.string(), "--sim", "--lf-dir", lf}, &out).ok());
  EXPECT_NE(out.find("lftrack commission --scene"), std::string::npos) << out;
  ASSERT_TRUE(lftrack({"-q", "commission", "--scene", scene.string(), "--lf-dir", lf, "--good", "10", "--bad", "70",
                       "--report", (dir / "report").string(), "--max-false-rejects", "0.5"},
                      &out)
                  .ok())
      << out;
  ASSERT_TRUE(lftrack({"-q", "register", "--scene", scene.string(), "--sim", "--lf-dir", lf}, &out).ok()) << out;
  EXPECT_NE(out.find("verdict: ACCEPTED"), std::string::npos) << out;
  ASSERT_TRUE(lftrack({"sim", "--scene", scene.string(), "--fast", "--cycles", "100", "--lf-dir", lf, "--journal", ""},
                      &out)
                  .ok())
      << out;
  EXPECT_NE(out.find("ALIGN -> TRACK  aligned"), std::string::npos) << out;
  const auto at = out.find("residual (true, TRACK cycles): mean ");
  ASSERT_NE(at, std::string::npos) << out;
  double mean = 0, p95 = 0;
  ASSERT_EQ(std::sscanf(out.c_str() + at, "residual (true, TRACK cycles): mean %lf mm, p95 %lf mm", &mean, &p95), 2);
  EXPECT_LE(p95, 0.5) << out;
  EXPECT_NE(out.find("holds 0, faults 0"), std::string::npos) << out;
  // Both CTs have 3 mm slices: the figures are said to be optimistic.
  EXPECT_NE(out.find("note: the CT's voxels are"), std::string::npos) << out;
}

TEST_F(SceneNewCli, ANewPatientFromThePlanTracks) {
  walk_to_track(dir_.path(), scene_new("patient.yaml"), dir_.path() / "patient.yaml");
}

TEST(SceneNewNifti, TheExampleCtWithAGivenIsocentreTracks) {
  LFTRACK_REQUIRE_SHARED_DATA(test::totalseg_example());
  test::TempDir dir;
  // A lumbar vertebral body of TotalSegmentator's example (read off the set-up picture's slices).
  walk_to_track(dir.path(),
                {"scene", "new", "--ct", test::totalseg_example().string(), "--room", room_file().string(),
                 "--isocentre", "0,-148,281", "-o", (dir.path() / "example.yaml").string()},
                dir.path() / "example.yaml");
}

}  // namespace
}  // namespace lftrack::session

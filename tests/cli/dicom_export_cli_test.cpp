// Registrations exported as DICOM (issue 22), as a user runs it: the built-in phantom written as a
// DICOM CT series, `lftrack register --sim --dicom-sro` on it, and `lftrack journal export
// --dicom-sro` of a journal's applied cycle; each file read back with DCMTK (the matrix, the CT's
// Frame of Reference and series). Refusals: an existing file, a CT without DICOM identity, a cycle
// the gate did not apply.

#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "dicom_writer.hpp"
#include "lftrack/loop/journal.hpp"
#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/loop/tracking_states.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_fingerprint.hpp"
#include "lftrack/studies/plastimatch_peer.hpp"  // run_process
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::session {

using studies::run_process;

using loop::GateDecision;
using loop::JournalOptions;
using loop::JournalRecord;
using loop::JournalWriter;
using loop::TrackingState;
namespace {

namespace fs = std::filesystem;

constexpr const char* kFrameOfReference = "1.2.826.0.1.3680043.2.1125.55";

// The built-in phantom as a DICOM CT series (HU rounded to integers) and a scene on it: the
// built-in scene's detectors and a coarse light field, with its ROI and registration origin named.
class DicomExportCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = std::make_unique<test::TempDir>();
    tracking::ThreadPool pool(2);
    auto builtin = load_scene(kBuiltinPhantom);
    ASSERT_TRUE(builtin.ok());
    auto phantom = prepare_scene(*builtin, "", &pool);
    ASSERT_TRUE(phantom.ok()) << phantom.status().message();
    const tracking::CtVolume& ct = *phantom->ct;
    const tracking::VolumeGeometry& g = ct.geometry;
    test::SyntheticSlice base;
    base.series_uid = "1.2.826.0.1.3680043.2.1125.44";
    base.frame_of_reference_uid = kFrameOfReference;
    base.rows = g.size.y();
    base.cols = g.size.x();
    base.row_cosine = g.direction.col(0);
    base.col_cosine = g.direction.col(1);
    base.pixel_spacing_mm = {g.spacing_mm.y(), g.spacing_mm.x()};
    base.intercept = 0;
    fs::create_directories(dicom_dir());
    for (int k = 0; k < g.size.z(); ++k) {
      test::SyntheticSlice s = base;
      s.position_mm = g.origin_mm + g.direction.col(2) * (k * g.spacing_mm.z());
      s.stored.resize(std::size_t(g.size.x()) * std::size_t(g.size.y()));
      for (int j = 0; j < g.size.y(); ++j)
        for (int i = 0; i < g.size.x(); ++i)
          s.stored[std::size_t(j) * std::size_t(g.size.x()) + std::size_t(i)] =
              static_cast<std::int16_t>(std::lround(std::clamp(ct.at(i, j, k), -1024.0f, 3071.0f)));
      char name[32];
      std::snprintf(name, sizeof name, "ct%04d.dcm", k);
      ASSERT_TRUE(test::write_synthetic_slice(dicom_dir() / name, s));
    }
    std::string scene = *builtin_scene_text(kBuiltinPhantom);
    auto swap = [&](const std::string& from, const std::string& to) {
      const auto at = scene.find(from);
      ASSERT_NE(at, std::string::npos) << from;
      scene.replace(at, from.size(), to);
    };
    std::ostringstream ct_and_roi;
    ct_and_roi.precision(17);
    const Eigen::Vector3d roi = phantom->roi_centre_ct_mm, origin = phantom->registration_origin_ct_mm;
    ct_and_roi << "ct:\n  path: " << dicom_dir().string() << "\nroi:\n  centre_mm: [" << roi.x() << ", " << roi.y()
               << ", " << roi.z() << "]\n  size_mm: [64, 64, 40]\nregistration_origin_mm: [" << origin.x() << ", "
               << origin.y() << ", " << origin.z() << "]\n";
    swap("ct:\n  path: builtin:phantom\n  seed: 1\n", "");
    const auto roi_at = scene.find("roi:");
    scene.erase(roi_at, scene.find("detectors:") - roi_at);
    scene.insert(roi_at, ct_and_roi.str());
    swap("    resolution: [16, 16, 128, 128]\n", "    resolution: [8, 8, 96, 96]\n");
    std::ofstream(scene_file()) << scene;
  }
  static void TearDownTestSuite() { dir_.reset(); }
  static fs::path dicom_dir() { return dir_->path() / "ct"; }
  static fs::path scene_file() { return dir_->path() / "phantom-dicom.yaml"; }

  // The object's CT registration item: its Frame of Reference and matrix.
  static std::pair<std::string, Eigen::Matrix4d> read_registration(const fs::path& file) {
    DcmFileFormat format;
    EXPECT_TRUE(format.loadFile(file.c_str()).good()) << file;
    DcmDataset* ds = format.getDataset();
    DcmItem* ct = nullptr;
    ds->findAndGetSequenceItem(DCM_RegistrationSequence, ct, 1);
    EXPECT_NE(ct, nullptr);
    if (ct == nullptr) return {};
    OFString frame;
    ct->findAndGetOFString(DCM_FrameOfReferenceUID, frame);
    DcmItem *registration = nullptr, *matrix = nullptr;
    ct->findAndGetSequenceItem(DCM_MatrixRegistrationSequence, registration, 0);
    registration->findAndGetSequenceItem(DCM_MatrixSequence, matrix, 0);
    Eigen::Matrix4d m;
    for (unsigned long i = 0; i < 16; ++i) {
      Float64 v = 0;
      matrix->findAndGetFloat64(DCM_FrameOfReferenceTransformationMatrix, v, i);
      m(int(i / 4), int(i % 4)) = v;
    }
    return {frame.c_str(), m};
  }

  static inline std::unique_ptr<test::TempDir> dir_;
};

TEST_F(DicomExportCli, RegisterWritesTheAcceptedResultAgainstTheCtsFrameOfReference) {
  const fs::path out = dir_->path() / "register.dcm";
  std::string said;
  const std::vector<std::string> argv{LFTRACK_BIN_PATH, "-q",      "register", "--scene", scene_file().string(),
                                      "--sim",          "--gold",  "1,-0.5,0.5,0.5,0,-0.5", "--lf-dir",
                                      (dir_->path() / "lf").string(), "--json", "--dicom-sro", out.string()};
  ASSERT_TRUE(run_process(argv, &said).ok()) << said;
  const auto j = nlohmann::json::parse(said.substr(said.find('{')));
  EXPECT_TRUE(j["verdict"]["ok"].get<bool>()) << said;
  ASSERT_TRUE(fs::exists(out)) << said;
  const auto [frame, m] = read_registration(out);
  EXPECT_EQ(frame, kFrameOfReference);
  const auto t = j["T_room_from_ct"]["translation_mm"];
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(m(i, 3), t[std::size_t(i)].get<double>(), 1e-6) << i;
  EXPECT_NEAR((m.topLeftCorner<3, 3>().determinant()), 1.0, 1e-9);
  // Again into the same file: refused before any work, and the file kept.
  const auto written = fs::last_write_time(out);
  EXPECT_FALSE(run_process(argv, &said).ok());
  EXPECT_NE(said.find("exists"), std::string::npos) << said;
  EXPECT_EQ(fs::last_write_time(out), written);
  // The built-in phantom has no DICOM identity: refused with the reason.
  EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "register", "--sim", "--dicom-sro",
                            (dir_->path() / "phantom.dcm").string()},
                           &said)
                   .ok());
  EXPECT_NE(said.find("built-in phantom"), std::string::npos) << said;
  EXPECT_FALSE(fs::exists(dir_->path() / "phantom.dcm"));
}

TEST_F(DicomExportCli, JournalExportWritesAnAppliedCyclesRegistration) {
  tracking::ThreadPool pool(1);
  auto scene = load_scene(scene_file().string());
  ASSERT_TRUE(scene.ok());
  // Five cycles: 3 held by the gate; 1 applied by the gate but ended in HOLD (the couch refused).
  const auto write_journal = [](const fs::path& file, const std::array<std::uint8_t, 16>& fingerprint) {
    JournalOptions options;
    options.scene_fingerprint = fingerprint;
    auto writer = JournalWriter::open(file, options);
    ASSERT_TRUE(writer.ok());
    for (std::uint64_t c = 0; c < 5; ++c) {
      JournalRecord r;
      r.cycle = c;
      r.gate_decision = static_cast<std::uint8_t>(c == 3 ? GateDecision::kHold : GateDecision::kApply);
      r.state = static_cast<std::uint8_t>(c == 1 || c == 3 ? TrackingState::kHold : TrackingState::kTrack);
      r.pose_delta[0] = 0.5 * double(c);
      r.pose_delta[4] = 0.01 * double(c);
      r.similarity[0] = 0.4;
      (*writer)->append(r);
    }
    ASSERT_TRUE((*writer)->close().ok());
  };
  const fs::path journal = dir_->path() / "run.lfj";
  write_journal(journal, scene_fingerprint(*scene));
  auto prepared = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(prepared.ok());
  auto expected = [&](std::uint64_t c) {
    tracking::Vector6d d = tracking::Vector6d::Zero();
    d(0) = 0.5 * double(c);
    d(4) = 0.01 * double(c);
    return tracking::apply_delta(prepared->nominal_T_room_from_ct, tracking::PoseDelta::from_vector(d),
                                 prepared->registration_origin_room_mm())
        .matrix();
  };
  std::string said;
  // The last applied cycle by default (4), or the one named.
  const fs::path last = dir_->path() / "last.dcm";
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--dicom-sro",
                           last.string(), "--scene", scene_file().string()},
                          &said)
                  .ok())
      << said;
  EXPECT_NE(said.find("cycle 4"), std::string::npos) << said;
  auto [frame, m] = read_registration(last);
  EXPECT_EQ(frame, kFrameOfReference);
  EXPECT_LT((m - expected(4)).cwiseAbs().maxCoeff(), 1e-9);
  const fs::path two = dir_->path() / "two.dcm";
  ASSERT_TRUE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--dicom-sro", two.string(),
                           "--scene", scene_file().string(), "--cycle", "2"},
                          &said)
                  .ok())
      << said;
  EXPECT_LT((read_registration(two).second - expected(2)).cwiseAbs().maxCoeff(), 1e-9);
  // A cycle the gate held, a cycle not in the journal, an existing file, --cycle without
  // --dicom-sro: refused, nothing written.
  const fs::path held = dir_->path() / "held.dcm";
  EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--dicom-sro",
                            held.string(), "--scene", scene_file().string(), "--cycle", "3"},
                           &said)
                   .ok());
  EXPECT_NE(said.find("not applied"), std::string::npos) << said;
  EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--dicom-sro",
                            held.string(), "--scene", scene_file().string(), "--cycle", "1"},
                           &said)
                   .ok());
  EXPECT_NE(said.find("ended in HOLD"), std::string::npos) << said;
  // A journal of another scene (the built-in phantom's room and CT), one that does not record its
  // scene, and a damaged one: refused (an outside probe exported the phantom's poses as a
  // registration of a patient's CT).
  const fs::path other = dir_->path() / "other-scene.lfj", unrecorded = dir_->path() / "unrecorded.lfj",
                 damaged = dir_->path() / "damaged.lfj";
  auto builtin = load_scene(kBuiltinPhantom);
  ASSERT_TRUE(builtin.ok());
  write_journal(other, scene_fingerprint(*builtin));
  write_journal(unrecorded, {});
  fs::copy_file(journal, damaged);
  {
    std::fstream f(damaged, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(32 + 8 + 20);  // inside the first record's payload: its CRC no longer matches
    f.put('\x55');
  }
  for (const auto& [file, why] : std::vector<std::pair<fs::path, std::string>>{
           {other, "another room or CT"}, {unrecorded, "does not record its scene"}, {damaged, "damaged"}}) {
    EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", file.string(), "--dicom-sro", held.string(),
                              "--scene", scene_file().string()},
                             &said)
                     .ok())
        << file;
    EXPECT_NE(said.find(why), std::string::npos) << said;
  }
  // A link at the target is never written through; a missing folder is refused before anything.
  const fs::path victim = dir_->path() / "victim.txt", link = dir_->path() / "link.dcm";
  std::ofstream(victim) << "kept\n";
  fs::create_symlink(victim, link);
  EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--dicom-sro",
                            link.string(), "--scene", scene_file().string()},
                           &said)
                   .ok());
  EXPECT_EQ(fs::file_size(victim), 5u) << "written through the link";
  EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--dicom-sro",
                            (dir_->path() / "no-such-folder" / "x.dcm").string(), "--scene", scene_file().string()},
                           &said)
                   .ok());
  EXPECT_NE(said.find("does not exist"), std::string::npos) << said;
  for (const auto& entry : fs::directory_iterator(dir_->path()))
    EXPECT_EQ(entry.path().filename().string().find(".partial"), std::string::npos) << entry.path() << " left behind";
  EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--dicom-sro",
                            held.string(), "--scene", scene_file().string(), "--cycle", "99"},
                           &said)
                   .ok());
  EXPECT_FALSE(fs::exists(held));
  EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--dicom-sro",
                            last.string(), "--scene", scene_file().string()},
                           &said)
                   .ok());
  EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--cycle", "2"}, &said).ok());
  for (const char* bad : {"-1", "nan", "1e12x", ""})
    EXPECT_FALSE(run_process({LFTRACK_BIN_PATH, "-q", "journal", "export", journal.string(), "--dicom-sro",
                              held.string(), "--scene", scene_file().string(), "--cycle", bad},
                             &said)
                     .ok())
        << bad;
  EXPECT_FALSE(fs::exists(held));
}

}  // namespace
}  // namespace lftrack::session

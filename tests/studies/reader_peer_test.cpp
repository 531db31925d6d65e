// Cross-implementation tests of the CT readers against the peer: plastimatch converts the same
// DICOM series and NIfTI files; geometry and every voxel must agree with ours. (Moved from the
// readers' unit tests, which no longer link the studies.)

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "lftrack/studies/plastimatch_peer.hpp"
#include "lftrack/tracking/volume_io.hpp"
#include "metaimage_reader.hpp"
#include "test_data.hpp"

namespace lftrack::tracking {
namespace {

namespace fs = std::filesystem;
using test::TempDir;

// Cross-implementation: plastimatch (ITK's GDCM-based series reader) converts the same series to
// MetaImage; geometry and every voxel must agree with ours.
TEST(DicomReaderRealData, AgreesWithPlastimatchConvert) {
  LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
  LFTRACK_REQUIRE_PLASTIMATCH();
  TempDir dir;
  const fs::path mha = dir.path() / "peer.mha";
  std::string log;
  ASSERT_TRUE(studies::run_process({"plastimatch", "convert", "--input", test::pancreas_dicom().string(),
                                    "--output-img", mha.string(), "--output-type", "float"},
                                   &log)
                  .ok())
      << log;
  auto ours = read_dicom_series(test::pancreas_dicom());
  ASSERT_TRUE(ours.ok());
  auto peer = test::read_metaimage_for_test(mha);
  ASSERT_TRUE(peer.ok()) << peer.status().message();
  EXPECT_EQ(peer->geometry.size, ours->geometry.size);
  EXPECT_LT((peer->geometry.origin_mm - ours->geometry.origin_mm).norm(), 1e-3);
  EXPECT_LT((peer->geometry.spacing_mm - ours->geometry.spacing_mm).norm(), 1e-3);
  EXPECT_TRUE(peer->geometry.direction.isApprox(ours->geometry.direction, 1e-6));
  double max_diff = 0;
  for (std::size_t i = 0; i < ours->values.size(); ++i)
    max_diff = std::max(max_diff, double(std::abs(ours->values[i] - peer->values[i])));
  EXPECT_LT(max_diff, 0.01) << "HU differ between lftrack and plastimatch";
}

// Both TotalSegmentator files, whose affines differ (one flips x and y), must land in LPS exactly
// where ITK (through plastimatch) puts them: same geometry, same voxels.
class NiftiRealData : public ::testing::TestWithParam<const char*> {};

TEST_P(NiftiRealData, AgreesWithPlastimatchConvert) {
  const fs::path file = test::shared_data_dir() / "ct/totalseg" / GetParam();
  LFTRACK_REQUIRE_SHARED_DATA(file);
  LFTRACK_REQUIRE_PLASTIMATCH();
  auto ours = read_nifti(file);
  ASSERT_TRUE(ours.ok()) << ours.status().message();
  TempDir dir;
  const fs::path mha = dir.path() / "peer.mha";
  std::string log;
  ASSERT_TRUE(studies::run_process({"plastimatch", "convert", "--input", file.string(), "--output-img",
                                    mha.string(), "--output-type", "float"},
                                   &log)
                  .ok())
      << log;
  auto peer = test::read_metaimage_for_test(mha);
  ASSERT_TRUE(peer.ok()) << peer.status().message();
  ASSERT_EQ(peer->geometry.size, ours->geometry.size);
  // Compare where each voxel centre lies (the grids may be described with different axis signs
  // only if the voxel order matches, so compare corner voxels' positions and all values).
  for (const Eigen::Vector3d& idx :
       {Eigen::Vector3d(0, 0, 0),
        Eigen::Vector3d(ours->geometry.size.cast<double>() - Eigen::Vector3d::Ones())}) {
    const Eigen::Vector3d a = ours->geometry.ct_from_index() * idx;
    const Eigen::Vector3d b = peer->geometry.ct_from_index() * idx;
    EXPECT_LT((a - b).norm(), 1e-3) << "voxel " << idx.transpose() << ": ours " << a.transpose()
                                    << ", plastimatch " << b.transpose();
  }
  double max_diff = 0;
  for (std::size_t i = 0; i < ours->values.size(); ++i)
    max_diff = std::max(max_diff, double(std::abs(ours->values[i] - peer->values[i])));
  EXPECT_LT(max_diff, 0.01);
}

INSTANTIATE_TEST_SUITE_P(TotalSegmentator, NiftiRealData,
                         ::testing::Values("example_ct.nii.gz", "aorta_ct_cropped.nii.gz"),
                         [](const auto& p) {
                           return std::string(p.param).substr(0, std::string(p.param).find('.'));
                         });

}  // namespace
}  // namespace lftrack::tracking

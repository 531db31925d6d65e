#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "dicom_writer.hpp"
#include "lftrack/tracking/volume_io.hpp"
#include "test_data.hpp"

namespace lftrack::tracking {
namespace {

namespace fs = std::filesystem;
using test::SyntheticSlice;
using test::TempDir;

TEST(DicomReader, ReadsSyntheticSeriesInPositionOrder) {
  TempDir dir;
  SyntheticSlice base;
  base.slope = 2.0;
  base.intercept = -1024;
  test::write_synthetic_series(dir.path(), base, 5, 2.5);
  auto ct = read_dicom_series(dir.path());
  ASSERT_TRUE(ct.ok()) << ct.status().message();
  const VolumeGeometry& g = ct->geometry;
  EXPECT_EQ(g.size, Eigen::Vector3i(6, 8, 5));
  EXPECT_NEAR(g.spacing_mm.x(), 0.75, 1e-9);  // between columns
  EXPECT_NEAR(g.spacing_mm.y(), 0.5, 1e-9);   // between rows
  EXPECT_NEAR(g.spacing_mm.z(), 2.5, 1e-9);
  EXPECT_TRUE(g.origin_mm.isApprox(Eigen::Vector3d(-10, -20, 0)));
  // Slice k (by position) was written with seed k, into a file whose name sorts in reverse.
  for (int k = 0; k < 5; ++k) {
    EXPECT_FLOAT_EQ(ct->at(2, 3, k), float(2.0 * test::pattern_value(k, 3, 2) - 1024)) << "slice " << k;
  }
}

TEST(DicomReader, PlacesObliqueSeriesInTheCtFrame) {
  TempDir dir;
  SyntheticSlice base;
  const double a = 0.3;
  base.row_cosine = {std::cos(a), std::sin(a), 0};
  base.col_cosine = {0, 0, -1};  // coronal-like slices
  test::write_synthetic_series(dir.path(), base, 3, 1.25);
  auto ct = read_dicom_series(dir.path());
  ASSERT_TRUE(ct.ok()) << ct.status().message();
  const Eigen::Vector3d normal = base.row_cosine.cross(base.col_cosine);
  EXPECT_TRUE(ct->geometry.direction.col(2).isApprox(normal, 1e-6));
  // Voxel (i, j, k) centre = IPP_k + i * colspacing * row_cosine + j * rowspacing * col_cosine.
  const Eigen::Vector3d p = ct->geometry.ct_from_index() * Eigen::Vector3d(4, 2, 1);
  const Eigen::Vector3d expected =
      base.position_mm + 1.25 * normal + 4 * 0.75 * base.row_cosine + 2 * 0.5 * base.col_cosine;
  EXPECT_LT((p - expected).norm(), 1e-5);
}

// One bad-input class per case: the reader must fail with a message naming the problem.
struct BadSeriesCase {
  const char* name;
  const char* expected_message;
  void (*make)(const fs::path& folder);
};

SyntheticSlice slice_at(double z, int seed = 0) {
  SyntheticSlice s;
  s.position_mm.z() = z;
  s.seed = seed;
  return s;
}

void write(const fs::path& folder, const char* name, const SyntheticSlice& s) {
  ASSERT_TRUE(test::write_synthetic_slice(folder / name, s));
}

const BadSeriesCase kBadSeries[] = {
    {"MixedSeries", "mixed series",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       SyntheticSlice b = slice_at(1);
       b.series_uid = "1.2.3.4.5";
       write(d, "b.dcm", b);
     }},
    {"MixedSizes", "mixed sizes",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       SyntheticSlice b = slice_at(1);
       b.rows = 9;
       write(d, "b.dcm", b);
     }},
    {"MixedOrientations", "mixed orientations",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       SyntheticSlice b = slice_at(1);
       b.row_cosine = {0.8, 0.6, 0};
       b.col_cosine = {-0.6, 0.8, 0};
       write(d, "b.dcm", b);
     }},
    {"UnevenSpacing", "uneven slice spacing",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       write(d, "b.dcm", slice_at(1));
       write(d, "c.dcm", slice_at(2));
       write(d, "d.dcm", slice_at(3.4));
     }},
    {"DuplicatedPosition", "duplicated slice position",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       write(d, "b.dcm", slice_at(1));
       write(d, "c.dcm", slice_at(1, 5));
       write(d, "d.dcm", slice_at(2));
     }},
    {"MissingSlice", "missing slice",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       write(d, "b.dcm", slice_at(1));
       write(d, "c.dcm", slice_at(2));
       write(d, "e.dcm", slice_at(4));
       write(d, "f.dcm", slice_at(5));
     }},
    {"NonCtModality", "modality is 'MR'",
     [](const fs::path& d) {
       SyntheticSlice a = slice_at(0);
       a.modality = "MR";
       write(d, "a.dcm", a);
       write(d, "b.dcm", slice_at(1));
     }},
    {"UndecodableTransferSyntax", "cannot be decoded",
     [](const fs::path& d) {
       SyntheticSlice a = slice_at(0);
       a.mpeg2_pixel_data = true;
       write(d, "a.dcm", a);
       write(d, "b.dcm", slice_at(1));
     }},
    {"TruncatedFile", "not a readable DICOM",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       write(d, "b.dcm", slice_at(1));
       fs::resize_file(d / "b.dcm", fs::file_size(d / "b.dcm") / 2);
     }},
    {"TruncatedInsideMetaHeader", "not a readable DICOM",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       write(d, "b.dcm", slice_at(1));
       fs::resize_file(d / "b.dcm", 200);  // Debian's GDCM aborts on this one
     }},
    {"TruncatedInsidePixelData", "not a readable DICOM",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       write(d, "b.dcm", slice_at(1));
       fs::resize_file(d / "b.dcm", fs::file_size(d / "b.dcm") - 7);  // GDCM only warns
     }},
    {"NotDicom", "not a readable DICOM",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       std::ofstream(d / "notes.txt") << "this is not a DICOM file\n";
     }},
    // A rescale no CT has, and values no rescale makes plausible: refused with the slice named.
    {"HugeRescaleSlope", "b.dcm: RescaleSlope 1e+38 is not in [0.001, 1000]",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       SyntheticSlice b = slice_at(1);
       b.slope = 1e38;
       write(d, "b.dcm", b);
     }},
    {"ZeroRescaleSlope", "RescaleSlope 0 is not in [0.001, 1000]",
     [](const fs::path& d) {
       SyntheticSlice a = slice_at(0);
       a.slope = 0;
       write(d, "a.dcm", a);
       write(d, "b.dcm", slice_at(1));
     }},
    {"NegativeRescaleSlope", "RescaleSlope -1 is not in [0.001, 1000]",
     [](const fs::path& d) {
       SyntheticSlice a = slice_at(0);
       a.slope = -1;
       write(d, "a.dcm", a);
       write(d, "b.dcm", slice_at(1));
     }},
    {"HugeRescaleIntercept", "RescaleIntercept 1e+20 is beyond +-100000",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       SyntheticSlice b = slice_at(1);
       b.intercept = 1e20;
       write(d, "b.dcm", b);
     }},
    {"NonNumericRescaleSlope", "RescaleSlope is not 1 finite decimal numbers: '1abc'",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       SyntheticSlice b = slice_at(1);
       b.slope_text = "1abc";
       write(d, "b.dcm", b);
     }},
    {"MissingRescaleIntercept", "b.dcm: missing RescaleIntercept",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       SyntheticSlice b = slice_at(1);
       b.omit_intercept = true;
       write(d, "b.dcm", b);
     }},
    {"FarAwayOrigin", "is more than 10000 mm from the scanner's origin",
     [](const fs::path& d) {
       SyntheticSlice a = slice_at(0), b = slice_at(1);
       a.position_mm.x() = b.position_mm.x() = 1e30;
       write(d, "a.dcm", a);
       write(d, "b.dcm", b);
     }},
    {"ValueBeyondBitsStored", "pixel (row 2, column 3): stored value 3000 does not fit BitsStored 12 (signed)",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       SyntheticSlice b = slice_at(1);
       b.bits_stored = 12;
       b.stored.assign(std::size_t(b.rows * b.cols), 100);
       b.stored[std::size_t(2 * b.cols + 3)] = 3000;  // 12 bits signed hold -2048..2047
       write(d, "b.dcm", b);
     }},
    {"ImplausibleHu", "pixel (row 0, column 0): stored value 1000 x RescaleSlope 500 + RescaleIntercept -1024 = 498976 HU",
     [](const fs::path& d) {
       write(d, "a.dcm", slice_at(0));
       SyntheticSlice b = slice_at(1);
       b.slope = 500;
       write(d, "b.dcm", b);
     }},
    {"TooFewSlices", "at least 2 slice files", [](const fs::path& d) { write(d, "a.dcm", slice_at(0)); }},
    {"TiltedStack", "gantry tilt",
     [](const fs::path& d) {
       for (int k = 0; k < 3; ++k) {
         SyntheticSlice s = slice_at(k);
         s.position_mm.y() += 0.5 * k;  // each slice shifted sideways
         // (built in two steps: GCC 12's -Wrestrict misfires on "s" + to_string(k) + ".dcm" at -O3)
         std::string name = "s";
         name += std::to_string(k);
         name += ".dcm";
         write(d, name.c_str(), s);
       }
     }},
};

void PrintTo(const BadSeriesCase& c, std::ostream* os) {
  *os << c.name;
}

class BadDicomSeries : public ::testing::TestWithParam<BadSeriesCase> {};

TEST_P(BadDicomSeries, FailsWithAClearMessage) {
  TempDir dir;
  GetParam().make(dir.path());
  auto ct = read_dicom_series(dir.path());
  ASSERT_FALSE(ct.ok());
  EXPECT_NE(ct.status().message().find(GetParam().expected_message), std::string::npos)
      << ct.status().message();
  EXPECT_NE(ct.status().message().find(dir.path().string()), std::string::npos)
      << "the message names the file or folder: " << ct.status().message();
}

INSTANTIATE_TEST_SUITE_P(EveryClass, BadDicomSeries, ::testing::ValuesIn(kBadSeries),
                         [](const auto& p) { return std::string(p.param.name); });

TEST(DicomReader, MissingFolderIsNotFound) {
  auto ct = read_ct("/nonexistent/lftrack/ct");
  ASSERT_FALSE(ct.ok());
  EXPECT_EQ(ct.status().code(), StatusCode::kNotFound);
}

// The real series: 134 slices whose file names do not follow position order everywhere.
TEST(DicomReaderRealData, ReadsThePancreasSeries) {
  LFTRACK_REQUIRE_SHARED_DATA(test::pancreas_dicom());
  auto ct = read_dicom_series(test::pancreas_dicom());
  ASSERT_TRUE(ct.ok()) << ct.status().message();
  const VolumeGeometry& g = ct->geometry;
  EXPECT_EQ(g.size, Eigen::Vector3i(512, 512, 134));
  EXPECT_NEAR(g.spacing_mm.x(), 1.074, 0.001);
  EXPECT_NEAR(g.spacing_mm.z(), 3.0, 1e-3);
  float lo = 1e9f, hi = -1e9f;
  for (float v : ct->values) {
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  EXPECT_LE(lo, -1000.0f);  // air
  EXPECT_GE(hi, 1000.0f);   // bone
}

}  // namespace
}  // namespace lftrack::tracking

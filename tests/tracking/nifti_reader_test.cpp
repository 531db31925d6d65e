#include <gtest/gtest.h>
#include <nifti2_io.h>
#include <zlib.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>

#include "lftrack/tracking/volume_io.hpp"
#include "test_data.hpp"

namespace lftrack::tracking {
namespace {

namespace fs = std::filesystem;
using test::TempDir;

// Writes an 8 x 6 x 4 int16 NIfTI-1 volume with voxel value 10 i + 100 j + 1000 k and the given
// RAS affine as both sform and qform.
fs::path write_small_nifti(const fs::path& file, const Eigen::Matrix4d& ras_from_index,
                           int nifti_type = NIFTI_FTYPE_NIFTI1_1) {
  const int64_t dims[8] = {3, 8, 6, 4, 1, 1, 1, 1};
  nifti_image* nim = nifti_make_new_nim(dims, DT_INT16, 1);
  auto* data = static_cast<int16_t*>(nim->data);
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 6; ++j)
      for (int i = 0; i < 8; ++i)
        data[i + 8 * (j + 6 * k)] = static_cast<int16_t>(10 * i + 100 * j + 1000 * k);
  nim->sform_code = NIFTI_XFORM_SCANNER_ANAT;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) nim->sto_xyz.m[r][c] = ras_from_index(r, c);
  if (nifti_type == NIFTI_FTYPE_NIFTI2_1) {
    // nifti_image_write leaves a NIfTI-2 header empty here; write header, extender and data.
    nifti_2_header header;
    nifti_convert_nim2n2hdr(nim, &header);
    header.vox_offset = sizeof(nifti_2_header) + 4;
    std::ofstream out(file, std::ios::binary);
    out.write(reinterpret_cast<const char*>(&header), sizeof header);
    out.write("\0\0\0\0", 4);
    out.write(static_cast<const char*>(nim->data), static_cast<std::streamsize>(nim->nvox * nim->nbyper));
  } else {
    nifti_set_filenames(nim, file.c_str(), 0, 1);
    nifti_image_write(nim);
  }
  nifti_image_free(nim);
  return file;
}

void poke(const fs::path& file, std::streamoff offset, const void* bytes, std::size_t n) {
  std::fstream f(file, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp(offset);
  f.write(static_cast<const char*>(bytes), static_cast<std::streamsize>(n));
}

TEST(NiftiReader, ConvertsRasAffineToLps) {
  TempDir dir;
  Eigen::Matrix4d ras = Eigen::Matrix4d::Identity();
  ras.diagonal().head<3>() = Eigen::Vector3d(-2.0, 1.5, 3.0);  // i runs towards R (-x in RAS)
  ras.col(3).head<3>() = Eigen::Vector3d(40, -30, 12);
  const fs::path file = write_small_nifti(dir.path() / "v.nii", ras);
  auto ct = read_nifti(file);
  ASSERT_TRUE(ct.ok()) << ct.status().message();
  const VolumeGeometry& g = ct->geometry;
  EXPECT_EQ(g.size, Eigen::Vector3i(8, 6, 4));
  EXPECT_TRUE(g.spacing_mm.isApprox(Eigen::Vector3d(2.0, 1.5, 3.0)));
  // LPS = (-x, -y, z) of RAS.
  EXPECT_TRUE(g.origin_mm.isApprox(Eigen::Vector3d(-40, 30, 12)));
  const Eigen::Vector3d p_lps = g.ct_from_index() * Eigen::Vector3d(1, 2, 3);
  const Eigen::Vector4d p_ras = ras * Eigen::Vector4d(1, 2, 3, 1);
  EXPECT_TRUE(p_lps.isApprox(Eigen::Vector3d(-p_ras.x(), -p_ras.y(), p_ras.z())));
  EXPECT_FLOAT_EQ(ct->at(3, 2, 1), 10 * 3 + 100 * 2 + 1000 * 1);
}

TEST(NiftiReader, ReadsGzippedFiles) {
  TempDir dir;
  const fs::path file = write_small_nifti(dir.path() / "v.nii.gz", Eigen::Matrix4d::Identity());
  auto ct = read_ct(file);
  ASSERT_TRUE(ct.ok()) << ct.status().message();
  EXPECT_FLOAT_EQ(ct->at(7, 5, 3), 70 + 500 + 3000);
}

TEST(NiftiReader, ReadsNifti2) {
  TempDir dir;
  Eigen::Matrix4d ras = Eigen::Matrix4d::Identity();
  ras.diagonal().head<3>() = Eigen::Vector3d(0.8, 0.8, 2.5);
  const fs::path file = write_small_nifti(dir.path() / "v2.nii", ras, NIFTI_FTYPE_NIFTI2_1);
  int version = 0;
  void* header = nifti_read_header(file.c_str(), &version, 0);
  ASSERT_NE(header, nullptr);
  std::free(header);
  ASSERT_EQ(version, 2) << "the fixture must really be NIfTI-2";
  auto ct = read_nifti(file);
  ASSERT_TRUE(ct.ok()) << ct.status().message();
  EXPECT_TRUE(ct->geometry.spacing_mm.isApprox(Eigen::Vector3d(0.8, 0.8, 2.5)));
  EXPECT_FLOAT_EQ(ct->at(1, 1, 1), 1110);
}

struct BadNiftiCase {
  const char* name;
  const char* expected_message;
  void (*corrupt)(const fs::path& file);  // edits a valid .nii in place
};

const BadNiftiCase kBadNifti[] = {
    {"WrongMagic", "not a readable NIfTI",
     [](const fs::path& f) {
       poke(f, 344, "xx1\0", 4);
       poke(f, 0, "\0\0\0\0", 4);
     }},
    {"Truncated", "truncated", [](const fs::path& f) { fs::resize_file(f, 352 + 100); }},
    {"ZeroDimension", "NIfTI",
     [](const fs::path& f) {
       const int16_t zero = 0;
       poke(f, 42, &zero, 2);
     }},
    {"AbsurdDimension", "outside 1..",
     [](const fs::path& f) {
       const int16_t big = 30000;
       poke(f, 42, &big, 2);
     }},
    {"MoreDataClaimedThanPresent", "truncated",
     [](const fs::path& f) {
       const int16_t n = 600;
       poke(f, 46, &n, 2);
     }},
    {"NanSpacing", "not finite",
     [](const fs::path& f) {
       const float nan = std::nanf("");
       const int16_t zero = 0;
       poke(f, 80, &nan, 4);    // pixdim[1]
       poke(f, 252, &zero, 2);  // qform_code
       poke(f, 254, &zero, 2);  // sform_code
     }},
    {"NanAffine", "not finite",
     [](const fs::path& f) {
       const float nan = std::nanf("");
       poke(f, 280, &nan, 4);
     }},  // srow_x[0]
    {"EmptyFile", "not a readable NIfTI", [](const fs::path& f) { fs::resize_file(f, 0); }},
    // A tiny file whose header claims gigabytes: refused before nifti_clib allocates them
    // (fuzz_ct found 446 bytes claiming 6.5 GB).
    {"ClaimsGigabytes", "(2000000000 bytes from offset 352), more than the file's",
     [](const fs::path& f) {
       const int16_t dims[3] = {1000, 1000, 1000};  // under the voxel limit, 2 GB of int16
       poke(f, 42, dims, sizeof dims);
     }},
    // Voxels that would start inside the header (or nowhere): read as header bytes before.
    {"VoxOffsetInsideTheHeader", "vox_offset 100 is not a whole number of bytes at or after the 352-byte header",
     [](const fs::path& f) {
       const float offset = 100;
       poke(f, 108, &offset, 4);
     }},
    {"NanVoxOffset", "vox_offset nan",
     [](const fs::path& f) {
       const float offset = std::nanf("");
       poke(f, 108, &offset, 4);
     }},
    // Neither sform nor qform: left and right unknown.
    {"NoOrientation", "the patient's orientation (left from right included) is unknown",
     [](const fs::path& f) {
       const int16_t zero = 0;
       poke(f, 252, &zero, 2);  // qform_code
       poke(f, 254, &zero, 2);  // sform_code
     }},
    // Rescales nifti_clib would quietly drop, or no CT has.
    {"NanSlope", "scl_slope nan is not 0 (no scaling) or in [0.001, 1000]",
     [](const fs::path& f) {
       const float nan = std::nanf("");
       poke(f, 112, &nan, 4);
     }},
    {"NegativeSlope", "scl_slope -1 is not 0",
     [](const fs::path& f) {
       const float v = -1;
       poke(f, 112, &v, 4);
     }},
    {"HugeIntercept", "scl_inter 1e+20 is not finite within +-100000",
     [](const fs::path& f) {
       const float slope = 1, inter = 1e20f;
       poke(f, 112, &slope, 4);
       poke(f, 116, &inter, 4);
     }},
    {"ImplausibleValue", "voxel (1, 0, 1) holds 1010 (x scl_slope 100 + scl_inter 0): not a finite CT number",
     [](const fs::path& f) {
       const float slope = 100, inter = 0;
       poke(f, 112, &slope, 4);
       poke(f, 116, &inter, 4);
     }},
};

void PrintTo(const BadNiftiCase& c, std::ostream* os) {
  *os << c.name;
}

class BadNifti : public ::testing::TestWithParam<BadNiftiCase> {};

TEST_P(BadNifti, FailsWithAClearMessage) {
  TempDir dir;
  const fs::path file = write_small_nifti(dir.path() / "bad.nii", Eigen::Matrix4d::Identity());
  GetParam().corrupt(file);
  auto ct = read_nifti(file);
  ASSERT_FALSE(ct.ok());
  EXPECT_NE(ct.status().message().find(GetParam().expected_message), std::string::npos)
      << ct.status().message();
  EXPECT_NE(ct.status().message().find(file.string()), std::string::npos) << ct.status().message();
}

INSTANTIATE_TEST_SUITE_P(EveryClass, BadNifti, ::testing::ValuesIn(kBadNifti),
                         [](const auto& p) { return std::string(p.param.name); });

TEST(NiftiReader, TruncatedGzipFails) {
  TempDir dir;
  const fs::path file = write_small_nifti(dir.path() / "v.nii.gz", Eigen::Matrix4d::Identity());
  fs::resize_file(file, fs::file_size(file) * 2 / 3);
  auto ct = read_nifti(file);
  ASSERT_FALSE(ct.ok());
  EXPECT_NE(ct.status().message().find(file.string()), std::string::npos);
}

// A float volume with one NaN or infinite voxel is refused with the voxel named; so is a gzip
// stream whose CRC is wrong although the volume itself reads (nifti_clib stops before the CRC).
TEST(NiftiReader, NonFiniteVoxelsAndADamagedGzipStreamAreRefused) {
  TempDir dir;
  for (const float bad : {std::nanf(""), std::numeric_limits<float>::infinity(), -1e30f}) {
    const int64_t dims[8] = {3, 4, 3, 2, 1, 1, 1, 1};
    nifti_image* nim = nifti_make_new_nim(dims, DT_FLOAT32, 1);
    auto* data = static_cast<float*>(nim->data);
    for (int v = 0; v < 24; ++v) data[v] = -1000.0f + float(v);
    data[2 + 4 * (1 + 3 * 1)] = bad;  // voxel (2, 1, 1)
    nim->sform_code = NIFTI_XFORM_SCANNER_ANAT;
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) nim->sto_xyz.m[r][c] = r == c ? 1 : 0;
    const fs::path file = dir.path() / "float.nii";
    nifti_set_filenames(nim, file.c_str(), 0, 1);
    nifti_image_write(nim);
    nifti_image_free(nim);
    auto ct = read_nifti(file);
    ASSERT_FALSE(ct.ok()) << bad;
    EXPECT_NE(ct.status().message().find("voxel (2, 1, 1) holds"), std::string::npos) << ct.status().message();
  }
  // A stream that goes on past the volume (200 kB after the voxels), so reading the volume stops
  // before the stream's end and its CRC.
  const fs::path plain = write_small_nifti(dir.path() / "v.nii", Eigen::Matrix4d::Identity());
  std::string bytes;
  {
    std::ifstream in(plain, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  bytes += std::string(200000, 'x');
  const fs::path gz = dir.path() / "v.nii.gz";
  gzFile out = gzopen(gz.c_str(), "wb");
  ASSERT_NE(out, nullptr);
  ASSERT_EQ(gzwrite(out, bytes.data(), unsigned(bytes.size())), int(bytes.size()));
  ASSERT_EQ(gzclose(out), Z_OK);
  ASSERT_TRUE(read_nifti(gz).ok()) << "the intact file reads";
  std::fstream f(gz, std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(-8, std::ios::end);  // the gzip trailer: CRC-32, then the length
  char crc[4];
  f.read(crc, 4);
  for (char& c : crc) c = static_cast<char>(~c);
  f.seekp(-8, std::ios::end);
  f.write(crc, 4);
  f.close();
  auto ct = read_nifti(gz);
  ASSERT_FALSE(ct.ok()) << "a wrong CRC must not pass";
  EXPECT_NE(ct.status().message().find("the gzip stream is damaged"), std::string::npos) << ct.status().message();
}

TEST(NiftiReader, UnknownExtensionIsRejected) {
  TempDir dir;
  std::ofstream(dir.path() / "volume.raw") << "x";
  auto ct = read_ct(dir.path() / "volume.raw");
  ASSERT_FALSE(ct.ok());
  EXPECT_NE(ct.status().message().find("unknown CT format"), std::string::npos);
}

}  // namespace
}  // namespace lftrack::tracking

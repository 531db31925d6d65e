// Light fields: planning, samples, storage modes, files (rendering: light_field_render_test.cpp).

#include "lftrack/tracking/light_field.hpp"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <zlib.h>

#include <cstring>
#include <fstream>
#include <limits>
#include <random>
#include <vector>

#include "fixtures.hpp"
#include "lftrack/tracking/image_metrics.hpp"
#include "lftrack/tracking/ray_integrals.hpp"
#include "lftrack/tracking/random_draws.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;
using Eigen::Vector4d;
using test::fixture_light_field;
using test::fixture_plan;

TEST(LightFieldPlan, PlanesAreOrthonormalAndAimedAtTheRoi) {
  const LightFieldGeometry g = fixture_light_field(LightFieldStorage::kFloat32)->geometry();
  EXPECT_NEAR(g.axis.norm(), 1, 1e-12);
  EXPECT_NEAR(g.e1.dot(g.axis), 0, 1e-12);
  EXPECT_NEAR(g.e2.dot(g.axis), 0, 1e-12);
  EXPECT_NEAR(g.e1.dot(g.e2), 0, 1e-12);
  EXPECT_TRUE(((g.roi_centre_ct_mm - g.source_ct_mm).normalized() - g.axis).norm() < 1e-12);
  EXPECT_EQ(g.size, (std::array<int, 4>{12, 12, 64, 64}));
}

TEST(LightFieldPlan, TheNominalSourceIsASample) {
  for (const double rotation_deg : {0.0, 2.0, 5.0}) {
    LightFieldPlanInput in = fixture_plan();
    in.envelope.rotation_deg = rotation_deg;
    for (const int n : {3, 12, 32, 33}) {
      LightFieldSpec spec;
      spec.resolution = {n, n + 1, 64, 64};
      auto g = plan_light_field(in, spec);
      ASSERT_TRUE(g.ok()) << g.status().message();
      for (int a = 0; a < 2; ++a) {
        const double index = -g->lo[a] / g->spacing(a);  // where u = 0 (v = 0) falls
        EXPECT_NEAR(index, std::round(index), 1e-9) << "axis " << a << ", " << g->size[a] << " samples";
        EXPECT_GT(index, 0.5);
        EXPECT_LT(index, g->size[a] - 1.5);
      }
    }
  }
}

TEST(LightFieldPlan, CoordinatesAndRaysRoundTrip) {
  const LightFieldGeometry g = fixture_light_field(LightFieldStorage::kFloat32)->geometry();
  const Vector4d uvst(3.5, -2.0, 10.25, -7.5);
  Vector3d a, b;
  g.ray(uvst, &a, &b);
  EXPECT_TRUE(g.coordinates(a, b)->isApprox(uvst, 1e-9));
  // Any two points of the same line give the same coordinates.
  EXPECT_TRUE(g.coordinates(a - 50 * (b - a), b + 3 * (b - a))->isApprox(uvst, 1e-9));
  EXPECT_FALSE(g.coordinates(a, a + g.e1).has_value());  // parallel to the planes
}

TEST(LightFieldPlan, ExtentsCoverEveryEnvelopePoseAndGrowWithTheEnvelope) {
  const LightFieldPlanInput in = fixture_plan();
  LightFieldSpec spec;
  spec.margin_fraction = 0;
  auto g = plan_light_field(in, spec);
  ASSERT_TRUE(g.ok());
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int n = 0; n < 300; ++n) {
    PoseDelta d;
    d.translation_mm = in.envelope.translation_mm * tracking::draw3(u, rng);
    d.rotation_rad = deg_to_rad(in.envelope.rotation_deg) * tracking::draw3(u, rng);
    const Pose pose = apply_delta(in.nominal_T_room_from_ct, d, in.registration_origin_room_mm);
    const Vector3d s = pose.inverse() * in.view_room.source_mm;
    const Vector3d p = pose.inverse() * in.view_room.pixel_centre_mm(u(rng) * 10 + 24, u(rng) * 10 + 20);
    const Vector4d c = *g->coordinates(s, p);
    for (int a = 0; a < 4; ++a) {
      EXPECT_GE(c[a], g->lo[a] - 1e-6) << a;
      EXPECT_LE(c[a], g->hi[a] + 1e-6) << a;
    }
  }
  LightFieldPlanInput wider = in;
  wider.envelope.rotation_deg *= 2;
  auto g2 = plan_light_field(wider, spec);
  ASSERT_TRUE(g2.ok());
  EXPECT_GT(g2->hi[0] - g2->lo[0], 1.5 * (g->hi[0] - g->lo[0]));
}

// A field over the fixture integrated as asked (the fixture's own fields take the default, the walk).
std::shared_ptr<const LightField> fixture_field_by(LightFieldIntegration integration, double step_mm = 0,
                                                   ThreadPool* pool = nullptr) {
  LightFieldSpec spec;
  spec.resolution = {12, 12, 64, 64};
  spec.integration = integration;
  spec.slice_step_mm = step_mm;
  auto field = LightField::build(*test::fixture_volume(), fixture_plan(), spec, pool);
  return field.ok() ? *field : nullptr;
}

// How far a field's samples are from the exact walk's, relative to the walk's largest sample:
// the largest difference, the root mean square one, and the largest over the rays of the
// nominal source sample (u, v) = (0, 0).
struct FieldDifference {
  double max = 0, rms = 0, max_at_the_nominal_source = 0;
};
FieldDifference difference(const LightField& field, const LightField& walked) {
  const auto& n = walked.geometry().size;
  const LightFieldGeometry& g = walked.geometry();
  const int u0 = int(std::lround(-g.lo[0] / g.spacing(0))), v0 = int(std::lround(-g.lo[1] / g.spacing(1)));
  double peak = 0, sum = 0;
  FieldDifference d;
  std::int64_t count = 0;
  for (int iu = 0; iu < n[0]; ++iu)
    for (int iv = 0; iv < n[1]; ++iv)
      for (int is = 0; is < n[2]; ++is)
        for (int it = 0; it < n[3]; ++it) {
          const double w = walked.sample(iu, iv, is, it), e = std::abs(field.sample(iu, iv, is, it) - w);
          peak = std::max(peak, w);
          d.max = std::max(d.max, e);
          if (iu == u0 && iv == v0) d.max_at_the_nominal_source = std::max(d.max_at_the_nominal_source, e);
          sum += e * e;
          ++count;
        }
  d.max /= peak;
  d.max_at_the_nominal_source /= peak;
  d.rms = std::sqrt(sum / double(count)) / peak;
  return d;
}

// The integration by slices of the voxels' box model against the exact walk: the
// samples differ by its quadrature and its linear shifts between resampled samples, a fraction
// of a percent of the largest sample; least where the rays read the slices unshifted (the
// nominal source). A finer depth step comes closer.
TEST(LightFieldBuild, SlicesStayCloseToTheExactWalk) {
  const auto walked = fixture_field_by(LightFieldIntegration::kSiddon);
  const auto sliced = fixture_field_by(LightFieldIntegration::kSlices);
  const auto fine = fixture_field_by(LightFieldIntegration::kSlices, 0.25);
  ASSERT_TRUE(walked && sliced && fine);
  EXPECT_EQ(sliced->geometry().size, walked->geometry().size);
  EXPECT_NE(sliced->header().plan_hash, walked->header().plan_hash);
  EXPECT_NE(fine->header().plan_hash, sliced->header().plan_hash);
  const FieldDifference d = difference(*sliced, *walked), d_fine = difference(*fine, *walked);
  // Measured: max 0.115 (rays grazing the dense block's edges, where the walk's integral jumps
  // between neighbouring rays), rms 0.0060, nominal source 0.0072; at 0.25 mm 0.0015 there.
  // Without the step's length along each ray the rms was 0.024; with one box-model sample a
  // slice (not four), 0.0085 and 0.018 at the nominal source.
  EXPECT_LT(d.max, 0.15);
  EXPECT_LT(d.rms, 0.0075);
  EXPECT_LT(d.max_at_the_nominal_source, 0.01);
  EXPECT_LT(d_fine.max_at_the_nominal_source, 0.5 * d.max_at_the_nominal_source);
  EXPECT_LT(d_fine.rms, d.rms);
}

// The field is the same bit for bit however many threads build it.
TEST(LightFieldBuild, SlicesDoNotDependOnTheThreads) {
  ThreadPool pool(3);
  const auto alone = fixture_field_by(LightFieldIntegration::kSlices);
  const auto together = fixture_field_by(LightFieldIntegration::kSlices, 0, &pool);
  ASSERT_TRUE(alone && together);
  ASSERT_EQ(alone->payload_bytes(), together->payload_bytes());
  EXPECT_EQ(std::memcmp(alone->float_samples(), together->float_samples(), alone->payload_bytes()), 0);
}

// Slices need the volume well in front of the source (a slice's grid shrinks towards it): a
// volume that reaches the source plane's tenth of the way to the ROI is walked exactly instead,
// the same samples as a field asked to walk.
TEST(LightFieldBuild, AVolumeReachingTowardsTheSourceIsWalkedExactly) {
  MuVolume big = test::uniform_box({40, 40, 40}, {20, 20, 20}, 0.001f);
  big.geometry.origin_mm = {-390, -390, -390};  // 800 mm a side about the isocentre; the source is 400 mm out
  LightFieldSpec spec;
  spec.resolution = {4, 4, 16, 16};
  spec.integration = LightFieldIntegration::kSlices;
  auto sliced = LightField::build(big, fixture_plan(), spec, nullptr);
  spec.integration = LightFieldIntegration::kSiddon;
  auto walked = LightField::build(big, fixture_plan(), spec, nullptr);
  ASSERT_TRUE(sliced.ok() && walked.ok());
  ASSERT_EQ((*sliced)->payload_bytes(), (*walked)->payload_bytes());
  EXPECT_EQ(std::memcmp((*sliced)->float_samples(), (*walked)->float_samples(), (*walked)->payload_bytes()), 0);
  EXPECT_GT((*walked)->sample(2, 2, 8, 8), 0.5);  // about 800 mm of 0.001 / mm
}

// The walk skips the air around the body where asked (skip_air_below_hu -900): a body in a
// volume whose air is exactly 0 gives the whole grid's samples (to the rounding of a walk that
// starts elsewhere); with noise in the air, below the floor, each sample loses at most what the
// air along its ray holds, and some lose something. -1000 (the default) walks the whole grid,
// and the two fields are told apart by their plan's hash; a volume all below the floor is air
// alone: every sample 0.
TEST(LightFieldBuild, SkipsTheAirAroundTheBodyAndLosesOnlyWhatTheAirHolds) {
  constexpr float kBody = 0.02f, kAirNoise = 0.0015f;  // the floor is 0.00193 / mm (-900 HU)
  const auto volume = [&](bool noisy_air) {
    MuVolume v = test::uniform_box({64, 64, 48}, {1.0, 1.0, 1.0}, 0.0f);
    v.geometry.origin_mm = {-31.5, -31.5, -23.5};
    std::mt19937 draw(3);
    std::uniform_real_distribution<float> noise(0.0f, kAirNoise);
    for (int k = 0; k < 48; ++k)
      for (int j = 0; j < 64; ++j)
        for (int i = 0; i < 64; ++i) {
          const bool body = std::hypot(i - 31.5, j - 31.5) < 14 && std::abs(k - 23.5) < 16;
          v.at(i, j, k) = body ? kBody : (noisy_air ? noise(draw) : 0.0f);
        }
    return v;
  };
  LightFieldSpec spec;
  spec.resolution = {6, 6, 32, 32};
  const auto build = [&](const MuVolume& v, double skip_hu) {
    spec.skip_air_below_hu = skip_hu;
    auto field = LightField::build(v, fixture_plan(), spec, nullptr);
    EXPECT_TRUE(field.ok()) << field.status().to_string();
    return field.ok() ? *field : nullptr;
  };
  const MuVolume clean = volume(false), noisy = volume(true);
  const auto clean_whole = build(clean, -1000), clean_skipped = build(clean, -900);
  const auto noisy_whole = build(noisy, -1000), noisy_skipped = build(noisy, -900);
  ASSERT_TRUE(clean_whole && clean_skipped && noisy_whole && noisy_skipped);
  EXPECT_NE(clean_whole->header().plan_hash, clean_skipped->header().plan_hash);
  const double diagonal_mm = Vector3d(64, 64, 48).norm();
  const auto& n = clean_whole->geometry().size;
  double clean_worst = 0, noisy_worst = 0, noisy_loss_sum = 0, peak = 0;
  std::int64_t samples = 0;
  for (int iu = 0; iu < n[0]; ++iu)
    for (int iv = 0; iv < n[1]; ++iv)
      for (int is = 0; is < n[2]; ++is)
        for (int it = 0; it < n[3]; ++it) {
          const double w = clean_whole->sample(iu, iv, is, it);
          peak = std::max(peak, w);
          clean_worst = std::max(clean_worst, std::abs(clean_skipped->sample(iu, iv, is, it) - w));
          const double loss = noisy_whole->sample(iu, iv, is, it) - noisy_skipped->sample(iu, iv, is, it);
          EXPECT_GE(loss, -1e-5) << "skipping adds nothing";
          noisy_worst = std::max(noisy_worst, loss);
          noisy_loss_sum += loss;
          ++samples;
        }
  EXPECT_GT(peak, 0.3);  // the body is crossed: 28 mm of 0.02 / mm at least
  EXPECT_LT(clean_worst, 1e-5 * peak) << "air of 0 skipped is no loss";
  EXPECT_LE(noisy_worst, kAirNoise * diagonal_mm) << "at most the air's most along the grid's diagonal";
  EXPECT_GT(noisy_loss_sum / double(samples), 0.0) << "the noise outside the body's blocks is left out";
  EXPECT_EQ(LightFieldSpec().skip_air_below_hu, -1000.0);
  spec.skip_air_below_hu = -1000;
  EXPECT_EQ(clean_whole->header().plan_hash, plan_hash(fixture_plan(), spec))
      << "the default's hash as before";
  const auto thin = build(test::uniform_box({64, 64, 48}, {1.0, 1.0, 1.0}, kAirNoise), -900);
  ASSERT_TRUE(thin);
  EXPECT_EQ(thin->sample(3, 3, 16, 16), 0.0f);
}

TEST(LightFieldBuild, SamplesAreWholeLineIntegrals) {
  const auto field = fixture_field_by(LightFieldIntegration::kSiddon);
  ASSERT_TRUE(field);
  const LightFieldGeometry& g = field->geometry();
  const MuVolume& mu = *test::fixture_volume();
  const GridRayCaster caster(mu);
  for (auto idx : {std::array<int, 4>{0, 0, 0, 0}, {5, 7, 31, 40}, {11, 11, 63, 63}, {3, 9, 12, 50}}) {
    Vector4d uvst;
    for (int a = 0; a < 4; ++a) uvst[a] = g.lo[a] + idx[a] * g.spacing(a);
    Vector3d a, b;
    g.ray(uvst, &a, &b);
    const Vector3d dir = (b - a).normalized();
    const double expected = caster.siddon(mu.geometry.grid_from_ct() * (a - 1000 * dir),
                                          mu.geometry.grid_from_ct() * (b + 1000 * dir));
    EXPECT_NEAR(field->sample(idx[0], idx[1], idx[2], idx[3]), expected, 1e-5 * std::max(1.0, expected));
  }
}

TEST(LightFieldBuild, StorageModesKeepTheSamplesClose) {
  const auto f = fixture_light_field(LightFieldStorage::kFloat32);
  const auto q = fixture_light_field(LightFieldStorage::kFixed16);
  const auto v = fixture_light_field(LightFieldStorage::kVq);
  ASSERT_TRUE(f && q && v);
  EXPECT_EQ(q->payload_bytes() * 2, f->payload_bytes());
  EXPECT_LT(v->payload_bytes(), q->payload_bytes() / 3);
  double peak = 0, worst_q = 0, rms_v = 0;
  const auto& s = f->geometry().size;
  int n = 0;
  for (int iu = 0; iu < s[0]; iu += 3)
    for (int iv = 0; iv < s[1]; iv += 3)
      for (int is = 0; is < s[2]; ++is)
        for (int it = 0; it < s[3]; ++it) {
          const double x = f->sample(iu, iv, is, it);
          peak = std::max(peak, x);
          worst_q = std::max(worst_q, std::abs(q->sample(iu, iv, is, it) - x));
          rms_v += std::pow(v->sample(iu, iv, is, it) - x, 2);
          ++n;
        }
  EXPECT_LE(worst_q, 0.51 * q->header().fixed_scale + 1e-6) << "16-bit: half a quantisation step";
  EXPECT_LT(std::sqrt(rms_v / n), 0.02 * peak) << "VQ with 256 codewords";
}

// File faults, each with its own message.
class LightFieldFile : public ::testing::Test {
 protected:
  void SetUp() override {
    field_ = fixture_light_field(LightFieldStorage::kFixed16);
    file_ = dir_.path() / "A.lf";
    ASSERT_TRUE(field_->save(file_).ok());
  }
  void flip_byte(std::streamoff offset) {
    std::fstream f(file_, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(offset);
    char c = 0;
    f.read(&c, 1);
    c = static_cast<char>(c ^ 0x5a);
    f.seekp(offset);
    f.write(&c, 1);
  }
  std::string load_error(std::optional<std::uint64_t> ct = {}, std::optional<std::uint64_t> plan = {}) {
    auto loaded = LightField::load(file_, ct, plan);
    return loaded.ok() ? std::string("(loaded)") : loaded.status().message();
  }
  test::TempDir dir_;
  std::shared_ptr<const LightField> field_;
  std::filesystem::path file_;
};

TEST_F(LightFieldFile, RoundTripsThroughAMemoryMap) {
  auto loaded = LightField::load(file_, field_->header().ct_hash, field_->header().plan_hash);
  ASSERT_TRUE(loaded.ok()) << loaded.status().message();
  EXPECT_EQ((*loaded)->header().storage, LightFieldStorage::kFixed16);
  EXPECT_EQ((*loaded)->geometry().size, field_->geometry().size);
  EXPECT_EQ((*loaded)->sample(3, 4, 20, 33), field_->sample(3, 4, 20, 33));
  EXPECT_EQ((*loaded)->sample(11, 0, 63, 0), field_->sample(11, 0, 63, 0));
}

TEST_F(LightFieldFile, FlippedPayloadByte) {
  flip_byte(1024 + 5000);
  EXPECT_NE(load_error().find("sample data is corrupted"), std::string::npos) << load_error();
}

TEST_F(LightFieldFile, FlippedHeaderByte) {
  flip_byte(50);
  EXPECT_NE(load_error().find("header is corrupted"), std::string::npos) << load_error();
}

TEST_F(LightFieldFile, Truncated) {
  std::filesystem::resize_file(file_, std::filesystem::file_size(file_) - 100);
  EXPECT_NE(load_error().find("truncated"), std::string::npos) << load_error();
  std::filesystem::resize_file(file_, 600);
  EXPECT_NE(load_error().find("truncated"), std::string::npos) << load_error();
}

TEST_F(LightFieldFile, WrongVersion) {
  flip_byte(8);
  EXPECT_NE(load_error().find("unknown light-field file version"), std::string::npos) << load_error();
}

TEST_F(LightFieldFile, NotALightField) {
  flip_byte(0);
  EXPECT_NE(load_error().find("not a light-field file"), std::string::npos) << load_error();
}

TEST_F(LightFieldFile, WrongCt) {
  EXPECT_NE(load_error(field_->header().ct_hash ^ 1, field_->header().plan_hash).find("another CT"),
            std::string::npos);
}

TEST_F(LightFieldFile, WrongGeometry) {
  LightFieldPlanInput moved = fixture_plan();
  moved.view_room.source_mm.x() += 1.0;
  LightFieldSpec spec;
  spec.resolution = {12, 12, 64, 64};
  EXPECT_NE(load_error(field_->header().ct_hash, plan_hash(moved, spec)).find("another geometry"),
            std::string::npos);
  EXPECT_EQ(load_error(field_->header().ct_hash, plan_hash(fixture_plan(), spec)), "(loaded)");
}

// A file records the settings it was built with, so that a stale field names every one that
// differs, the integration and slice step too (issue 50); a file written before they were
// recorded says what it cannot tell.
TEST_F(LightFieldFile, RecordsItsSettingsAndAStaleOneNamesEachThatDiffers) {
  auto header = LightField::read_header(file_);
  ASSERT_TRUE(header.ok()) << header.status().message();
  EXPECT_TRUE(header->settings_recorded);
  EXPECT_EQ(header->integration, LightFieldIntegration::kSiddon);
  EXPECT_EQ(header->roi_window.cols, fixture_plan().roi_window.cols);
  EXPECT_EQ(header->detector_hash, detector_geometry_hash(fixture_plan().view_room));
  const std::uint64_t ct = field_->header().ct_hash;
  LightFieldSpec spec;
  spec.resolution = {12, 12, 64, 64};
  spec.storage = LightFieldStorage::kFixed16;
  EXPECT_TRUE(light_field_differences(*header, ct, fixture_plan(), spec).empty());

  LightFieldSpec sliced = spec;
  sliced.integration = LightFieldIntegration::kSlices;
  sliced.slice_step_mm = 0.5;
  sliced.resolution = {8, 8, 64, 64};
  LightFieldPlanInput moved = fixture_plan();
  moved.envelope.rotation_deg = 13;
  moved.view_room.source_mm.x() += 1.0;
  std::string all;
  for (const std::string& d : light_field_differences(*header, ct ^ 1, moved, sliced)) all += d + "\n";
  for (const char* named : {"CT (volume hash ", "detector geometry of view A", "envelope rotation_deg (12 in the file, 13 now)",
                            "resolution (12x12x64x64 in the file, 8x8x64x64 now)",
                            "integration (siddon in the file, slices now)",
                            "slice_step_mm (0 (the CT's finest spacing) in the file, 0.5 now)"})
    EXPECT_NE(all.find(named), std::string::npos) << named << " in:\n" << all;

  // As an earlier lftrack wrote it: no settings (zeros), the header's checksum good.
  {
    std::fstream f(file_, std::ios::in | std::ios::out | std::ios::binary);
    unsigned char bytes[1020];
    f.read(reinterpret_cast<char*>(bytes), 1020);
    std::memset(bytes + 492, 0, 60);
    const auto crc = static_cast<std::uint32_t>(crc32(crc32(0L, Z_NULL, 0), bytes, 1020));
    f.seekp(0);
    f.write(reinterpret_cast<const char*>(bytes), 1020);
    f.write(reinterpret_cast<const char*>(&crc), 4);
  }
  auto earlier = LightField::read_header(file_);
  ASSERT_TRUE(earlier.ok()) << earlier.status().message();
  EXPECT_FALSE(earlier->settings_recorded);
  EXPECT_EQ(load_error(ct, field_->header().plan_hash), "(loaded)") << "an earlier file still loads";
  LightFieldSpec margin = spec;
  margin.margin_fraction = 0.05;
  const auto d = light_field_differences(*earlier, ct, fixture_plan(), margin);
  ASSERT_EQ(d.size(), 1u);
  EXPECT_NE(d[0].find("a setting an older lftrack did not record"), std::string::npos) << d[0];
}

TEST_F(LightFieldFile, PaddedOrLyingAboutItsPayload) {
  const auto size = std::filesystem::file_size(file_);
  std::ofstream(file_, std::ios::app | std::ios::binary) << "trailing";
  EXPECT_NE(load_error().find("padded: the file has " + std::to_string(size + 8) + " bytes, the 1024-byte header and its " +
                              std::to_string(size - 1024) + "-byte payload make " + std::to_string(size)),
            std::string::npos)
      << load_error();
}

// A FIFO (or a folder) named like a light field: refused at once, never waited on.
TEST_F(LightFieldFile, AFifoOrFolderIsRefusedWithoutHanging) {
  const auto fifo = dir_.path() / "B.lf";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  auto loaded = LightField::load(fifo);
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("not a regular file"), std::string::npos) << loaded.status().message();
  std::filesystem::create_directory(dir_.path() / "C.lf");
  EXPECT_FALSE(LightField::load(dir_.path() / "C.lf").ok());
}

// A save that cannot be put in place (a folder where the file goes) fails with the reason and
// leaves no half-written copy beside it (each one was a whole field: 256 MB for the lumbar CT).
TEST_F(LightFieldFile, AFailedSaveLeavesNothingBehind) {
  const auto taken = dir_.path() / "D.lf";
  std::filesystem::create_directories(taken / "inside");
  const Status saved = field_->save(taken);
  ASSERT_FALSE(saved.ok());
  EXPECT_NE(saved.message().find("cannot rename into place"), std::string::npos) << saved.message();
  for (const auto& entry : std::filesystem::directory_iterator(dir_.path()))
    EXPECT_EQ(entry.path().string().find(".partial"), std::string::npos) << entry.path();
  EXPECT_TRUE(std::filesystem::exists(taken / "inside"));
}

// Rewrites the payload at `offset` (from the payload's start) and makes both checksums valid
// again, as a tool that writes bad values with good checksums would.
void patch_file(const std::filesystem::path& file, std::size_t offset, const void* bytes, std::size_t n);
void patch_payload(const std::filesystem::path& file, std::size_t offset, const void* bytes, std::size_t n) {
  patch_file(file, 1024 + offset, bytes, n);
}
void patch_file(const std::filesystem::path& file, std::size_t offset, const void* bytes, std::size_t n) {
  std::vector<unsigned char> data(std::filesystem::file_size(file));
  {
    std::ifstream in(file, std::ios::binary);
    in.read(reinterpret_cast<char*>(data.data()), std::streamsize(data.size()));
  }
  std::memcpy(data.data() + offset, bytes, n);
  const auto payload_crc = static_cast<std::uint32_t>(crc32(0, data.data() + 1024, uInt(data.size() - 1024)));
  std::memcpy(data.data() + 424, &payload_crc, 4);
  const auto header_crc = static_cast<std::uint32_t>(crc32(0, data.data(), 1020));
  std::memcpy(data.data() + 1020, &header_crc, 4);
  std::ofstream(file, std::ios::binary | std::ios::trunc).write(reinterpret_cast<const char*>(data.data()),
                                                                 std::streamsize(data.size()));
}

TEST(LightFieldFileValues, NonFiniteSamplesAndCodesOutsideTheCodebookAreRefusedUnderValidChecksums) {
  test::TempDir dir;
  const auto file = dir.path() / "A.lf";
  auto field = fixture_light_field(LightFieldStorage::kFloat32);
  ASSERT_TRUE(field->save(file).ok());
  const float nan = std::numeric_limits<float>::quiet_NaN();
  patch_payload(file, 4 * 777, &nan, 4);
  auto loaded = LightField::load(file);
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("sample 777 is not a line integral"), std::string::npos) << loaded.status().message();

  auto vq = fixture_light_field(LightFieldStorage::kVq);
  ASSERT_TRUE(vq->save(file).ok());
  const std::uint16_t beyond = static_cast<std::uint16_t>(vq->header().codebook_size);
  patch_payload(file, std::size_t(vq->header().codebook_size) * 64 + 2 * 5, &beyond, 2);
  loaded = LightField::load(file);
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("tile 5 names codebook entry"), std::string::npos)
      << loaded.status().message();
  ASSERT_TRUE(field->save(file).ok());
  const float huge = 3e38f;  // finite, yet no line integral
  patch_payload(file, 4 * 12, &huge, 4);
  loaded = LightField::load(file);
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("sample 12 is not a line integral"), std::string::npos)
      << loaded.status().message();
  ASSERT_TRUE(field->save(file).ok());
  const double nan_envelope = std::numeric_limits<double>::quiet_NaN();
  patch_file(file, 376, &nan_envelope, 8);  // envelope.translation_mm
  loaded = LightField::load(file);
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("nominal pose, registration origin or envelope is not a valid one"),
            std::string::npos)
      << loaded.status().message();

  ASSERT_TRUE(vq->save(file).ok());
  const float inf = std::numeric_limits<float>::infinity();
  patch_payload(file, 64 * 2 + 4, &inf, 4);
  loaded = LightField::load(file);
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("codebook entry 2 is not a line integral"), std::string::npos)
      << loaded.status().message();
}

TEST_F(LightFieldFile, MissingFile) {
  auto loaded = LightField::load(dir_.path() / "none.lf");
  ASSERT_FALSE(loaded.ok());
  EXPECT_NE(loaded.status().message().find("lftrack precompute"), std::string::npos);
}

}  // namespace
}  // namespace lftrack::tracking

#include "lftrack/studies/drr_benchmark.hpp"

#include <gtest/gtest.h>

#include "lftrack/studies/plastimatch_peer.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::session {

using studies::DrrBenchOptions;
using studies::plastimatch_available;
using studies::run_drr_benchmark;
using studies::sample_envelope_poses;
namespace {

TEST(DrrBenchmark, SmallRunReportsEveryRendererAndThePeer) {
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok());
  tracking::ThreadPool pool(2);
  auto prepared = prepare_scene(*scene, "", &pool);
  ASSERT_TRUE(prepared.ok());
  prepared->scene.light_field.resolution = {4, 4, 32, 32};  // small: this tests the plumbing
  DrrBenchOptions o;
  o.size = 32;
  o.poses = 2;
  o.repeats = 1;
  o.vq_codebooks = {16};
  o.peers = plastimatch_available();
  auto report = run_drr_benchmark(*prepared, o, &pool);
  ASSERT_TRUE(report.ok()) << report.status().message();
  const nlohmann::json j = to_json(*report);
  EXPECT_EQ(j["size"], nlohmann::json({32, 32}));
  // siddon, trilinear, light field float (source image), float per ray, fixed16, vq16
  ASSERT_EQ(j["renderers"].size(), 6u);
  EXPECT_EQ(j["renderers"][0]["name"], "siddon");
  EXPECT_DOUBLE_EQ(j["renderers"][0]["ncc_vs_siddon"].get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(j["renderers"][0]["speedup_vs_siddon"].get<double>(), 1.0);
  for (const auto& r : j["renderers"]) {
    EXPECT_GT(r["ms_median"].get<double>(), 0.0);
    EXPECT_GT(r["ncc_vs_siddon"].get<double>(), 0.9) << r["name"];  // 16 codewords: coarse on purpose
    EXPECT_EQ(r["out_of_field_fraction"].get<double>(), 0.0) << "envelope poses stay inside the fields";
  }
  EXPECT_EQ(j["renderers"][2]["name"], "lightfield-float");
  EXPECT_EQ(j["renderers"][2]["bytes"].get<std::size_t>(), 2u * 4 * 4 * 32 * 32 * 4);
  EXPECT_EQ(j["renderers"][3]["name"], "lightfield-float-per-ray");
  EXPECT_NEAR(j["renderers"][3]["ncc_vs_siddon"].get<double>(), j["renderers"][2]["ncc_vs_siddon"].get<double>(),
              1e-4);
  EXPECT_GT(j["light_field"]["precompute_s_all_views"].get<double>(), 0.0);
  if (o.peers) {
    ASSERT_EQ(j["peers"].size(), 1u);
    EXPECT_EQ(j["peers"][0]["name"], "plastimatch");
    EXPECT_GT(j["peers"][0]["ncc_vs_siddon"].get<double>(), 0.999);
  }
}

TEST(DrrBenchmark, EnvelopePosesStayInsideTheEnvelope) {
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok());
  PreparedScene p;
  p.scene = *scene;
  p.registration_origin_ct_mm = Eigen::Vector3d(1, 2, 3);
  p.nominal_T_room_from_ct.translation() = -p.registration_origin_ct_mm;
  const auto poses = sample_envelope_poses(p, 50, 3);
  ASSERT_EQ(poses.size(), 50u);
  EXPECT_TRUE(poses[0].isApprox(p.nominal_T_room_from_ct));
  for (const auto& pose : poses) {
    const auto d = tracking::delta_between(p.nominal_T_room_from_ct, pose, p.registration_origin_room_mm());
    EXPECT_LE(d.translation_mm.cwiseAbs().maxCoeff(), p.scene.envelope.translation_mm + 1e-9);
    EXPECT_LE(d.rotation_rad.cwiseAbs().maxCoeff(),
              tracking::deg_to_rad(p.scene.envelope.rotation_deg) + 1e-9);
  }
}

}  // namespace
}  // namespace lftrack::session

// The scene-level registration helpers on the built-in phantom: markers inserted by the
// simulator, found in synthetic frames and triangulated; preprocessing of whole-detector frames.

#include "lftrack/session/scene_registration.hpp"

#include <gtest/gtest.h>

#include "lftrack/sim_devices/scene_sim_frames.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::session {

using sim_devices::scene_detector_model;
using sim_devices::synthesize_scene_frames;
namespace {

using tracking::Pose;

struct PhantomWithMarker {
  PreparedScene prepared;
  Eigen::Vector3d marker_ct_mm;
};

const PhantomWithMarker& phantom_with_marker() {
  static const PhantomWithMarker p = [] {
    tracking::ThreadPool pool(0);
    Scene scene = *load_scene(kBuiltinPhantom);
    const PreparedScene plain = *prepare_scene(scene, "", &pool);
    PhantomWithMarker out;
    out.marker_ct_mm = plain.registration_origin_ct_mm + Eigen::Vector3d(12, 10, 6);  // a pedicle, roughly
    scene.fiducials.positions_ct_mm = {out.marker_ct_mm};
    scene.fiducials.radius_mm = 1.0;
    scene.fiducials.insert = true;
    out.prepared = *prepare_scene(scene, "", &pool);
    return out;
  }();
  return p;
}

TEST(SceneRegistration, InsertedMarkerIsFoundAndTriangulatedFromSyntheticFrames) {
  const PhantomWithMarker& p = phantom_with_marker();
  // The CT shows the marker clipped at the scanner's top value; the anatomy the frames come
  // from holds steel.
  const auto index = p.prepared.ct->geometry.index_from_ct() * p.marker_ct_mm;
  const Eigen::Vector3i voxel = index.array().round().cast<int>();
  EXPECT_GT(p.prepared.ct->at(voxel.x(), voxel.y(), voxel.z()), 2000.f);
  EXPECT_GT(p.prepared.world_mu->at(voxel.x(), voxel.y(), voxel.z()), 0.3f);

  tracking::ThreadPool pool(0);
  tracking::RendererOptions options;
  options.pool = &pool;
  auto exact = std::move(tracking::make_renderer("siddon", p.prepared.world_mu, options)).value();
  const Pose gold = *pose_from_nominal_delta(p.prepared, {2, -1, 1.5, 1, -1, 0.5});
  auto raw = synthesize_scene_frames(p.prepared, *exact, gold, 5);
  ASSERT_TRUE(raw.ok()) << raw.status().message();
  auto frames = preprocess_scene_frames(p.prepared, *raw, sim::detector_correction(scene_detector_model(p.prepared)));
  ASSERT_TRUE(frames.ok()) << frames.status().message();
  // Search from a start 6 mm and 3 degrees away from the gold pose.
  const Pose start = *pose_from_nominal_delta(p.prepared, {-4, 3, -2, -2, 1, -1});
  auto located = locate_fiducial(p.prepared, *frames, start, 0.05);
  ASSERT_TRUE(located.ok()) << located.status().message();
  EXPECT_LT((located->term.marker_room_mm - gold * p.marker_ct_mm).norm(), 0.5);
  EXPECT_LT(located->gap_mm, 0.5);
  EXPECT_EQ(located->pixels.size(), 2u);
}

TEST(SceneRegistration, FramesOfTheWrongShapeOrCountAreRefused) {
  const PhantomWithMarker& p = phantom_with_marker();
  const tracking::DetectorCorrection correction;
  std::vector<tracking::Image<std::uint16_t>> one(1, tracking::Image<std::uint16_t>(512, 512, 1000));
  EXPECT_FALSE(preprocess_scene_frames(p.prepared, one, correction).ok());
  std::vector<tracking::Image<std::uint16_t>> small(2, tracking::Image<std::uint16_t>(100, 100, 1000));
  auto r = preprocess_scene_frames(p.prepared, small, correction);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("the detector 512 x 512"), std::string::npos) << r.status().message();
  EXPECT_FALSE(pose_from_nominal_delta(p.prepared, {1, 2, 3}).ok());
  EXPECT_FALSE(pose_from_nominal_delta(p.prepared, {1, 2, 3, 4, 5, NAN}).ok());
}

TEST(SceneRegistration, NominalDeltaRoundTrips) {
  const PhantomWithMarker& p = phantom_with_marker();
  const std::vector<double> d = {1.5, -2, 3, 2, -1, 0.5};
  const auto back = nominal_delta_of(p.prepared, *pose_from_nominal_delta(p.prepared, d));
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(back[std::size_t(i)], d[std::size_t(i)], 1e-9);
}

}  // namespace
}  // namespace lftrack::session

#include "lftrack/phantom/spine_phantom.hpp"

#include <gtest/gtest.h>

#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::phantom {
namespace {

SpinePhantomOptions small() {
  SpinePhantomOptions o;
  o.size = {160, 160, 96};
  o.spacing_mm = {2.0, 2.0, 2.0};
  o.centre_mm = {0, 20, -350};
  return o;
}

float hu_at(const SpinePhantom& p, const Eigen::Vector3d& x_ct) {
  const Eigen::Vector3d idx = p.ct.geometry.index_from_ct() * x_ct;
  return p.ct.at(int(std::lround(idx.x())), int(std::lround(idx.y())), int(std::lround(idx.z())));
}

TEST(SpinePhantom, SameSeedSameVolumeWhateverTheThreads) {
  tracking::ThreadPool pool(3);
  auto a = make_spine_phantom(small(), nullptr);
  auto b = make_spine_phantom(small(), &pool);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->ct.values, b->ct.values);
  SpinePhantomOptions other = small();
  other.seed = 2;
  auto c = make_spine_phantom(other, &pool);
  ASSERT_TRUE(c.ok());
  EXPECT_NE(a->ct.values, c->ct.values);
}

TEST(SpinePhantom, AnatomyHasRealisticHounsfieldUnits) {
  SpinePhantomOptions o = small();
  o.noise_hu = 0;
  auto p = make_spine_phantom(o);
  ASSERT_TRUE(p.ok());
  ASSERT_GE(p->vertebral_body_centres_mm.size(), 2u);
  const Eigen::Vector3d body = p->vertebral_body_centres_mm[std::size_t(p->target_vertebra)];
  EXPECT_NEAR(hu_at(*p, body), 220, 120) << "cancellous bone";
  float end_plate = -1000;  // the densest voxel on the body's axis: the cortical end plate
  for (double dz = 8; dz < 16; dz += 0.5)
    end_plate = std::max(end_plate, hu_at(*p, body + Eigen::Vector3d(0, 0, dz)));
  EXPECT_GT(end_plate, 600) << "cortical end plate";
  EXPECT_LT(hu_at(*p, body + Eigen::Vector3d(0, 0, 17.0)), 200) << "disc";
  EXPECT_NEAR(hu_at(*p, o.centre_mm + Eigen::Vector3d(150, -150, 0)), -1000, 1) << "air outside the body";
  EXPECT_NEAR(hu_at(*p, body + Eigen::Vector3d(0, -60, 0)), 40, 40) << "soft tissue anterior to the spine";
  // Vertebrae are stacked along z, one level apart.
  for (std::size_t n = 1; n < p->vertebral_body_centres_mm.size(); ++n) {
    const double dz = p->vertebral_body_centres_mm[n].z() - p->vertebral_body_centres_mm[n - 1].z();
    EXPECT_NEAR(dz, 34.0, 3.0);
  }
}

TEST(SpinePhantom, RejectsGridsTooSmallForAVertebra) {
  SpinePhantomOptions o = small();
  o.size = {20, 20, 10};
  EXPECT_FALSE(make_spine_phantom(o).ok());
  o = small();
  o.spacing_mm.x() = 0;
  EXPECT_FALSE(make_spine_phantom(o).ok());
}

}  // namespace
}  // namespace lftrack::phantom

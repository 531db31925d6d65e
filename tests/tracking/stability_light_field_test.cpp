// Numerical stability at the extremes: light fields (docs/stability.md, "Light fields"). Queries
// on, just inside and just outside the field's bounds in every storage mode; a field of one
// sample per axis.

#include <gtest/gtest.h>

#include <cmath>

#include "fixtures.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/light_field.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

// A one-pixel view with the field's own source whose single ray passes through (s, t) on the
// field's (s, t) plane at the nominal pose (u = v = 0, inside the field).
XrayView ray_through(const LightField& field, double s, double t) {
  const LightField::Header& h = field.header();
  const LightFieldGeometry& g = h.geometry;
  const Pose& T = h.nominal_T_room_from_ct;
  const Vector3d source = T * g.source_ct_mm;
  const Vector3d on_st = T * (g.roi_centre_ct_mm + s * g.e1 + t * g.e2);
  XrayView v;
  v.name = g.view_name;
  v.source_mm = source;
  v.pixel00_mm = source + 2.0 * (on_st - source);
  v.col_axis = T.linear() * g.e1;
  v.row_axis = T.linear() * g.e2;
  v.pitch_col_mm = v.pitch_row_mm = 0.1;
  v.rows = v.cols = 1;
  return v;
}

struct Query {
  float value = -1;
  bool valid = false;
};

Query query(const DrrRenderer& r, const LightField& field, double s, double t) {
  const XrayView view = ray_through(field, s, t);
  Image<float> out(1, 1, -1.0f);
  Image<unsigned char> valid(1, 1, 7);
  RenderExtras extras;
  extras.valid = valid.view();
  const Status status =
      r.render(field.header().nominal_T_room_from_ct, view, PixelWindow::full(1, 1), out.view(), &extras);
  EXPECT_TRUE(status.ok()) << status.message();
  return {out.at(0, 0), valid.at(0, 0) == 1};
}

class StorageAtTheBounds : public ::testing::TestWithParam<LightFieldStorage> {};

TEST_P(StorageAtTheBounds, OnJustInsideAndJustOutsideTheBounds) {
  const auto field = test::fixture_light_field(GetParam());
  RendererOptions options;
  options.light_fields = {field};
  auto renderer = make_renderer("lightfield", nullptr, options);
  ASSERT_TRUE(renderer.ok()) << renderer.status().message();
  const LightFieldGeometry& g = field->geometry();
  for (int a : {2, 3}) {  // s and t
    for (double bound : {g.lo[std::size_t(a)], g.hi[std::size_t(a)]}) {
      const double outward = bound == g.lo[std::size_t(a)] ? -1 : 1;
      const double step = g.spacing(a);
      for (double offset : {-1e-3 * step, 0.0, 1e-2 * step, 0.5 * step}) {
        const double coordinate = bound + outward * offset;
        const Query q =
            a == 2 ? query(**renderer, *field, coordinate, 0.0) : query(**renderer, *field, 0.0, coordinate);
        ASSERT_TRUE(std::isfinite(q.value)) << "axis " << a << " offset " << offset;
        if (offset < 0) {
          EXPECT_TRUE(q.valid) << "just inside: interpolated";
          EXPECT_GE(q.value, 0.0f);
        } else if (offset > 0) {
          EXPECT_FALSE(q.valid) << "just outside: masked";
        }
        if (!q.valid) {
          EXPECT_EQ(q.value, 0.0f) << "masked pixels are 0, never clamped values";
        }
        // Exactly on the bound float rounding decides; either answer is defined.
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Stability, StorageAtTheBounds,
                         ::testing::Values(LightFieldStorage::kFloat32, LightFieldStorage::kFixed16,
                                           LightFieldStorage::kVq),
                         [](const auto& p) { return std::string(to_string(p.param)); });

TEST(StabilityLightField, OneSamplePerAxisIsRefused) {
  LightFieldSpec spec;
  spec.resolution = {1, 1, 1, 1};
  auto field = LightField::build(*test::fixture_volume(), test::fixture_plan(), spec, nullptr);
  ASSERT_FALSE(field.ok());
  EXPECT_NE(field.status().message().find("2..4096"), std::string::npos) << field.status().message();
  spec.resolution = {2, 2, 2, 2};  // the smallest field builds and renders finite values
  auto smallest = LightField::build(*test::fixture_volume(), test::fixture_plan(), spec, nullptr);
  ASSERT_TRUE(smallest.ok()) << smallest.status().message();
  RendererOptions options;
  options.light_fields = {*smallest};
  auto renderer = make_renderer("lightfield", nullptr, options);
  ASSERT_TRUE(renderer.ok());
  const XrayView view = test::fixture_view();
  Image<float> drr(view.rows, view.cols);
  ASSERT_TRUE(
      (*renderer)->render(Pose::Identity(), view, PixelWindow::full(view.rows, view.cols), drr.view()).ok());
  for (float p : drr.pixels()) ASSERT_TRUE(std::isfinite(p) && p >= 0);
}

}  // namespace
}  // namespace lftrack::tracking

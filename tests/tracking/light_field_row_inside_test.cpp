// The light-field kernels' row test (tracking/src/light_field_row_inside.cpp, private to the
// renderer): a block of rows judged from its four corner rays (rows_inside_field) may only say
// "inside" where the row test says so for every row of the block, and must say it for the usual
// render, a window well inside the field.

#include <gtest/gtest.h>

#include <random>

#include "../../tracking/src/light_field_kernels.hpp"

namespace lftrack::tracking {
namespace {

// A field of 16 x 16 x 256 x 256 samples, axis z, and the map of a `rows` x `cols` window whose
// rays from a source 1,000 mm before the (s, t) plane spread over `spread` of the plane's
// samples, centred `offset` samples off its middle and turned by `tilt` radians.
struct Case {
  LightFieldGeometry g;
  RayMap m;
};

Case make_case(double spread, double offset_s, double offset_t, double tilt, int rows, int cols, double slant = 0) {
  Case k;
  k.g.size = {16, 16, 256, 256};
  const double st_per_mm = 1.0;  // (s, t) samples per mm on the plane 1,000 mm away
  for (int a = 0; a < 4; ++a) {
    k.m.base[a] = a < 2 ? 7.5f : float(127.5 + (a == 2 ? offset_s : offset_t));
    k.m.gain[a] = a < 2 ? 0.5f : float(1000.0 * st_per_mm);
    k.m.limit[a] = float(k.g.size[a] - 1);
  }
  // Ray directions (not normalised): q1 = d.x / d.z and q2 = d.y / d.z.
  const double per_pixel = spread / (1000.0 * st_per_mm * std::max(rows, cols));
  // `slant` tilts the window out of the plane: the rays' n then changes across it.
  const Eigen::Vector3d row_dir(std::cos(tilt), std::sin(tilt), 0.02 * tilt + slant);
  const Eigen::Vector3d col_dir(-std::sin(tilt), std::cos(tilt), -0.03 * tilt);
  k.m.d_row = row_dir * per_pixel;
  k.m.d_col = col_dir * per_pixel;
  k.m.d00 = Eigen::Vector3d(0, 0, 1) - k.m.d_row * (0.5 * (rows - 1)) - k.m.d_col * (0.5 * (cols - 1));
  return k;
}

TEST(RowsInsideField, ABlockIsInsideOnlyWhereEveryRowIs) {
  std::mt19937_64 random(5);
  std::uniform_real_distribution<double> unit(0, 1);
  int blocks_inside = 0, blocks_judged = 0, rows_all_inside_but_block_not = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    const int rows = 1 + int(unit(random) * 300), cols = 1 + int(unit(random) * 300);
    // Windows from well inside to far across the field's edge (its half-width is 127.5 samples).
    const double spread = 20 + 260 * unit(random);
    const Case k = make_case(spread, 140 * (unit(random) - 0.5), 140 * (unit(random) - 0.5),
                             3.0 * (unit(random) - 0.5), rows, cols);
    const int r_first = int(unit(random) * rows);
    const int r_last = r_first + int(unit(random) * (rows - r_first));
    bool every_row = true;
    for (int r = r_first; r <= r_last; ++r) every_row = every_row && row_inside_field(k.g, k.m, r, cols);
    const bool block = rows_inside_field(k.g, k.m, r_first, r_last, cols);
    ++blocks_judged;
    blocks_inside += block;
    rows_all_inside_but_block_not += every_row && !block;
    ASSERT_TRUE(!block || every_row) << "trial " << trial << ": the block says inside, a row does not";
  }
  // Not vacuous: many blocks inside, many not.
  EXPECT_GT(blocks_inside, blocks_judged / 5);
  EXPECT_LT(blocks_inside, blocks_judged * 4 / 5);
  // The corner bounds cost little: a block whose rows all pass is nearly always passed whole.
  EXPECT_LT(rows_all_inside_but_block_not, blocks_judged / 50);
}

// Where it matters: within a few thousandths of a sample of where the first row leaves the
// field, each margin term counts. Found by bisection on the field's s offset for each block,
// then stepped across in 2e-5 sample steps (a few float epsilons of the offset).
TEST(RowsInsideField, AtTheFieldsEdgeABlockIsNeverInsideWhereARowIsNot) {
  std::mt19937_64 random(11);
  std::uniform_real_distribution<double> unit(0, 1);
  int near_edge = 0, block_inside_near_edge = 0;
  for (int trial = 0; trial < 150; ++trial) {
    const int rows = 2 + int(unit(random) * 60), cols = 1 + int(unit(random) * 60);
    Case k = make_case(20 + 200 * unit(random), 0, 40 * (unit(random) - 0.5), 3.0 * (unit(random) - 0.5), rows,
                       cols, 0.6 * (unit(random) - 0.5));
    const int r_first = int(unit(random) * rows / 2), r_last = r_first + int(unit(random) * (rows - r_first));
    const auto every_row = [&](double base_s) {
      k.m.base[2] = float(base_s);
      for (int r = r_first; r <= r_last; ++r)
        if (!row_inside_field(k.g, k.m, r, cols)) return false;
      return true;
    };
    double inside = k.m.base[2], outside = inside + 300;
    if (!every_row(inside) || every_row(outside)) continue;
    for (int i = 0; i < 60; ++i) {
      const double mid = 0.5 * (inside + outside);
      (every_row(mid) ? inside : outside) = mid;
    }
    for (int j = -150; j <= 150; ++j) {
      const bool rows_ok = every_row(inside + 2e-5 * j);  // sets base[2]
      const bool block = rows_inside_field(k.g, k.m, r_first, r_last, cols);
      ASSERT_TRUE(!block || rows_ok) << "trial " << trial << ", " << j << " steps from the edge";
      ++near_edge;
      block_inside_near_edge += block;
    }
  }
  EXPECT_GT(near_edge, 20000);
  // The block's bounds are a little wider than each row's, but it reaches the edge's last
  // thousandths of a sample too (else this test would say nothing about the margins).
  EXPECT_GT(block_inside_near_edge, near_edge / 5);
}

TEST(RowsInsideField, AWindowWellInsideIsOneBlockAndAWindowOverTheEdgeIsNot) {
  const Case inside = make_case(150, 10, -20, 0.3, 256, 256);
  EXPECT_TRUE(rows_inside_field(inside.g, inside.m, 0, 255, 256));
  const Case over = make_case(150, 60, 0, 0.3, 256, 256);  // 60 + 75 * 1.3 samples: past 127.5
  EXPECT_FALSE(rows_inside_field(over.g, over.m, 0, 255, 256));
  EXPECT_TRUE(row_inside_field(over.g, over.m, 128, 1)) << "the middle of the window's first column is inside";
  // No rows, no columns, rays that run away from the planes, NaN: never inside.
  EXPECT_FALSE(rows_inside_field(inside.g, inside.m, 5, 4, 256));
  EXPECT_FALSE(rows_inside_field(inside.g, inside.m, 0, 255, 0));
  Case away = inside;
  away.m.d00.z() = -1;
  EXPECT_FALSE(rows_inside_field(away.g, away.m, 0, 255, 256));
  Case nan = inside;
  nan.m.d_col.x() = std::nan("");
  EXPECT_FALSE(rows_inside_field(nan.g, nan.m, 0, 255, 256));
}

}  // namespace
}  // namespace lftrack::tracking

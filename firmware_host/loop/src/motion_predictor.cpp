#include "lftrack/loop/motion_predictor.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>

#include "lftrack/loop/time_interval.hpp"

namespace lftrack::loop {
namespace {

// The normal equations of a fit of `order` (1 or 2) from the parabola's: a line's are their
// leading 2 x 2 block, its unused coefficient solving to zero. Null `rhs`: only the matrix.
Eigen::Matrix3d normal_of_order(const Eigen::Matrix3d& normal2, int order, Eigen::Matrix<double, 3, 6>* rhs) {
  Eigen::Matrix3d normal = normal2;
  if (order == 1) {
    normal.row(2).setZero();
    normal.col(2).setZero();
    normal(2, 2) = 1.0;
    if (rhs != nullptr) rhs->row(2).setZero();
  }
  return normal;
}

// A parabola's basis at dt (s, relative to the newest estimate): the normal equations of every
// fit are sums of its outer products.
Eigen::Vector3d parabola_basis(double dt) { return {1.0, dt, dt * dt}; }

// The first order predict() tries with `count` estimates: the configured one where there are
// enough estimates to smooth it (order + 2), else a line; it then drops while the gain is too high.
int first_order_to_try(int count, int order) { return count >= order + 2 ? order : 1; }

// The fit's prediction at h is a weighted sum of the estimates, w = at' N^-1 B'; with independent
// noise of one deviation in each, its deviation is |w| = sqrt(at' N^-1 at) times that.
Eigen::Vector3d evaluation_at(double h, int order) { return {1.0, h, order == 2 ? h * h : 0.0}; }
double noise_gain(const Eigen::Matrix3d& inverse, double h, int order) {
  const Eigen::Vector3d at = evaluation_at(h, order);
  return std::sqrt(at.dot(inverse * at));
}

}  // namespace

MotionPredictor::MotionPredictor(int window, int order, double lookahead_s, bool predict_rotations)
    : window_(std::clamp(window, 0, kCapacity)),
      order_(std::clamp(order, 1, 2)),
      lookahead_s_(lookahead_s),
      predict_rotations_(predict_rotations) {}

void MotionPredictor::add(std::int64_t t_ns, const tracking::Vector6d& offset) {
  const int keep = std::max(1, window_);
  if (count_ == keep) {
    std::move(t_ns_.begin() + 1, t_ns_.begin() + count_, t_ns_.begin());
    std::move(x_.begin() + 1, x_.begin() + count_, x_.begin());
    --count_;
  }
  t_ns_[std::size_t(count_)] = t_ns;
  x_[std::size_t(count_)] = offset;
  ++count_;
}

tracking::Vector6d MotionPredictor::predict() const {
  if (count_ == 0) return tracking::Vector6d::Zero();
  const tracking::Vector6d& newest = x_[std::size_t(count_ - 1)];
  if (window_ < 2 || count_ < 2) return newest;
  // Times relative to the newest estimate keep the normal equations well conditioned (ns_between:
  // exact differences).
  const std::int64_t t0_ns = t_ns_[std::size_t(count_ - 1)];
  // The normal equations of the parabola, once; a line's are their leading 2 x 2 block.
  Eigen::Matrix3d normal2 = Eigen::Matrix3d::Zero();
  Eigen::Matrix<double, 3, 6> rhs2 = Eigen::Matrix<double, 3, 6>::Zero();
  for (int i = 0; i < count_; ++i) {
    const double dt = 1e-9 * ns_between(t0_ns, t_ns_[std::size_t(i)]);  // s
    const Eigen::Vector3d basis = parabola_basis(dt);
    normal2 += basis * basis.transpose();
    rhs2 += basis * x_[std::size_t(i)].transpose();
  }
  const double h = lookahead_s_;
  // The configured order first, then a line: the first whose noise gain is within the bound.
  for (int order = first_order_to_try(count_, order_); order >= 1; --order) {
    Eigen::Matrix<double, 3, 6> rhs = rhs2;
    const Eigen::Matrix3d inverse = normal_of_order(normal2, order, &rhs).inverse();
    if (!inverse.allFinite()) continue;
    if (!(noise_gain(inverse, h, order) <= kMaxNoiseGain)) continue;
    tracking::Vector6d predicted = (evaluation_at(h, order).transpose() * (inverse * rhs)).transpose();
    if (!predict_rotations_) predicted.tail<3>() = newest.tail<3>();  // the header says why
    if (predicted.allFinite()) return predicted;
  }
  return newest;
}

MotionPredictor::FullWindow MotionPredictor::full_window(int window, int order, double period_s, double lookahead_s) {
  FullWindow out;
  const int n = std::clamp(window, 0, kCapacity);
  order = std::clamp(order, 1, 2);
  if (n < 2 || !(period_s > 0)) return out;  // no prediction: the newest estimate, gain 1
  Eigen::Matrix3d normal2 = Eigen::Matrix3d::Zero();
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d basis = parabola_basis(-period_s * double(n - 1 - i));
    normal2 += basis * basis.transpose();
  }
  const auto gain = [&](int k) {
    const Eigen::Matrix3d inverse = normal_of_order(normal2, k, nullptr).inverse();
    return inverse.allFinite() ? noise_gain(inverse, lookahead_s, k) : INFINITY;
  };
  // Too few estimates for the order (predict() never fits it): no gain of its own.
  const int first = first_order_to_try(n, order);
  out.gain_configured = first == order ? gain(order) : INFINITY;
  for (int k = first; k >= 1; --k) {
    const double g = gain(k);
    if (g <= kMaxNoiseGain) {
      out.order_used = k;
      out.gain_used = g;
      return out;
    }
  }
  return out;
}

}  // namespace lftrack::loop

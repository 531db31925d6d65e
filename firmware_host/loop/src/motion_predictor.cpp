#include "lftrack/loop/motion_predictor.hpp"

#include <Eigen/Dense>
#include <algorithm>

#include "lftrack/loop/time_interval.hpp"

namespace lftrack::host {

MotionPredictor::MotionPredictor(int window, int order, double lookahead_s)
    : window_(std::clamp(window, 0, kCapacity)), order_(std::clamp(order, 1, 2)), lookahead_s_(lookahead_s) {}

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
    const Eigen::Vector3d basis(1.0, dt, dt * dt);
    normal2 += basis * basis.transpose();
    rhs2 += basis * x_[std::size_t(i)].transpose();
  }
  const double h = lookahead_s_;
  // The configured order first, then a line: the first whose noise gain is within the bound.
  for (int order = count_ >= order_ + 2 ? order_ : 1; order >= 1; --order) {
    Eigen::Matrix3d normal = normal2;
    Eigen::Matrix<double, 3, 6> rhs = rhs2;
    if (order == 1) {  // the unused coefficient solves to zero
      normal.row(2).setZero();
      normal.col(2).setZero();
      normal(2, 2) = 1.0;
      rhs.row(2).setZero();
    }
    const Eigen::Matrix3d inverse = normal.inverse();
    if (!inverse.allFinite()) continue;
    // The prediction is a weighted sum of the estimates, w = at' N^-1 B'; with independent noise
    // of one deviation in each, its deviation is |w| = sqrt(at' N^-1 at) times that.
    const Eigen::Vector3d at(1.0, h, order == 2 ? h * h : 0.0);
    if (!(at.dot(inverse * at) <= kMaxNoiseGain * kMaxNoiseGain)) continue;
    const tracking::Vector6d predicted = (at.transpose() * (inverse * rhs)).transpose();
    if (predicted.allFinite()) return predicted;
  }
  return newest;
}

}  // namespace lftrack::host

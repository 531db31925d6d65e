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
  const double h = lookahead_s_;
  const Eigen::Vector3d at(1.0, h, h * h);
  // The configured order first, then a line: the first whose noise gain is within the bound.
  for (int order = count_ >= order_ + 2 ? order_ : 1; order >= 1; --order) {
    Eigen::Matrix3d normal = Eigen::Matrix3d::Zero();
    Eigen::Matrix<double, 3, 6> rhs = Eigen::Matrix<double, 3, 6>::Zero();
    for (int i = 0; i < count_; ++i) {
      const double dt = 1e-9 * ns_between(t0_ns, t_ns_[std::size_t(i)]);  // s
      const Eigen::Vector3d basis(1.0, dt, order == 2 ? dt * dt : 0.0);
      normal += basis * basis.transpose();
      rhs += basis * x_[std::size_t(i)].transpose();
    }
    if (order == 1) normal(2, 2) = 1.0;  // the unused coefficient solves to zero
    const Eigen::Matrix3d inverse = normal.inverse();
    if (!inverse.allFinite()) continue;
    // The prediction is a weighted sum of the estimates, w = at' N^-1 B'; with independent noise
    // of one deviation in each, its deviation is |w| = sqrt(at' N^-1 at) times that.
    const Eigen::Vector3d at_used(1.0, h, order == 2 ? h * h : 0.0);
    const double noise_gain_squared = at_used.dot(inverse * at_used);
    if (!(noise_gain_squared <= kMaxNoiseGain * kMaxNoiseGain)) continue;
    const Eigen::Matrix<double, 3, 6> coefficients = inverse * rhs;
    const tracking::Vector6d predicted = (at_used.transpose() * coefficients).transpose();
    if (predicted.allFinite()) return predicted;
  }
  return newest;
}

}  // namespace lftrack::host

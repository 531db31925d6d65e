#include "lftrack/calib/couch_calibration.hpp"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Dense>
#include <cmath>

namespace lftrack::calib {

using tracking::Vector6d;

Eigen::Isometry3d couch_motion(const Vector6d& q) {
  Eigen::Isometry3d e = Eigen::Isometry3d::Identity();
  e.linear() = tracking::rotation_exp(q.tail<3>());
  e.translation() = q.head<3>();
  return e;
}

Eigen::Isometry3d room_motion_of_couch(const Eigen::Isometry3d& x, const Vector6d& q) {
  return x * couch_motion(q) * x.inverse();
}

Vector6d couch_move_for(const Eigen::Isometry3d& x, const Eigen::Isometry3d& room_motion) {
  const Eigen::Isometry3d e = x.inverse() * room_motion * x;
  Vector6d q;
  q.head<3>() = e.translation();
  q.tail<3>() = tracking::rotation_log(e.linear());
  return q;
}

namespace {

constexpr double kRotationScaleMm = 100;  // a 1 rad rotation vector weighs like 100 mm of travel

// Residual of one box point in one move: X E(q) X^-1 p - A p, X = exp(w) (rotation) + c.
struct BoxPointResidual {
  BoxPointResidual(const Vector6d& q, const Eigen::Vector3d& p, const Eigen::Vector3d& ap)
      : move(q), point(p), moved(ap) {}
  template <class T>
  bool operator()(const T* w, const T* c, T* r) const {
    // X^-1 p = R^T (p - c)
    const T d[3] = {T(point.x()) - c[0], T(point.y()) - c[1], T(point.z()) - c[2]};
    const T minus_w[3] = {-w[0], -w[1], -w[2]};
    T local[3];
    ceres::AngleAxisRotatePoint(minus_w, d, local);
    // E(q) local = exp(omega) local + t
    const T omega[3] = {T(move(3)), T(move(4)), T(move(5))};
    T turned[3];
    ceres::AngleAxisRotatePoint(omega, local, turned);
    for (int k = 0; k < 3; ++k) turned[k] += T(move(k));
    // X (.) = R (.) + c
    T room[3];
    ceres::AngleAxisRotatePoint(w, turned, room);
    for (int k = 0; k < 3; ++k) r[k] = room[k] + c[k] - T(moved(k));
    return true;
  }
  Vector6d move;
  Eigen::Vector3d point, moved;
};

}  // namespace

Result<CouchCalibration> solve_couch_calibration(const tracking::Pose& zero,
                                                 const std::vector<CouchObservation>& moves,
                                                 const Eigen::Vector3d& box_centre, double box_mm,
                                                 const Eigen::Vector3d& centre_guess) {
  if (moves.size() < 3) {
    return invalid_argument("couch calibration: needs at least 3 moves, has " + std::to_string(moves.size()));
  }
  if (!(box_mm > 0) || !box_centre.allFinite() || !centre_guess.allFinite()) {
    return invalid_argument("couch calibration: box and centre must be finite, box size positive");
  }
  std::vector<Eigen::Isometry3d> room_moves;
  for (const CouchObservation& m : moves) {
    if (!m.couch_position.allFinite() || !m.T_room_from_object.matrix().allFinite()) {
      return invalid_argument("couch calibration: a move or a measured pose is not finite");
    }
    room_moves.push_back(m.T_room_from_object * zero.inverse());
  }
  // Closed form: rotation from paired directions.
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
  int rotating = 0;
  for (std::size_t i = 0; i < moves.size(); ++i) {
    const Vector6d& q = moves[i].couch_position;
    const Eigen::Vector3d a_rot = tracking::rotation_log(room_moves[i].linear());
    if (q.tail<3>().norm() > 1e-4) {
      h += kRotationScaleMm * kRotationScaleMm * q.tail<3>() * a_rot.transpose();
      ++rotating;
    } else {
      h += q.head<3>() * room_moves[i].translation().transpose();
    }
  }
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  if (svd.singularValues()(1) < 1e-6 * std::max(svd.singularValues()(0), 1e-12)) {
    return invalid_argument(
        "couch calibration: the moves span fewer than two directions; move along (or rotate about) at least "
        "two "
        "different axes");
  }
  Eigen::Matrix3d fix = Eigen::Matrix3d::Identity();
  fix(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1 : 1;
  const Eigen::Matrix3d rotation0 = svd.matrixV() * fix * svd.matrixU().transpose();  // room_from_couch
  // Centre: (I - R_A) c = t_A - R_X t_B over the rotating moves.
  Eigen::Vector3d centre0 = centre_guess;
  bool centre_determined = false;
  if (rotating >= 2) {
    Eigen::MatrixXd a(3 * rotating, 3);
    Eigen::VectorXd b(3 * rotating);
    int row = 0;
    for (std::size_t i = 0; i < moves.size(); ++i) {
      if (moves[i].couch_position.tail<3>().norm() <= 1e-4) continue;
      a.block<3, 3>(row, 0) = Eigen::Matrix3d::Identity() - room_moves[i].linear();
      b.segment<3>(row) = room_moves[i].translation() - rotation0 * moves[i].couch_position.head<3>();
      row += 3;
    }
    const Eigen::JacobiSVD<Eigen::MatrixXd> lsq(a, Eigen::ComputeThinU | Eigen::ComputeThinV);
    if (lsq.singularValues()(2) > 1e-6 * lsq.singularValues()(0)) {
      centre0 = lsq.solve(b);
      centre_determined = true;
    }
  }

  // Ceres refinement.
  Eigen::Vector3d w = tracking::rotation_log(rotation0);
  Eigen::Vector3d c = centre0;
  ceres::Problem problem;
  std::vector<Eigen::Vector3d> box;
  for (int k = 0; k < 8; ++k) {
    box.push_back(box_centre +
                  0.5 * box_mm * Eigen::Vector3d(k & 1 ? 1 : -1, k & 2 ? 1 : -1, k & 4 ? 1 : -1));
  }
  for (std::size_t i = 0; i < moves.size(); ++i) {
    for (const Eigen::Vector3d& p : box) {
      auto* cost = new ceres::AutoDiffCostFunction<BoxPointResidual, 3, 3, 3>(
          new BoxPointResidual(moves[i].couch_position, p, room_moves[i] * p));
      problem.AddResidualBlock(cost, new ceres::HuberLoss(0.5), w.data(), c.data());
    }
  }
  if (!centre_determined) problem.SetParameterBlockConstant(c.data());
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = 100;
  options.function_tolerance = 1e-14;
  options.parameter_tolerance = 1e-14;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  if (!summary.IsSolutionUsable() || !w.allFinite() || !c.allFinite()) {
    return internal_error("couch calibration: the solver did not converge: " + summary.message);
  }
  CouchCalibration out;
  out.T_room_from_couch.linear() = tracking::rotation_exp(w);
  out.T_room_from_couch.translation() = c;
  out.centre_determined = centre_determined;
  double total = 0;
  for (std::size_t i = 0; i < moves.size(); ++i) {
    const Eigen::Isometry3d predicted = room_motion_of_couch(out.T_room_from_couch, moves[i].couch_position);
    double se = 0;
    for (const Eigen::Vector3d& p : box) se += (predicted * p - room_moves[i] * p).squaredNorm();
    out.move_rms_mm.push_back(std::sqrt(se / 8));
    total += se;
  }
  out.rms_mm = std::sqrt(total / double(8 * moves.size()));
  // Standard deviations: the covariance scaled by the residuals' variance.
  ceres::Covariance::Options copt;
  copt.algorithm_type = ceres::DENSE_SVD;
  copt.min_reciprocal_condition_number = 1e-30;
  ceres::Covariance covariance(copt);
  std::vector<std::pair<const double*, const double*>> blocks = {{w.data(), w.data()}};
  if (centre_determined) blocks.emplace_back(c.data(), c.data());
  if (covariance.Compute(blocks, &problem)) {
    const double dof = double(3 * 8 * moves.size()) - (centre_determined ? 6.0 : 3.0);
    const double variance = dof > 0 ? 2 * summary.final_cost / dof : 0;
    Eigen::Matrix3d cw, cc;
    if (covariance.GetCovarianceBlock(w.data(), w.data(), cw.data())) {
      out.rotation_sd_deg =
          (cw.diagonal() * variance).cwiseMax(0).cwiseSqrt() * (180 / 3.14159265358979323846);
    }
    if (centre_determined && covariance.GetCovarianceBlock(c.data(), c.data(), cc.data())) {
      out.centre_sd_mm = (cc.diagonal() * variance).cwiseMax(0).cwiseSqrt();
    }
  }
  return out;
}

}  // namespace lftrack::calib

#include "lftrack/calib/view_calibration.hpp"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "lftrack/tracking/pose.hpp"

namespace lftrack::calib {

using tracking::Matrix34d;
using tracking::XrayView;

namespace {

// ---- DLT ------------------------------------------------------------------------------------

// Similarity transform that moves points to zero mean and mean distance sqrt(dim).
template <int D>
Eigen::Matrix<double, D + 1, D + 1> normaliser(const std::vector<Eigen::Matrix<double, D, 1>>& points) {
  Eigen::Matrix<double, D, 1> mean = Eigen::Matrix<double, D, 1>::Zero();
  for (const auto& p : points) mean += p;
  mean /= double(points.size());
  double spread = 0;
  for (const auto& p : points) spread += (p - mean).norm();
  spread /= double(points.size());
  const double s = spread > 0 ? std::sqrt(double(D)) / spread : 1.0;
  Eigen::Matrix<double, D + 1, D + 1> t = Eigen::Matrix<double, D + 1, D + 1>::Identity();
  t.template topLeftCorner<D, D>() *= s;
  t.template topRightCorner<D, 1>() = -s * mean;
  return t;
}

// Thickness of a point set relative to its extent: sqrt(smallest / largest eigenvalue of its
// covariance). 0 for coplanar points.
double flatness(const std::vector<Eigen::Vector3d>& points) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points) mean += p;
  mean /= double(points.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : points) cov += (p - mean) * (p - mean).transpose();
  const Eigen::Vector3d ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvalues();
  return ev(2) > 0 ? std::sqrt(std::max(ev(0), 0.0) / ev(2)) : 0.0;
}

// ---- the camera model Ceres refines ---------------------------------------------------------
//
// Parameters: source s (3), rotation vector w (3) with detector axes R = exp(w) R0 (columns:
// col axis, row axis, beam = col x row, pointing from the source towards the detector),
// principal point (col, row) in pixels (2), focal length f in column pixels (1).
//   d = R^T (X - s);  col = pp_c + f d_x / d_z;  row = pp_r + f * aspect * d_y / d_z
// with aspect = pitch_col / pitch_row (fixed).
struct CameraModel {
  Eigen::Matrix3d axes0;  // R0
  double aspect = 1;
};

struct Reprojection {
  Reprojection(const CameraModel& m, const Eigen::Vector3d& x, const Eigen::Vector2d& px)
      : model(m), point(x), pixel(px) {}
  template <class T>
  bool operator()(const T* s, const T* w, const T* pp, const T* f, T* residual) const {
    const T d[3] = {T(point.x()) - s[0], T(point.y()) - s[1], T(point.z()) - s[2]};
    const T minus_w[3] = {-w[0], -w[1], -w[2]};
    T e[3];
    ceres::AngleAxisRotatePoint(minus_w, d, e);  // exp(w)^T d
    T c[3];
    for (int k = 0; k < 3; ++k) {
      c[k] = T(model.axes0(0, k)) * e[0] + T(model.axes0(1, k)) * e[1] + T(model.axes0(2, k)) * e[2];
    }
    residual[0] = pp[0] + f[0] * c[0] / c[2] - T(pixel.x());
    residual[1] = pp[1] + f[0] * T(model.aspect) * c[1] / c[2] - T(pixel.y());
    return true;
  }
  CameraModel model;
  Eigen::Vector3d point;
  Eigen::Vector2d pixel;
};

struct CameraParams {
  double s[3], w[3], pp[2], f[1];
  Eigen::Matrix<double, 9, 1> as_vector() const {
    Eigen::Matrix<double, 9, 1> v;
    v << s[0], s[1], s[2], w[0], w[1], w[2], pp[0], pp[1], f[0];
    return v;
  }
  static CameraParams from_vector(const Eigen::Matrix<double, 9, 1>& v) {
    return CameraParams{{v(0), v(1), v(2)}, {v(3), v(4), v(5)}, {v(6), v(7)}, {v(8)}};
  }
};

// The view with these parameters. `sdd_fixed_mm` > 0: the distance is fixed and the pitch
// follows (fit_pitch); otherwise the pitch is spec's and the distance follows.
XrayView view_of(const CameraParams& p, const CameraModel& m, const XrayView& spec, double sdd_fixed_mm) {
  XrayView v = spec;
  const Eigen::Matrix3d axes = tracking::rotation_exp(Eigen::Vector3d(p.w[0], p.w[1], p.w[2])) * m.axes0;
  v.col_axis = axes.col(0);
  v.row_axis = axes.col(1);
  const Eigen::Vector3d beam = axes.col(2);
  double sdd = 0;
  if (sdd_fixed_mm > 0) {
    sdd = sdd_fixed_mm;
    v.pitch_col_mm = sdd / p.f[0];
    v.pitch_row_mm = v.pitch_col_mm * spec.pitch_row_mm / spec.pitch_col_mm;
  } else {
    sdd = p.f[0] * spec.pitch_col_mm;
  }
  v.source_mm = Eigen::Vector3d(p.s[0], p.s[1], p.s[2]);
  v.pixel00_mm = v.source_mm + sdd * beam - p.pp[0] * v.pitch_col_mm * v.col_axis -
                 p.pp[1] * v.pitch_row_mm * v.row_axis;
  return v;
}

CameraParams params_of(const XrayView& v, CameraModel* model) {
  model->axes0 = v.detector_axes();
  model->aspect = v.pitch_col_mm / v.pitch_row_mm;
  CameraParams p{};
  for (int k = 0; k < 3; ++k) p.s[k] = v.source_mm(k);
  const Eigen::Vector3d beam = model->axes0.col(2);
  const double sdd = beam.dot(v.pixel00_mm - v.source_mm);
  const Eigen::Vector3d foot = v.source_mm + sdd * beam;
  p.pp[0] = v.col_axis.dot(foot - v.pixel00_mm) / v.pitch_col_mm;
  p.pp[1] = v.row_axis.dot(foot - v.pixel00_mm) / v.pitch_row_mm;
  p.f[0] = sdd / v.pitch_col_mm;
  return p;
}

// ---- correspondence -------------------------------------------------------------------------

struct Pair {
  int marker = -1;
  int detection = -1;
};

struct Predicted {
  int marker;
  Eigen::Vector2d px;
};

// Projections of the markers that land on the detector and do not overlap another's.
std::vector<Predicted> predict(const CalibrationPhantom& phantom, const XrayView& view,
                               double min_separation_px) {
  std::vector<Predicted> all;
  for (int i = 0; i < int(phantom.markers_mm.size()); ++i) {
    const auto px = view.project(phantom.markers_mm[std::size_t(i)]);
    if (!px) continue;
    if (px->x() < 0 || px->y() < 0 || px->x() > view.cols - 1 || px->y() > view.rows - 1) continue;
    all.push_back({i, *px});
  }
  std::vector<Predicted> kept;
  for (const Predicted& p : all) {
    bool overlaps = false;
    for (const Predicted& q : all)
      overlaps |= q.marker != p.marker && (q.px - p.px).norm() < min_separation_px;
    if (!overlaps) kept.push_back(p);
  }
  return kept;
}

// Mutual nearest neighbours within `gate` after shifting the predictions by `shift`; a pair whose
// second-nearest detection is within 1.5 times the nearest (and the gate) is ambiguous and
// skipped.
std::vector<Pair> pair_up(const std::vector<Predicted>& predicted,
                          const std::vector<MarkerDetection>& detections, const Eigen::Vector2d& shift,
                          double gate, int* ambiguous) {
  std::vector<Pair> pairs;
  *ambiguous = 0;
  for (std::size_t i = 0; i < predicted.size(); ++i) {
    const Eigen::Vector2d p = predicted[i].px + shift;
    int best = -1;
    double d1 = 1e300, d2 = 1e300;
    for (std::size_t j = 0; j < detections.size(); ++j) {
      const double d = (detections[j].pixel - p).norm();
      if (d < d1) {
        d2 = d1;
        d1 = d;
        best = int(j);
      } else if (d < d2) {
        d2 = d;
      }
    }
    if (best < 0 || d1 > gate) continue;
    if (d2 < gate && d2 < 1.5 * d1 + 1.0) {
      ++*ambiguous;
      continue;
    }
    // Mutual: no other prediction is nearer to this detection.
    bool mutual = true;
    for (std::size_t k = 0; k < predicted.size() && mutual; ++k) {
      mutual = k == i || (predicted[k].px + shift - detections[std::size_t(best)].pixel).norm() > d1;
    }
    if (mutual) pairs.push_back({predicted[i].marker, best});
  }
  return pairs;
}

struct ShiftVote {
  Eigen::Vector2d shift = Eigen::Vector2d::Zero();
  int votes = 0;
  int runner_up_votes = 0;
};

// The image shift that brings the most predictions within `gate` of a detection: every
// prediction/detection pair proposes one; each is scored over all predictions.
ShiftVote vote_for_shift(const std::vector<Predicted>& predicted,
                         const std::vector<MarkerDetection>& detections, double gate) {
  std::vector<std::pair<int, Eigen::Vector2d>> scored;
  for (const Predicted& p : predicted) {
    for (const MarkerDetection& d : detections) {
      const Eigen::Vector2d shift = d.pixel - p.px;
      int votes = 0;
      for (const Predicted& q : predicted) {
        const Eigen::Vector2d at = q.px + shift;
        for (const MarkerDetection& e : detections) {
          if ((e.pixel - at).squaredNorm() < 0.25 * gate * gate) {
            ++votes;
            break;
          }
        }
      }
      scored.emplace_back(votes, shift);
    }
  }
  ShiftVote out;
  for (const auto& [votes, shift] : scored) {
    if (votes > out.votes) {
      out.votes = votes;
      out.shift = shift;
    }
  }
  // The best shift that is clearly a different one (further than the gate from the winner).
  for (const auto& [votes, shift] : scored) {
    if ((shift - out.shift).norm() > gate) out.runner_up_votes = std::max(out.runner_up_votes, votes);
  }
  return out;
}

struct Fit {
  CameraParams params;
  double rms_px = 0;
  double cost = 0;
  Eigen::Matrix<double, 9, 9> covariance = Eigen::Matrix<double, 9, 9>::Zero();
  bool covariance_ok = false;
};

Result<Fit> refine(const CameraParams& start, const CameraModel& model,
                   const std::vector<Eigen::Vector3d>& points, const std::vector<Eigen::Vector2d>& pixels,
                   double huber_px, bool want_covariance) {
  Fit fit;
  fit.params = start;
  ceres::Problem problem;
  for (std::size_t i = 0; i < points.size(); ++i) {
    auto* cost = new ceres::AutoDiffCostFunction<Reprojection, 2, 3, 3, 2, 1>(
        new Reprojection(model, points[i], pixels[i]));
    problem.AddResidualBlock(cost, new ceres::HuberLoss(huber_px), fit.params.s, fit.params.w, fit.params.pp,
                             fit.params.f);
  }
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = 200;
  options.function_tolerance = 1e-14;
  options.gradient_tolerance = 1e-14;
  options.parameter_tolerance = 1e-14;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  if (!summary.IsSolutionUsable()) {
    return internal_error("view calibration: the solver did not converge: " + summary.message);
  }
  fit.cost = summary.final_cost;
  double se = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    double r[2];
    Reprojection(model, points[i], pixels[i])(fit.params.s, fit.params.w, fit.params.pp, fit.params.f, r);
    se += r[0] * r[0] + r[1] * r[1];
  }
  fit.rms_px = std::sqrt(se / double(points.size()));
  if (want_covariance) {
    ceres::Covariance::Options copt;
    copt.algorithm_type = ceres::DENSE_SVD;
    // Long focal lengths make detector tilt and principal point nearly interchangeable; the
    // covariance is then large, which is what it should say, not a reason to give none.
    copt.min_reciprocal_condition_number = 1e-30;
    ceres::Covariance covariance(copt);
    const std::vector<const double*> blocks = {fit.params.s, fit.params.w, fit.params.pp, fit.params.f};
    if (covariance.Compute(blocks, &problem)) {
      Eigen::Matrix<double, 9, 9, Eigen::RowMajor> c;
      if (covariance.GetCovarianceMatrix(blocks, c.data())) {
        // Ceres assumes unit-variance residuals; scale by the residuals' own variance.
        const double dof = double(2 * points.size()) - 9.0;
        const double variance = dof > 0 ? 2.0 * summary.final_cost / dof : 0.0;
        fit.covariance = c * variance;
        fit.covariance_ok = fit.covariance.allFinite();
      }
    }
  }
  return fit;
}

Eigen::Matrix3d rq_rotation(const Eigen::Matrix3d& m, Eigen::Matrix3d* k) {
  Eigen::Matrix3d flip;
  flip << 0, 0, 1, 0, 1, 0, 1, 0, 0;
  const Eigen::Matrix3d a = (flip * m).transpose();
  Eigen::HouseholderQR<Eigen::Matrix3d> qr(a);
  const Eigen::Matrix3d q = qr.householderQ();
  const Eigen::Matrix3d r = qr.matrixQR().triangularView<Eigen::Upper>();
  Eigen::Matrix3d kk = flip * r.transpose() * flip;
  Eigen::Matrix3d rot = flip * q.transpose();
  const Eigen::Vector3d signs(kk(0, 0) < 0 ? -1 : 1, kk(1, 1) < 0 ? -1 : 1, kk(2, 2) < 0 ? -1 : 1);
  kk = kk * signs.asDiagonal();
  rot = signs.asDiagonal() * rot;
  *k = kk;
  return rot;
}

}  // namespace

Result<Matrix34d> projection_from_dlt(const std::vector<Eigen::Vector3d>& points_mm,
                                      const std::vector<Eigen::Vector2d>& pixels) {
  if (points_mm.size() != pixels.size()) return invalid_argument("DLT: point and pixel counts differ");
  if (points_mm.size() < 6) {
    return invalid_argument("DLT: needs at least 6 point/pixel pairs, has " +
                            std::to_string(points_mm.size()));
  }
  if (flatness(points_mm) < 0.02) {
    return invalid_argument(
        "DLT: the markers are (nearly) coplanar; one image of a flat pattern does not determine the view. "
        "Use a phantom with markers in depth");
  }
  const Eigen::Matrix4d t3 = normaliser<3>(points_mm);
  const Eigen::Matrix3d t2 = normaliser<2>(pixels);
  const int n = int(points_mm.size());
  Eigen::MatrixXd a(2 * n, 12);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector4d x = t3 * points_mm[std::size_t(i)].homogeneous();
    const Eigen::Vector3d u = t2 * pixels[std::size_t(i)].homogeneous();
    a.row(2 * i) << x.transpose(), Eigen::RowVector4d::Zero(), -u.x() * x.transpose();
    a.row(2 * i + 1) << Eigen::RowVector4d::Zero(), x.transpose(), -u.y() * x.transpose();
  }
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeFullV);
  const Eigen::VectorXd sv = svd.singularValues();
  if (!(sv(10) > 1e-9 * sv(0))) return invalid_argument("DLT: the point configuration is degenerate");
  const Eigen::VectorXd h = svd.matrixV().col(11);
  Matrix34d p_normalised;
  p_normalised << h.segment<4>(0).transpose(), h.segment<4>(4).transpose(), h.segment<4>(8).transpose();
  Matrix34d p = t2.inverse() * p_normalised * t3;
  // Sign: points in front of the source have w > 0.
  if ((p * points_mm[0].homogeneous()).z() < 0) p = -p;
  return p;
}

Result<XrayView> view_from_projection(const Matrix34d& projection, const XrayView& spec) {
  if (!projection.allFinite()) return invalid_argument("projection matrix is not finite");
  const Eigen::Matrix3d m = projection.leftCols<3>();
  if (std::abs(m.determinant()) < 1e-300) return invalid_argument("projection matrix is singular");
  const Eigen::Vector3d centre = -m.inverse() * projection.col(3);
  Eigen::Matrix3d k;
  const Eigen::Matrix3d rot = rq_rotation(m, &k);
  k /= k(2, 2);
  // rot's rows: col axis, row axis, viewing direction (P is scaled so that w > 0 in front, and
  // K(2,2) > 0). lftrack's detectors have col x row = beam; a mirrored image breaks that.
  const Eigen::Vector3d col_axis = rot.row(0).transpose();
  const Eigen::Vector3d row_axis = rot.row(1).transpose();
  const Eigen::Vector3d beam = rot.row(2).transpose();  // w = k22 beam.(X - C) > 0 in front
  if (col_axis.cross(row_axis).dot(beam) < 0) {
    return invalid_argument(
        "the image appears mirrored (column x row axes point towards the source); flip it left-right");
  }
  XrayView v = spec;
  v.source_mm = centre;
  v.col_axis = col_axis;
  v.row_axis = row_axis;
  const double sdd = k(0, 0) * spec.pitch_col_mm;
  v.pixel00_mm =
      centre + sdd * beam - k(0, 2) * spec.pitch_col_mm * col_axis - k(1, 2) * spec.pitch_row_mm * row_axis;
  if (Status s = v.validate(); !s.ok()) return s;
  return v;
}

Result<ViewCalibration> calibrate_view(const CalibrationPhantom& phantom,
                                       const std::vector<MarkerDetection>& detections,
                                       const XrayView& nominal, const ViewCalibrationOptions& options) {
  LFTRACK_RETURN_IF_ERROR(phantom.validate());
  LFTRACK_RETURN_IF_ERROR(nominal.validate());
  const std::string who = "view '" + nominal.name + "': ";
  if (options.min_markers < 6) return invalid_argument(who + "min_markers must be at least 6");
  const std::vector<Predicted> predicted = predict(phantom, nominal, options.min_separation_px);
  const auto too_few = [&](int matched, const std::string& stage) {
    std::ostringstream m;
    m << who << "too few markers found: " << matched << " matched " << stage << " (need "
      << options.min_markers << "); " << detections.size() << " detected, " << predicted.size() << " of "
      << phantom.markers_mm.size()
      << " expected on the detector. Check the exposure, the phantom's placement and the nominal geometry";
    return not_found(m.str());
  };
  if (int(detections.size()) < options.min_markers || int(predicted.size()) < options.min_markers) {
    return too_few(0, "(before matching)");
  }
  {
    std::vector<Eigen::Vector3d> seen;
    for (const Predicted& p : predicted) seen.push_back(phantom.markers_mm[std::size_t(p.marker)]);
    if (flatness(seen) < 0.02) {
      return invalid_argument(who +
                              "the phantom's markers in view are (nearly) coplanar; one image of a flat "
                              "pattern does not determine the view. Use a phantom with markers in depth");
    }
  }

  // 1. Shift vote and first pairing.
  const ShiftVote vote = vote_for_shift(predicted, detections, options.match_gate_px);
  if (vote.runner_up_votes >= std::max(options.min_markers, int(std::ceil(0.7 * vote.votes)))) {
    std::ostringstream m;
    m << who
      << "ambiguous correspondence: two placements of the phantom's projection explain the image about "
      << "equally well (" << vote.votes << " and " << vote.runner_up_votes << " markers). The pattern is too "
      << "regular for the nominal geometry's uncertainty; use an irregular phantom or a closer nominal "
         "geometry";
    return invalid_argument(m.str());
  }
  int ambiguous = 0;
  std::vector<Pair> pairs = pair_up(predicted, detections, vote.shift, options.match_gate_px, &ambiguous);
  if (ambiguous > int(pairs.size())) {
    std::ostringstream m;
    m << who << "ambiguous correspondence: " << ambiguous
      << " markers have two detections about equally near "
      << "(only " << pairs.size() << " unambiguous)";
    return invalid_argument(m.str());
  }
  if (int(pairs.size()) < options.min_markers) return too_few(int(pairs.size()), "after the shift vote");

  auto gather = [&](const std::vector<Pair>& ps, std::vector<Eigen::Vector3d>* points,
                    std::vector<Eigen::Vector2d>* pixels) {
    points->clear();
    pixels->clear();
    for (const Pair& p : ps) {
      points->push_back(phantom.markers_mm[std::size_t(p.marker)]);
      pixels->push_back(detections[std::size_t(p.detection)].pixel);
    }
  };
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector2d> pixels;

  // 2. DLT, re-pair with its view, twice.
  XrayView current = nominal;
  for (int round = 0; round < 2; ++round) {
    gather(pairs, &points, &pixels);
    auto p = projection_from_dlt(points, pixels);
    if (!p.ok()) return p.status().with_context(who.substr(0, who.size() - 2));
    auto v = view_from_projection(*p, nominal);
    if (!v.ok()) return v.status().with_context(who.substr(0, who.size() - 2));
    current = *v;
    const std::vector<Predicted> again = predict(phantom, current, options.min_separation_px);
    pairs = pair_up(again, detections, Eigen::Vector2d::Zero(), std::max(4.0, 0.25 * options.match_gate_px),
                    &ambiguous);
    if (int(pairs.size()) < options.min_markers) return too_few(int(pairs.size()), "after the DLT");
  }

  // 3. Ceres refinement; drop outliers, refit.
  CameraModel model;
  CameraParams start = params_of(current, &model);
  Fit fit;
  for (int round = 0; round < 3; ++round) {
    gather(pairs, &points, &pixels);
    auto refined = refine(start, model, points, pixels, options.huber_px, round == 2);
    if (!refined.ok()) return refined.status().with_context(who.substr(0, who.size() - 2));
    fit = *refined;
    start = fit.params;
    if (round == 2) break;
    const XrayView v = view_of(fit.params, model, nominal, 0);
    const std::vector<Predicted> again = predict(phantom, v, options.min_separation_px);
    std::vector<Pair> candidates = pair_up(again, detections, Eigen::Vector2d::Zero(),
                                           std::max(4.0, 0.25 * options.match_gate_px), &ambiguous);
    // Outliers: beyond outlier_px, or beyond 6 times the median residual (a ball whose
    // centroid a neighbour's shadow pulls; one such ball can move the source's distance by a
    // millimetre, so a robust loss alone does not suffice).
    std::vector<double> residuals;
    for (const Pair& p : candidates) {
      const auto at = v.project(phantom.markers_mm[std::size_t(p.marker)]);
      residuals.push_back(at ? (*at - detections[std::size_t(p.detection)].pixel).norm() : 1e300);
    }
    std::vector<double> sorted = residuals;
    std::nth_element(sorted.begin(), sorted.begin() + std::ptrdiff_t(sorted.size() / 2), sorted.end());
    const double median = sorted.empty() ? 0.0 : sorted[sorted.size() / 2];
    const double limit = std::min(options.outlier_px, std::max(6 * median, 1e-3));
    pairs.clear();
    for (std::size_t i = 0; i < candidates.size(); ++i) {
      if (residuals[i] <= limit) pairs.push_back(candidates[i]);
    }
    if (int(pairs.size()) < options.min_markers)
      return too_few(int(pairs.size()), "within the outlier limit");
  }

  const double nominal_sdd = nominal.source_to_detector_mm();
  const double sdd_fixed = options.fit_pitch ? nominal_sdd : 0.0;
  ViewCalibration out;
  out.view = view_of(fit.params, model, nominal, sdd_fixed);
  if (Status s = out.view.validate(); !s.ok()) return s.with_context(who + "calibrated geometry is invalid");
  out.rms_px = fit.rms_px;
  out.markers_matched = int(pairs.size());
  out.markers_projected = int(predicted.size());
  out.detections = int(detections.size());
  for (const Pair& p : pairs) {
    MarkerResidual r;
    r.marker = p.marker;
    r.detected_px = detections[std::size_t(p.detection)].pixel;
    r.residual_px = *out.view.project(phantom.markers_mm[std::size_t(p.marker)]) - r.detected_px;
    out.residuals.push_back(r);
  }
  out.principal_point_px = {fit.params.pp[0], fit.params.pp[1]};
  out.source_to_detector_mm = out.view.source_to_detector_mm();
  out.pitch_col_mm = out.view.pitch_col_mm;
  if (fit.covariance_ok) {
    const auto& c = fit.covariance;
    const Eigen::Matrix<double, 9, 1> sd = c.diagonal().cwiseMax(0).cwiseSqrt();
    out.source_sd_mm = sd.segment<3>(0);
    out.orientation_sd_deg = sd.segment<3>(3) * (180.0 / 3.14159265358979323846);
    out.principal_point_sd_px = sd.segment<2>(6);
    if (options.fit_pitch) {
      out.pitch_sd_mm = nominal_sdd * sd(8) / (fit.params.f[0] * fit.params.f[0]);
    } else {
      out.source_to_detector_sd_mm = sd(8) * nominal.pitch_col_mm;
    }
    // pixel00 by linear propagation: numerical Jacobian of the view's pixel00 in the parameters.
    Eigen::Matrix<double, 3, 9> j;
    const Eigen::Matrix<double, 9, 1> x0 = fit.params.as_vector();
    for (int k = 0; k < 9; ++k) {
      const double h = 1e-6 * std::max(1.0, std::abs(x0(k)));
      Eigen::Matrix<double, 9, 1> xp = x0, xm = x0;
      xp(k) += h;
      xm(k) -= h;
      j.col(k) = (view_of(CameraParams::from_vector(xp), model, nominal, sdd_fixed).pixel00_mm -
                  view_of(CameraParams::from_vector(xm), model, nominal, sdd_fixed).pixel00_mm) /
                 (2 * h);
    }
    out.pixel00_sd_mm = (j * c * j.transpose()).diagonal().cwiseMax(0).cwiseSqrt();
  }
  return out;
}

}  // namespace lftrack::calib

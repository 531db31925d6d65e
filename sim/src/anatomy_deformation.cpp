#include "lftrack/sim/anatomy_deformation.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::sim {

using sim_spec::AnatomySpec;

using Eigen::Vector3d;

namespace {

double smoothstep(double t) {
  if (t <= 0) return 0;
  if (t >= 1) return 1;
  return t * t * (3 - 2 * t);
}

}  // namespace

AnatomyDeformation::AnatomyDeformation(const AnatomySpec& spec, const Vector3d& centre, std::uint64_t seed)
    : spec_(spec), centre_(centre), half_(0.5 * spec.target_size_mm) {
  std::mt19937_64 rng(seed * 0x9e3779b97f4a7c15ULL + 0x5eed);
  std::uniform_real_distribution<double> pm(-1, 1), unit(0, 1);
  std::normal_distribution<double> normal;
  auto segment = [&](double face_z) {
    tracking::Pose T = tracking::Pose::Identity();
    Vector3d omega, t;
    for (int a = 0; a < 3; ++a) {
      omega[a] = tracking::deg_to_rad(spec.adjacent_rotation_deg) * pm(rng);
      t[a] = spec.adjacent_translation_mm * pm(rng);
    }
    const Vector3d pivot(centre.x(), centre.y(), face_z);
    T.linear() = tracking::rotation_exp(omega);
    T.translation() = pivot + t - T.linear() * pivot;
    return T;
  };
  above_ = segment(centre.z() + half_.z());
  below_ = segment(centre.z() - half_.z());
  // Four waves per component, each of rms amplitude a / sqrt(2): a component's rms is a sqrt(2);
  // the vector's rms soft_tissue_mm when a = soft / sqrt(6).
  const double a = spec.soft_tissue_mm / std::sqrt(6.0);
  wave_amplitude_ = Vector3d::Constant(a);
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < 4; ++k) {
      Vector3d dir(normal(rng), normal(rng), normal(rng));
      dir /= std::max(1e-9, dir.norm());
      const double wavelength = spec.soft_tissue_scale_mm * (0.7 + 0.6 * unit(rng));
      wave_k_[c][k] = dir * (2 * M_PI / wavelength);
      wave_phase_[c][k] = 2 * M_PI * unit(rng);
    }
  breathing_phase_ = unit(rng);
}

bool AnatomyDeformation::in_target(const Vector3d& x) const {
  return ((x - centre_).cwiseAbs() - half_).maxCoeff() <= 0;
}

Vector3d AnatomyDeformation::displacement_mm(const Vector3d& x) const {
  const Vector3d rel = x - centre_;
  const Vector3d outside = (rel.cwiseAbs() - half_).cwiseMax(0.0);
  const double dist_box = outside.norm();
  const double dist_column = outside.head<2>().norm();
  Vector3d d = Vector3d::Zero();
  // Adjacent segments.
  if (spec_.adjacent_translation_mm > 0 || spec_.adjacent_rotation_deg > 0) {
    const double column = 1 - smoothstep(dist_column / spec_.ramp_mm);
    if (column > 0) {
      if (rel.z() > half_.z())
        d += column * smoothstep((rel.z() - half_.z()) / spec_.disc_mm) * (above_ * x - x);
      else if (rel.z() < -half_.z())
        d += column * smoothstep((-rel.z() - half_.z()) / spec_.disc_mm) * (below_ * x - x);
    }
  }
  const double soft = smoothstep(dist_box / spec_.ramp_mm);
  if (soft > 0 && spec_.soft_tissue_mm > 0)
    for (int c = 0; c < 3; ++c) {
      double v = 0;
      for (int k = 0; k < 4; ++k) v += std::cos(wave_k_[c][k].dot(x) + wave_phase_[c][k]);
      d[c] += soft * wave_amplitude_[c] * v;
    }
  if (soft > 0 && spec_.breathing_mm > 0) {
    const double anterior = smoothstep((-rel.y() - 20) / 60);  // -y is anterior
    d.z() += soft * anterior * spec_.breathing_mm * breathing_phase_;
  }
  return d;
}

Result<tracking::CtVolume> deform_ct(const tracking::CtVolume& ct, const AnatomyDeformation& deformation,
                                     tracking::ThreadPool* pool) {
  LFTRACK_RETURN_IF_ERROR(ct.geometry.validate());
  if (ct.values.size() != std::size_t(ct.geometry.voxel_count()))
    return invalid_argument("deformation: the CT has the wrong number of values");
  const tracking::VolumeGeometry& g = ct.geometry;
  const Eigen::Affine3d ct_from_index = g.ct_from_index();
  const Eigen::Matrix3d index_from_ct_linear = g.index_from_ct().linear();
  // The displacement on a coarse lattice of about 6 mm, in index units, trilinear in between.
  Eigen::Vector3i step, nodes;
  for (int a = 0; a < 3; ++a) {
    step[a] = std::max(1, int(6.0 / g.spacing_mm[a]));
    nodes[a] = (g.size[a] - 1) / step[a] + 2;
  }
  std::vector<Vector3d> lattice(std::size_t(nodes.x()) * nodes.y() * nodes.z());
  auto node = [&](int a, int b, int c) -> Vector3d& {
    return lattice[std::size_t(a) + std::size_t(nodes.x()) * (std::size_t(b) + std::size_t(nodes.y()) * c)];
  };
  for (int c = 0; c < nodes.z(); ++c)
    for (int b = 0; b < nodes.y(); ++b)
      for (int a = 0; a < nodes.x(); ++a) {
        const Vector3d index(a * step.x(), b * step.y(), c * step.z());
        node(a, b, c) = index_from_ct_linear * deformation.displacement_mm(ct_from_index * index);
      }
  tracking::CtVolume out;
  out.geometry = g;
  out.values.assign(ct.values.size(), -1000.f);
  auto sample = [&](const Vector3d& p) -> float {
    const double fx = std::floor(p.x()), fy = std::floor(p.y()), fz = std::floor(p.z());
    const int i0 = int(fx), j0 = int(fy), k0 = int(fz);
    const double tx = p.x() - fx, ty = p.y() - fy, tz = p.z() - fz;
    double sum = 0;
    for (int dz = 0; dz < 2; ++dz)
      for (int dy = 0; dy < 2; ++dy)
        for (int dx = 0; dx < 2; ++dx) {
          const int i = i0 + dx, j = j0 + dy, k = k0 + dz;
          const double w = (dx ? tx : 1 - tx) * (dy ? ty : 1 - ty) * (dz ? tz : 1 - tz);
          const bool in = i >= 0 && j >= 0 && k >= 0 && i < g.size.x() && j < g.size.y() && k < g.size.z();
          const float v = in ? ct.at(i, j, k) : -1000.f;
          sum += w * (std::isfinite(v) ? v : -1000.0);
        }
    return float(sum);
  };
  auto slices = [&](int k_begin, int k_end) {
    for (int k = k_begin; k < k_end; ++k) {
      const int c = k / step.z();
      const double tz = double(k - c * step.z()) / step.z();
      for (int j = 0; j < g.size.y(); ++j) {
        const int b = j / step.y();
        const double ty = double(j - b * step.y()) / step.y();
        for (int i = 0; i < g.size.x(); ++i) {
          const int a = i / step.x();
          const double tx = double(i - a * step.x()) / step.x();
          Vector3d d = Vector3d::Zero();
          for (int dz = 0; dz < 2; ++dz)
            for (int dy = 0; dy < 2; ++dy)
              for (int dx = 0; dx < 2; ++dx)
                d += ((dx ? tx : 1 - tx) * (dy ? ty : 1 - ty) * (dz ? tz : 1 - tz)) * node(a + dx, b + dy, c + dz);
          // The lattice is interpolated; the target's voxels are copied, so it stays exactly rigid.
          const bool rigid = d.isZero(0) || deformation.in_target(ct_from_index * Vector3d(i, j, k));
          out.at(i, j, k) = rigid ? ct.at(i, j, k) : sample(Vector3d(i, j, k) - d);
        }
      }
    }
  };
  if (pool == nullptr)
    slices(0, g.size.z());
  else
    pool->parallel_for(g.size.z(), 1, slices);
  return out;
}

}  // namespace lftrack::sim

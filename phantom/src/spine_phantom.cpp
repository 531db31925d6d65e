#include "lftrack/phantom/spine_phantom.hpp"

#include <algorithm>
#include <cmath>
#include <random>

#include "lftrack/tracking/random_draws.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::phantom {
namespace {

using Eigen::Vector3d;

constexpr double kAir = -1000, kFat = -100, kSoft = 40, kMuscle = 55, kKidney = 30, kAorta = 45;
constexpr double kGas = -900, kCortical = 1100, kCancellous = 220, kDisc = 90, kArch = 750;
constexpr double kCsf = 15, kCouch = 250;

// Stateless hash -> uniform [0, 1): per-voxel noise that does not depend on thread scheduling.
double hash_unit(std::uint64_t seed, std::uint64_t key) {
  std::uint64_t z = seed * 0x9E3779B97F4A7C15ull + key + 0x632BE59BD9B4E019ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  return double(z >> 11) * 0x1.0p-53;
}

// Smooth value noise on a lattice of `cell_mm`, in [-1, 1]: the trabecular texture.
double value_noise(std::uint64_t seed, const Vector3d& p, double cell_mm) {
  const Vector3d q = p / cell_mm;
  const Vector3d f = q.array().floor();
  const Vector3d t = q - f;
  const Vector3d s = t.array() * t.array() * (3.0 - 2.0 * t.array());
  double v = 0;
  for (int corner = 0; corner < 8; ++corner) {
    const int dx = corner & 1, dy = (corner >> 1) & 1, dz = (corner >> 2) & 1;
    const auto key = static_cast<std::uint64_t>((static_cast<std::int64_t>(f.x()) + dx) * 73856093 ^
                                                (static_cast<std::int64_t>(f.y()) + dy) * 19349663 ^
                                                (static_cast<std::int64_t>(f.z()) + dz) * 83492791);
    const double w = (dx ? s.x() : 1 - s.x()) * (dy ? s.y() : 1 - s.y()) * (dz ? s.z() : 1 - s.z());
    v += w * (2.0 * hash_unit(seed, key) - 1.0);
  }
  return v;
}

// Coverage of a voxel by a shape from its approximate signed distance (mm, negative inside):
// a linear ramp over one voxel width.
double coverage(double signed_distance_mm, double voxel_mm) {
  return std::clamp(0.5 - signed_distance_mm / voxel_mm, 0.0, 1.0);
}

// Approximate signed distance to an axis-aligned ellipse (x, y) with semi-axes a, b.
double ellipse_sd(double x, double y, double a, double b) {
  const double r = std::hypot(x / a, y / b);
  return (r - 1.0) * std::min(a, b);
}

// True when a shape bounded by an ellipse (x, y, a, b) cannot cover the voxel: a lower bound of
// ellipse_sd (the root's argument is at least the larger term) already past the coverage ramp.
// Skipping such a shape leaves the voxel exactly as painting it with weight 0 would.
bool outside_ellipse_ramp(double x, double y, double a, double b, double vox) {
  return (std::max(std::abs(x) / a, std::abs(y) / b) - 1.0) * std::min(a, b) > 0.5 * vox + 1e-9;
}

// The same for an ellipsoid (p relative to its centre, semi-axes `semi`).
bool outside_ellipsoid_ramp(const Vector3d& p, const Vector3d& semi, double vox) {
  return (p.cwiseAbs().cwiseQuotient(semi).maxCoeff() - 1.0) * semi.minCoeff() > 0.5 * vox + 1e-9;
}

double ellipsoid_sd(const Vector3d& p, const Vector3d& semi) {
  return (p.cwiseQuotient(semi).norm() - 1.0) * semi.minCoeff();
}

void paint(double* hu, double value, double weight) {
  *hu += weight * (value - *hu);
}

struct Vertebra {
  Vector3d body_centre;   // mm, CT frame
  double half_height;     // of the body, mm
  double body_a, body_b;  // lateral and AP semi-axes of the body, mm
  double cortex_mm;
  double cortical_hu;
};

struct Gas {
  Vector3d centre, semi;
};

struct Anatomy {
  Vector3d body_centre;  // centre of the torso ellipse at z = 0 (x, y used)
  double body_a = 155, body_b = 105, fat_mm = 12;
  double couch_top_y = 0;
  std::vector<Vertebra> vertebrae;
  std::vector<Gas> gas;
  double disc_gap = 8;
  std::uint64_t seed = 1;
};

double vertebra_hu(const Anatomy& an, const Vertebra& v, const Vector3d& p, double hu, double vox) {
  const Vector3d d = p - v.body_centre;  // x lateral, y posterior, z superior
  if (std::abs(d.z()) > v.half_height + 2 * vox + 2 || std::abs(d.x()) > 60 || d.y() < -v.body_b - 3 ||
      d.y() > 70) {
    return hu;
  }
  // Vertebral body: cortical shell then cancellous interior; the body is waisted (narrower at
  // mid-height than at its end plates), as lumbar bodies are.
  const double t = std::min(1.0, std::abs(d.z()) / v.half_height);
  const double waist = 0.88 + 0.12 * t * t;
  const double radial = ellipse_sd(d.x(), d.y(), waist * v.body_a, waist * v.body_b);
  const double axial = std::abs(d.z()) - v.half_height;
  const double body_sd = std::max(radial, axial);
  const double w_body = coverage(body_sd, vox);
  if (w_body > 0) {
    paint(&hu, v.cortical_hu, w_body);
    const double w_in = coverage(body_sd + v.cortex_mm, vox);
    if (w_in > 0) {
      const double texture = 70.0 * value_noise(an.seed, p, 2.5) + 30.0 * value_noise(an.seed + 7, p, 1.2);
      paint(&hu, kCancellous + texture, w_in);
    }
  }
  // Posterior elements, at the level of the upper two thirds of the body.
  const double canal_y = v.body_b + 11.0;  // canal centre, posterior of the body
  const double arch_z = std::abs(d.z() - 0.2 * v.half_height);
  if (arch_z < 0.55 * v.half_height + vox) {
    const double zc = 0.55 * v.half_height;
    // Pedicles: elliptic rods from the body's back to the lamina.
    for (double side : {-1.0, 1.0}) {
      const double ped_sd = std::max(ellipse_sd(d.x() - side * 11.0, d.z() - 0.2 * v.half_height, 4.5, zc),
                                     std::max(v.body_b - 2 - d.y(), d.y() - (canal_y + 2)));
      paint(&hu, kArch, coverage(ped_sd, vox));
      // Transverse processes: lateral rods.
      const double tp_sd = std::max(ellipse_sd(d.y() - (canal_y - 4), d.z() - 0.2 * v.half_height, 4.0, 5.0),
                                    std::max(12.0 - side * d.x(), side * d.x() - 40.0));
      paint(&hu, kArch, coverage(tp_sd, vox));
    }
    // Laminae: the posterior half of an annulus around the canal.
    const double r = std::hypot(d.x(), d.y() - canal_y);
    const double lam_sd = std::max({std::abs(r - 11.5) - 3.0, canal_y + 1.0 - d.y(), arch_z - zc});
    paint(&hu, kArch, coverage(lam_sd, vox));
    // Spinous process: a midline plate sloping caudally.
    const double sy = d.y() - (canal_y + 12.0);
    const double sp_sd = std::max({std::abs(d.x()) - 3.0, -sy, sy - 30.0,
                                   std::abs(d.z() - 0.2 * v.half_height + 0.35 * std::max(sy, 0.0)) - 7.0});
    paint(&hu, kArch - 100, coverage(sp_sd, vox));
  }
  // Spinal canal (CSF) through every level.
  if (std::abs(d.z()) <= v.half_height + an.disc_gap) {
    paint(&hu, kCsf, coverage(std::hypot(d.x(), d.y() - canal_y) - 8.5, vox));
  }
  return hu;
}

double voxel_hu(const Anatomy& an, const Vector3d& p, double vox) {
  const double x = p.x() - an.body_centre.x();
  const double y = p.y() - an.body_centre.y();
  double hu = kAir;
  // Couch: a 12 mm carbon-fibre plate under the patient.
  const double couch_sd = std::max(std::abs(y - (an.couch_top_y + 6.0)) - 6.0, std::abs(x) - 230.0);
  paint(&hu, kCouch, coverage(couch_sd, vox));
  // Torso: fat layer, then soft tissue.
  const double skin = ellipse_sd(x, y, an.body_a, an.body_b);
  // Outside the skin's ramp the fat and soft tissue paint with weight 0 (the soft tissue's
  // distance is the skin's plus fat_mm + fat_var, at least 12 - 3 mm) and the organs are not
  // reached (skin > 0 returns below): skip the noise lattices, which are most of a voxel's cost.
  // The values are exactly those the full evaluation gives.
  if (coverage(skin, vox) == 0.0) return hu;
  paint(&hu, kFat, coverage(skin, vox));
  const double fat_var = 3.0 * value_noise(an.seed + 11, p, 40.0);
  paint(&hu, kSoft + 8.0 * value_noise(an.seed + 3, p, 15.0), coverage(skin + an.fat_mm + fat_var, vox));
  if (skin > 0) return hu;

  const Vertebra& v0 = an.vertebrae.front();
  const double sx = p.x() - v0.body_centre.x();
  const double sy = p.y() - v0.body_centre.y();
  // Psoas, kidneys, aorta.
  for (double side : {-1.0, 1.0}) {
    if (!outside_ellipse_ramp(sx - side * 38.0, sy + 2.0, 16.0, 20.0, vox))
      paint(&hu, kMuscle, coverage(ellipse_sd(sx - side * 38.0, sy + 2.0, 16.0, 20.0), vox));
    const Vector3d kidney(sx - side * 75.0, sy + 5.0, p.z() - v0.body_centre.z() - 70.0);
    if (!outside_ellipsoid_ramp(kidney, {28, 22, 55}, vox))
      paint(&hu, kKidney, coverage(ellipsoid_sd(kidney, {28, 22, 55}), vox));
  }
  if (!outside_ellipse_ramp(sx - 15.0, sy + 32.0, 11.0, 11.0, vox))
    paint(&hu, kAorta, coverage(std::hypot(sx - 15.0, sy + 32.0) - 11.0, vox));
  for (const Gas& g : an.gas)
    if (!outside_ellipsoid_ramp(p - g.centre, g.semi, vox))
      paint(&hu, kGas, coverage(ellipsoid_sd(p - g.centre, g.semi), vox));
  // Discs between consecutive bodies, then the vertebrae.
  for (std::size_t n = 0; n + 1 < an.vertebrae.size(); ++n) {
    const Vertebra& a = an.vertebrae[n];
    const Vertebra& b = an.vertebrae[n + 1];
    const Vector3d mid = 0.5 * (a.body_centre + b.body_centre);
    const double half = 0.5 * (b.body_centre.z() - a.body_centre.z()) - a.half_height + 0.5;
    if (std::abs(p.z() - mid.z()) - half > 0.5 * vox + 1e-9 ||
        outside_ellipse_ramp(p.x() - mid.x(), p.y() - mid.y(), a.body_a, a.body_b, vox)) {
      continue;  // disc_sd is at least either bound: weight 0
    }
    const double disc_sd = std::max(ellipse_sd(p.x() - mid.x(), p.y() - mid.y(), a.body_a, a.body_b),
                                    std::abs(p.z() - mid.z()) - half);
    paint(&hu, kDisc, coverage(disc_sd, vox));
  }
  for (const Vertebra& v : an.vertebrae) hu = vertebra_hu(an, v, p, hu, vox);
  return hu;
}

Anatomy make_anatomy(const SpinePhantomOptions& o, const tracking::VolumeGeometry& g) {
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Anatomy an;
  an.seed = o.seed;
  an.body_centre = {o.centre_mm.x() + 2.0 * u(rng), o.centre_mm.y() - 20.0 + 2.0 * u(rng), 0};
  an.body_a = 150 + 8 * u(rng);
  an.body_b = 102 + 5 * u(rng);
  an.couch_top_y = an.body_centre.y() + an.body_b + 1.0;
  const double z_lo = o.centre_mm.z() - 0.5 * g.extent_mm().z();
  const double z_hi = o.centre_mm.z() + 0.5 * g.extent_mm().z();
  const double level = 26.0 + an.disc_gap;  // body height + disc
  const double spine_y = an.body_centre.y() + an.body_b - 72.0;
  // Levels centred on the volume, as many as fit with their bodies inside it.
  const int count = std::max(1, static_cast<int>(std::floor((z_hi - z_lo - 26.0) / level)) + 1);
  const double first = o.centre_mm.z() - 0.5 * (count - 1) * level;
  for (int n = 0; n < count; ++n) {
    Vertebra v;
    const double z = first + n * level + 1.0 * u(rng);
    v.body_centre = {o.centre_mm.x() + 0.8 * u(rng),
                     spine_y + 4.0 * std::cos(0.6 * (n - count / 2)) + 0.8 * u(rng), z};
    v.half_height = 13.0 + 0.8 * u(rng);
    v.body_a = 24.0 + 1.5 * u(rng);
    v.body_b = 17.0 + 1.0 * u(rng);
    v.cortex_mm = 1.5 + 0.2 * u(rng);
    v.cortical_hu = kCortical + 120 * u(rng);
    an.vertebrae.push_back(v);
  }
  for (int n = 0; n < 10; ++n) {
    Gas gas;
    gas.centre = {an.body_centre.x() + 90 * u(rng), an.body_centre.y() - 40 + 30 * u(rng),
                  o.centre_mm.z() + 0.45 * g.extent_mm().z() * u(rng)};
    gas.semi = Vector3d(14, 10, 18) + 6 * tracking::draw3(u, rng);
    an.gas.push_back(gas);
  }
  return an;
}

// Standard normal deviate from two hashed uniforms (Box-Muller).
double hashed_gaussian(std::uint64_t seed, std::uint64_t key) {
  const double u1 = std::max(hash_unit(seed, 2 * key), 1e-300);
  const double u2 = hash_unit(seed, 2 * key + 1);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2);
}

// The phantom without its voxels, and the anatomy its voxels are drawn from.
struct Layout {
  SpinePhantom phantom;
  Anatomy anatomy;
};

Result<Layout> make_layout(const SpinePhantomOptions& o) {
  tracking::VolumeGeometry g;
  g.size = o.size;
  g.spacing_mm = o.spacing_mm;
  g.origin_mm = o.centre_mm - 0.5 * (o.size.cast<double>() - Vector3d::Ones()).cwiseProduct(o.spacing_mm);
  LFTRACK_RETURN_IF_ERROR(g.validate().with_context("spine phantom"));
  if (g.extent_mm().z() < 30.0 || g.extent_mm().x() < 120.0 || g.extent_mm().y() < 120.0) {
    return invalid_argument("spine phantom: the grid must span at least 120 x 120 x 30 mm");
  }
  Layout layout;
  layout.anatomy = make_anatomy(o, g);
  for (const Vertebra& v : layout.anatomy.vertebrae)
    layout.phantom.vertebral_body_centres_mm.push_back(v.body_centre);
  layout.phantom.target_vertebra = static_cast<int>(layout.anatomy.vertebrae.size()) / 2;
  layout.phantom.ct.geometry = g;
  return layout;
}

}  // namespace

Result<SpinePhantom> spine_phantom_layout(const SpinePhantomOptions& o) {
  auto layout = make_layout(o);
  if (!layout.ok()) return layout.status();
  return std::move(layout->phantom);
}

Result<SpinePhantom> make_spine_phantom(const SpinePhantomOptions& o, tracking::ThreadPool* pool) {
  auto layout = make_layout(o);
  if (!layout.ok()) return layout.status();
  SpinePhantom phantom = std::move(layout->phantom);
  const Anatomy& anatomy = layout->anatomy;
  const tracking::VolumeGeometry& g = phantom.ct.geometry;
  phantom.ct.values.resize(static_cast<std::size_t>(g.voxel_count()));
  const double vox = g.spacing_mm.minCoeff();
  auto slices = [&](int k_begin, int k_end) {
    for (int k = k_begin; k < k_end; ++k)
      for (int j = 0; j < g.size.y(); ++j)
        for (int i = 0; i < g.size.x(); ++i) {
          const Vector3d p = g.origin_mm + Vector3d(i, j, k).cwiseProduct(g.spacing_mm);
          const auto key =
              static_cast<std::uint64_t>(i + std::int64_t{g.size.x()} * (j + std::int64_t{g.size.y()} * k));
          const double noise = o.noise_hu > 0 ? o.noise_hu * hashed_gaussian(o.seed ^ 0xA5A5ull, key) : 0.0;
          phantom.ct.at(i, j, k) = static_cast<float>(voxel_hu(anatomy, p, vox) + noise);
        }
  };
  if (pool) {
    pool->parallel_for(g.size.z(), 1, slices);
  } else {
    slices(0, g.size.z());
  }
  return phantom;
}

}  // namespace lftrack::phantom

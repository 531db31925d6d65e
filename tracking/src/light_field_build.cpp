// Building light fields: integrating every sample (by slices, or by the exact walk), and
// converting float samples to 16-bit fixed point or vector-quantised tiles.

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <optional>
#include <random>

#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/ray_integrals.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "build_progress.hpp"
#include "light_field_slices.hpp"
#include "vector_quantizer.hpp"

namespace lftrack::tracking {
namespace {

using Eigen::Vector3d;

std::array<int, 4> tile_grid(const std::array<int, 4>& size) {
  return {(size[0] + 1) / 2, (size[1] + 1) / 2, (size[2] + 1) / 2, (size[3] + 1) / 2};
}

// Which blocks of kBlock^3 voxels hold a voxel whose attenuation reaches a floor, and how far
// (in blocks, the largest of the three index differences) each block is from the nearest that
// does. The walk skips the air around the body: from each end of a ray it jumps through the air
// by that distance until it reaches a block that holds the body, and walks only between the two.
class BodyBlocks {
 public:
  static constexpr int kBlock = 8;

  BodyBlocks(const MuVolume& mu, float floor_per_mm)
      : blocks_((mu.geometry.size.array() + kBlock - 1) / kBlock),
        block_mm_(mu.geometry.spacing_mm * kBlock),
        half_voxel_mm_(mu.geometry.spacing_mm / 2),
        distance_(static_cast<std::size_t>(blocks_.prod()), kFar) {
    const Eigen::Vector3i n = mu.geometry.size;
    for (int k = 0; k < n.z(); ++k)
      for (int j = 0; j < n.y(); ++j) {
        const float* row =
            &mu.values[static_cast<std::size_t>(std::int64_t{n.x()} * (j + std::int64_t{n.y()} * k))];
        for (int i = 0; i < n.x(); ++i)
          if (row[i] >= floor_per_mm) distance_[index(i / kBlock, j / kBlock, k / kBlock)] = 0;
      }
    // The chessboard distance by two raster passes (a chamfer with every weight 1 is exact for it).
    for (int pass = 0; pass < 2; ++pass) {
      const int step = pass == 0 ? 1 : -1;
      for (int k = pass == 0 ? 0 : blocks_.z() - 1; k >= 0 && k < blocks_.z(); k += step)
        for (int j = pass == 0 ? 0 : blocks_.y() - 1; j >= 0 && j < blocks_.y(); j += step)
          for (int i = pass == 0 ? 0 : blocks_.x() - 1; i >= 0 && i < blocks_.x(); i += step) {
            std::uint8_t& d = distance_[index(i, j, k)];
            for (int dk = -1; dk <= 1; ++dk)
              for (int dj = -1; dj <= 1; ++dj)
                for (int di = -1; di <= 1; ++di) {
                  const int ni = i + di, nj = j + dj, nk = k + dk;
                  if (ni < 0 || nj < 0 || nk < 0 || ni >= blocks_.x() || nj >= blocks_.y() ||
                      nk >= blocks_.z())
                    continue;
                  const std::uint8_t nd = distance_[index(ni, nj, nk)];
                  if (nd < kFar && nd + 1 < d) d = std::uint8_t(nd + 1);
                }
          }
    }
  }

  // The part [*a0, *a1] of the segment from + a (to - from), a in [0, 1] (grid frame, mm),
  // between the first and the last block it meets that holds the body; false where it meets none.
  bool clip(const Vector3d& from_grid_mm, const Vector3d& to_grid_mm, double* a0, double* a1) const {
    const Vector3d p = from_grid_mm + half_voxel_mm_;  // block b spans [b, b + 1) * block_mm_
    const Vector3d d = to_grid_mm - from_grid_mm;
    const Vector3d extent = blocks_.cast<double>().cwiseProduct(block_mm_);
    double enter = 0, exit = 1;
    for (int axis = 0; axis < 3; ++axis) {
      if (d(axis) == 0) {
        if (p(axis) < 0 || p(axis) >= extent(axis)) return false;
        continue;
      }
      double t0 = -p(axis) / d(axis), t1 = (extent(axis) - p(axis)) / d(axis);
      if (t0 > t1) std::swap(t0, t1);
      enter = std::max(enter, t0);
      exit = std::min(exit, t1);
    }
    if (!(enter < exit)) return false;
    const double first = reach_body(p, d, enter, exit);
    if (first >= exit) return false;
    // From the other end: the same search on the reversed segment, a -> 1 - a.
    const double last = 1.0 - reach_body(p + d, -d, 1.0 - exit, 1.0 - first);
    *a0 = first;
    *a1 = std::max(last, first);
    return true;
  }

 private:
  static constexpr std::uint8_t kFar = 255;

  std::size_t index(int i, int j, int k) const {
    return static_cast<std::size_t>(i + std::int64_t{blocks_.x()} * (j + std::int64_t{blocks_.y()} * k));
  }
  // The parameter at which p + a d (block frame) enters the first block that holds the body,
  // searched over [enter, exit); exit where none does. Jumps through air by the distance: a block
  // D blocks from the body leaves D - 1 blocks' width of air in every direction, so the point may
  // move that far (along the ray's largest axis) without passing a block that holds the body;
  // next to the body (D = 1) it steps block by block.
  double reach_body(const Vector3d& p, const Vector3d& d, double enter, double exit) const {
    const double largest = d.cwiseAbs().maxCoeff();
    const double jump_per_block = block_mm_.minCoeff() / largest * (1.0 - 1e-9);
    double t = enter;
    for (int guard = 0; guard < 100000 && t < exit; ++guard) {
      const Vector3d at = p + t * d;
      Eigen::Vector3i b;
      for (int axis = 0; axis < 3; ++axis)
        b(axis) = std::clamp(static_cast<int>(std::floor(at(axis) / block_mm_(axis))), 0, blocks_(axis) - 1);
      const std::uint8_t distance = distance_[index(b.x(), b.y(), b.z())];
      if (distance == 0) return t;
      if (distance >= 2) {
        t += (distance - 1) * jump_per_block;
        continue;
      }
      // To this block's far side along the ray, and just over it.
      double leave = exit;
      for (int axis = 0; axis < 3; ++axis) {
        if (d(axis) == 0) continue;
        const double plane = (b(axis) + (d(axis) > 0 ? 1 : 0)) * block_mm_(axis);
        leave = std::min(leave, (plane - p(axis)) / d(axis));
      }
      t = std::max(leave, t) + 1e-12;
    }
    return std::min(t, exit);
  }

  Eigen::Vector3i blocks_;
  Vector3d block_mm_, half_voxel_mm_;
  std::vector<std::uint8_t> distance_;  // 0: holds the body; kFar: no block does
};

// The exact walk: whole lines, from well before the volume to well beyond it, in the grid frame,
// each cut to the blocks that hold the body (`skip_air_below_hu`): what lies outside them is
// below that floor everywhere.
void walk_every_ray(const MuVolume& mu, const LightFieldGeometry& g, double skip_air_below_hu, float* samples,
                    ThreadPool* pool, const std::function<void(double)>& progress) {
  const GridRayCaster caster(mu);
  const double floor_per_mm = kDefaultMuWaterPerMm * (1.0 + skip_air_below_hu / 1000.0);
  const bool skip_air = floor_per_mm > 0;
  std::optional<BodyBlocks> body;
  if (skip_air) body.emplace(mu, static_cast<float>(floor_per_mm));
  const Eigen::Isometry3d grid_from_ct = mu.geometry.grid_from_ct();
  const double reach = mu.geometry.extent_mm().norm() + (g.roi_centre_ct_mm - g.source_ct_mm).norm() + 10.0;
  const int nu = g.size[0], nv = g.size[1], ns = g.size[2], nt = g.size[3];
  detail::BuildProgress report(progress, std::int64_t{nu} * nv);
  // One (u, v) slice a job; its rays go to the caster a row of t at a time (siddon_batch walks
  // them in vector lanes where the CPU can).
  auto slices = [&](int begin, int end) {
    std::vector<Vector3d> from(static_cast<std::size_t>(nt)), to(static_cast<std::size_t>(nt));
    std::vector<double> integrals(static_cast<std::size_t>(nt));
    std::vector<char> missed(static_cast<std::size_t>(nt), 0);
    for (int slice = begin; slice < end; ++slice) {
      const int iu = slice / nv, iv = slice % nv;
      const Vector3d on_uv =
          g.source_ct_mm + (g.lo[0] + iu * g.spacing(0)) * g.e1 + (g.lo[1] + iv * g.spacing(1)) * g.e2;
      float* out = samples + static_cast<std::size_t>(slice) * static_cast<std::size_t>(ns) *
                                 static_cast<std::size_t>(nt);
      for (int is = 0; is < ns; ++is) {
        for (int it = 0; it < nt; ++it) {
          const Vector3d on_st = g.roi_centre_ct_mm + (g.lo[2] + is * g.spacing(2)) * g.e1 +
                                 (g.lo[3] + it * g.spacing(3)) * g.e2;
          const Vector3d dir = (on_st - on_uv).normalized();
          Vector3d a = grid_from_ct * (on_uv - reach * dir), b = grid_from_ct * (on_st + reach * dir);
          double a0 = 0, a1 = 1;
          const std::size_t i = static_cast<std::size_t>(it);
          missed[i] = skip_air && !body->clip(a, b, &a0, &a1);
          if (skip_air && !missed[i]) {
            const Vector3d d = b - a;
            b = a + a1 * d;
            a = a + a0 * d;
          }
          from[static_cast<std::size_t>(it)] = a;
          to[static_cast<std::size_t>(it)] = b;
        }
        caster.siddon_batch(from, to, integrals);
        for (int it = 0; it < nt; ++it)  // a ray that misses the body crosses air alone: 0
          out[is * nt + it] = missed[static_cast<std::size_t>(it)]
                                  ? 0.0f
                                  : static_cast<float>(integrals[static_cast<std::size_t>(it)]);
      }
      report.advance();
    }
  };
  if (pool)
    pool->parallel_for(nu * nv, 1, slices);
  else
    slices(0, nu * nv);
}

}  // namespace

Result<std::shared_ptr<const LightField>> LightField::build(const MuVolume& mu,
                                                            const LightFieldPlanInput& input,
                                                            const LightFieldSpec& spec, ThreadPool* pool,
                                                            const std::function<void(double)>& progress) {
  LFTRACK_RETURN_IF_ERROR(check_attenuation_volume(mu));
  auto planned = plan_light_field(input, spec);
  if (!planned.ok()) return planned.status();
  std::shared_ptr<LightField> field(new LightField);
  Header& h = field->header_;
  h.geometry = *planned;
  h.storage = LightFieldStorage::kFloat32;
  h.nominal_T_room_from_ct = input.nominal_T_room_from_ct;
  h.registration_origin_room_mm = input.registration_origin_room_mm;
  h.envelope = input.envelope;
  h.ct_hash = volume_hash(mu);
  h.plan_hash = plan_hash(input, spec);
  h.settings_recorded = true;
  h.detector_hash = detector_geometry_hash(input.view_room);
  h.roi_window = input.roi_window;
  h.margin_fraction = spec.margin_fraction;
  h.integration = spec.integration;
  h.slice_step_mm = spec.slice_step_mm;
  const LightFieldGeometry& g = h.geometry;
  const auto count = static_cast<std::size_t>(g.sample_count());
  field->owned_.resize(count * sizeof(float));
  float* samples = reinterpret_cast<float*>(field->owned_.data());

  if (spec.integration != LightFieldIntegration::kSlices ||
      !detail::integrate_by_slices(mu, g, spec.slice_step_mm, samples, pool, progress).ok())
    walk_every_ray(mu, g, spec.skip_air_below_hu, samples, pool, progress);
  field->payload_bytes_ = field->owned_.size();
  field->point_at(field->owned_.data());
  if (spec.storage == LightFieldStorage::kFloat32) return std::shared_ptr<const LightField>(field);
  return convert(*field, spec, pool);
}

Result<std::shared_ptr<const LightField>> LightField::convert(const LightField& source,
                                                              const LightFieldSpec& spec, ThreadPool* pool) {
  if (source.header_.storage != LightFieldStorage::kFloat32) {
    return invalid_argument("light fields convert from float storage only");
  }
  std::shared_ptr<LightField> field(new LightField);
  field->header_ = source.header_;
  field->header_.storage = spec.storage;
  const LightFieldGeometry& g = source.geometry();
  const auto count = static_cast<std::size_t>(g.sample_count());
  const float* f = source.float_samples();

  if (spec.storage == LightFieldStorage::kFloat32) {
    field->owned_.assign(reinterpret_cast<const unsigned char*>(f),
                         reinterpret_cast<const unsigned char*>(f + count));
  } else if (spec.storage == LightFieldStorage::kFixed16) {
    const float peak = *std::max_element(f, f + count);
    const double scale = peak > 0 ? double(peak) / 65535.0 : 1.0;
    field->header_.fixed_scale = scale;
    field->owned_.resize(count * sizeof(std::uint16_t));
    auto* codes = reinterpret_cast<std::uint16_t*>(field->owned_.data());
    for (std::size_t i = 0; i < count; ++i) {
      codes[i] = static_cast<std::uint16_t>(std::clamp(std::lround(f[i] / scale), 0L, 65535L));
    }
  } else {
    if (spec.vq_codebook_size < 2 || spec.vq_codebook_size > 65536) {
      return out_of_range("VQ codebook size must be in 2..65536");
    }
    const auto tiles = tile_grid(g.size);
    const std::int64_t tile_count = std::int64_t{tiles[0]} * tiles[1] * tiles[2] * tiles[3];
    auto tile_at = [&](std::int64_t index) {
      std::array<int, 4> t;
      for (int a = 3; a >= 0; --a) {
        t[a] = static_cast<int>(index % tiles[a]);
        index /= tiles[a];
      }
      Tile tile;
      for (int e = 0; e < 16; ++e) {  // element e = 8 du + 4 dv + 2 ds + dt; edges replicate
        const int iu = std::min(2 * t[0] + ((e >> 3) & 1), g.size[0] - 1);
        const int iv = std::min(2 * t[1] + ((e >> 2) & 1), g.size[1] - 1);
        const int is = std::min(2 * t[2] + ((e >> 1) & 1), g.size[2] - 1);
        const int it = std::min(2 * t[3] + (e & 1), g.size[3] - 1);
        tile[static_cast<std::size_t>(e)] = source.sample(iu, iv, is, it);
      }
      return tile;
    };
    std::mt19937_64 rng(spec.vq_seed);
    const std::int64_t training = std::min<std::int64_t>(
        tile_count, std::max<std::int64_t>(spec.vq_training_tiles, 4 * std::int64_t{spec.vq_codebook_size}));
    std::uniform_int_distribution<std::int64_t> pick(0, tile_count - 1);
    std::vector<Tile> sample;
    sample.reserve(static_cast<std::size_t>(training));
    for (std::int64_t i = 0; i < training; ++i) sample.push_back(tile_at(pick(rng)));
    const Codebook book = train_codebook(sample, spec.vq_codebook_size, 8, spec.vq_seed, pool);
    field->header_.codebook_size = book.size();
    field->header_.vq_training_tiles = spec.vq_training_tiles;
    field->header_.vq_seed = spec.vq_seed;
    const std::size_t codebook_bytes = std::size_t(book.size()) * 16 * sizeof(float);
    field->owned_.resize(codebook_bytes + static_cast<std::size_t>(tile_count) * sizeof(std::uint16_t));
    auto* words = reinterpret_cast<float*>(field->owned_.data());
    for (int w = 0; w < book.size(); ++w)
      std::memcpy(words + 16 * w, book.word(w).data(), 16 * sizeof(float));
    auto* codes = reinterpret_cast<std::uint16_t*>(field->owned_.data() + codebook_bytes);
    auto encode = [&](int begin, int end) {
      for (int i = begin; i < end; ++i) codes[i] = static_cast<std::uint16_t>(book.nearest(tile_at(i)));
    };
    if (pool)
      pool->parallel_for(static_cast<int>(tile_count), 4096, encode);
    else
      encode(0, static_cast<int>(tile_count));
  }
  field->payload_bytes_ = field->owned_.size();
  field->point_at(field->owned_.data());
  return std::shared_ptr<const LightField>(field);
}

}  // namespace lftrack::tracking

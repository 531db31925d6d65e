// Building light fields: integrating every sample (by slices, or by the exact walk), and
// converting float samples to 16-bit fixed point or vector-quantised tiles.

#include <algorithm>
#include <cmath>
#include <cstring>
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

// The exact walk: whole lines, from well before the volume to well beyond it, in the grid frame.
void walk_every_ray(const MuVolume& mu, const LightFieldGeometry& g, float* samples, ThreadPool* pool,
                    const std::function<void(double)>& progress) {
  const GridRayCaster caster(mu);
  const Eigen::Isometry3d grid_from_ct = mu.geometry.grid_from_ct();
  const double reach = mu.geometry.extent_mm().norm() + (g.roi_centre_ct_mm - g.source_ct_mm).norm() + 10.0;
  const int nu = g.size[0], nv = g.size[1], ns = g.size[2], nt = g.size[3];
  detail::BuildProgress report(progress, std::int64_t{nu} * nv);
  // One (u, v) slice a job; its rays go to the caster a row of t at a time (siddon_batch walks
  // them in vector lanes where the CPU can).
  auto slices = [&](int begin, int end) {
    std::vector<Vector3d> from(static_cast<std::size_t>(nt)), to(static_cast<std::size_t>(nt));
    std::vector<double> integrals(static_cast<std::size_t>(nt));
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
          from[static_cast<std::size_t>(it)] = grid_from_ct * (on_uv - reach * dir);
          to[static_cast<std::size_t>(it)] = grid_from_ct * (on_st + reach * dir);
        }
        caster.siddon_batch(from, to, integrals);
        for (int it = 0; it < nt; ++it)
          out[is * nt + it] = static_cast<float>(integrals[static_cast<std::size_t>(it)]);
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
    walk_every_ray(mu, g, samples, pool, progress);
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

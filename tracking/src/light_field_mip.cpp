// LightField::downsampled_st: the (s, t)-averaged copies a light-field renderer reads for coarse
// pixels (light_field_renderer.cpp chooses among them by a view's pixel footprint).

#include <algorithm>
#include <vector>

#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::tracking {
namespace {

// Trapezoid weights of a block of `factor` samples centred on one: offsets -factor/2 ..
// factor/2, the two ends at half weight, summing to 1 (factor 2: 1/4, 1/2, 1/4).
std::vector<float> block_weights(int factor) {
  std::vector<float> w(std::size_t(factor) + 1, 1.0f / float(factor));
  w.front() *= 0.5f;
  w.back() *= 0.5f;
  return w;
}

}  // namespace

Result<std::shared_ptr<const LightField>> LightField::downsampled_st(const LightField& source, int factor,
                                                                     ThreadPool* pool) {
  if (factor < 2 || factor > 64 || (factor & (factor - 1)) != 0)
    return invalid_argument("light field: an (s, t) downsampling factor is a power of two from 2 to 64");
  const LightFieldGeometry& g = source.geometry();
  std::shared_ptr<LightField> field(new LightField);
  field->header_ = source.header();
  field->header_.storage = LightFieldStorage::kFloat32;
  field->header_.codebook_size = 0;
  field->header_.fixed_scale = 0;
  field->header_.plan_hash = 0;  // not the field its plan describes: never to be taken for it
  LightFieldGeometry& m = field->header_.geometry;
  for (int a = 2; a < 4; ++a) {
    // Enough samples to reach the source's last one or past it (the renderer keeps its rays
    // inside the source's extent).
    m.size[a] = (g.size[a] - 1 + factor - 1) / factor + 1;
    if (g.size[a] - 1 < factor)
      return invalid_argument("light field: " + std::to_string(g.size[a]) + " samples along " + (a == 2 ? "s" : "t") +
                              " are too few to average by " + std::to_string(factor));
    m.hi[a] = g.lo[a] + (m.size[a] - 1) * factor * g.spacing(a);
  }
  LFTRACK_RETURN_IF_ERROR(m.validate().with_context("downsampled light field"));

  const std::vector<float> w = block_weights(factor);
  const int half = factor / 2;
  const int ns = g.size[2], nt = g.size[3], ms = m.size[2], mt = m.size[3];
  const std::size_t out_slice = std::size_t(ms) * std::size_t(mt);
  field->owned_.resize(std::size_t(m.size[0]) * std::size_t(m.size[1]) * out_slice * sizeof(float));
  float* out = reinterpret_cast<float*>(field->owned_.data());
  // One (u, v) slice per task: t averaged into a row buffer per source s row, then s. Float
  // fields are read in place; 16-bit ones decoded a row at a time; VQ ones sample by sample.
  auto slices = [&](int begin, int end) {
    std::vector<float> rows(std::size_t(ns) * std::size_t(mt));
    std::vector<float> decoded(static_cast<std::size_t>(nt));
    for (int uv = begin; uv < end; ++uv) {
      const int iu = uv / g.size[1], iv = uv % g.size[1];
      const std::size_t slice_start = std::size_t(uv) * std::size_t(ns) * std::size_t(nt);
      for (int is = 0; is < ns; ++is) {
        const float* row = nullptr;
        const std::size_t row_start = slice_start + std::size_t(is) * std::size_t(nt);
        if (source.float_samples() != nullptr) {
          row = source.float_samples() + row_start;
        } else {
          if (source.fixed_samples() != nullptr) {
            const double scale = source.header().fixed_scale;  // decoded as sample() decodes
            for (int it = 0; it < nt; ++it)
              decoded[std::size_t(it)] = static_cast<float>(source.fixed_samples()[row_start + std::size_t(it)] * scale);
          } else {
            for (int it = 0; it < nt; ++it) decoded[std::size_t(it)] = source.sample(iu, iv, is, it);
          }
          row = decoded.data();
        }
        for (int jt = 0; jt < mt; ++jt) {
          float sum = 0;
          for (int k = -half; k <= half; ++k) {
            const int it = std::clamp(jt * factor + k, 0, nt - 1);
            sum += w[std::size_t(k + half)] * row[it];
          }
          rows[std::size_t(is) * std::size_t(mt) + std::size_t(jt)] = sum;
        }
      }
      float* slice = out + std::size_t(uv) * out_slice;
      for (int js = 0; js < ms; ++js) {
        for (int jt = 0; jt < mt; ++jt) {
          float sum = 0;
          for (int k = -half; k <= half; ++k) {
            const int is = std::clamp(js * factor + k, 0, ns - 1);
            sum += w[std::size_t(k + half)] * rows[std::size_t(is) * std::size_t(mt) + std::size_t(jt)];
          }
          slice[std::size_t(js) * std::size_t(mt) + std::size_t(jt)] = sum;
        }
      }
    }
  };
  const int uv_count = g.size[0] * g.size[1];
  if (pool != nullptr)
    pool->parallel_for(uv_count, 1, slices);
  else
    slices(0, uv_count);
  field->payload_bytes_ = field->owned_.size();
  field->point_at(field->owned_.data());
  return std::shared_ptr<const LightField>(field);
}

}  // namespace lftrack::tracking

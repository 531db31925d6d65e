#include "lftrack/studies/drr_benchmark.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <random>

#include "lftrack/studies/plastimatch_peer.hpp"
#include "lftrack/tracking/image_metrics.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "lftrack/tracking/volume_io.hpp"

namespace lftrack::studies {

using session::build_light_fields;
using session::load_light_fields;
using session::PreparedScene;
namespace {

namespace fs = std::filesystem;
using tracking::Image;
using Clock = std::chrono::steady_clock;

double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(v.size() / 2), v.end());
  return v[v.size() / 2];
}

double mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? std::nan("") : s / double(v.size());
}

double max_abs_diff_rel(const Image<float>& ref, const Image<float>& test) {
  double peak = 0, worst = 0;
  for (std::size_t i = 0; i < ref.pixels().size(); ++i) {
    peak = std::max(peak, double(std::abs(ref.pixels()[i])));
    worst = std::max(worst, double(std::abs(test.pixels()[i] - ref.pixels()[i])));
  }
  return peak > 0 ? worst / peak : worst;
}

}  // namespace

std::vector<tracking::Pose> sample_envelope_poses(const PreparedScene& scene, int count, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double t = scene.scene.envelope.translation_mm;
  const double r = tracking::deg_to_rad(scene.scene.envelope.rotation_deg);
  std::vector<tracking::Pose> poses;
  for (int i = 0; i < count; ++i) {
    tracking::PoseDelta d;
    if (i > 0) {
      d.translation_mm = {t * u(rng), t * u(rng), t * u(rng)};
      d.rotation_rad = {r * u(rng), r * u(rng), r * u(rng)};
    }
    poses.push_back(
        tracking::apply_delta(scene.nominal_T_room_from_ct, d, scene.registration_origin_room_mm()));
  }
  return poses;
}

std::vector<tracking::XrayView> roi_views(const PreparedScene& scene, int size) {
  std::vector<tracking::XrayView> views;
  for (std::size_t i = 0; i < scene.scene.detectors.size(); ++i) {
    const auto& w = scene.roi_windows[i];
    views.push_back(scene.scene.detectors[i].view.resampled(w.row0, w.col0, w.rows, w.cols, size, size));
  }
  return views;
}

namespace {

// Times `renderer` on every pose and view and compares each image with the reference (the first
// renderer measured supplies the reference images).
Status measure(const tracking::DrrRenderer& renderer, const std::vector<tracking::Pose>& poses,
               const std::vector<tracking::XrayView>& views, int size, int repeats,
               std::vector<Image<float>>* reference, RendererFigures* fig) {
  const tracking::PixelWindow window = tracking::PixelWindow::full(size, size);
  std::vector<double> ms, ncc, psnr;
  Image<float> image(size, size);
  Image<unsigned char> valid(size, size);
  const bool is_reference = reference->empty();
  std::size_t k = 0;
  long masked = 0, pixels = 0;
  for (const auto& pose : poses) {
    for (const auto& view : views) {
      tracking::RenderExtras extras;
      extras.valid = valid.view();
      for (int rep = 0; rep < repeats; ++rep) {
        const auto t0 = Clock::now();
        LFTRACK_RETURN_IF_ERROR(renderer.render(pose, view, window, image.view(), &extras));
        ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      }
      masked += extras.masked_pixels;
      pixels += long(size) * size;
      if (is_reference) reference->push_back(image);
      // Fidelity over the pixels the renderer computed (masked ones are reported separately).
      const tracking::ImageView<const unsigned char> mask = valid.view();
      ncc.push_back(tracking::normalized_cross_correlation((*reference)[k].view(), image.view(), &mask));
      psnr.push_back(tracking::psnr_db((*reference)[k].view(), image.view(), &mask));
      ++k;
    }
  }
  fig->name = std::string(renderer.name());
  fig->ms_median = median(ms);
  fig->ms_min = *std::min_element(ms.begin(), ms.end());
  fig->ncc_vs_siddon = mean(ncc);
  fig->ncc_min_vs_siddon = *std::min_element(ncc.begin(), ncc.end());
  fig->psnr_db_vs_siddon = mean(psnr);
  fig->bytes = renderer.bytes();
  fig->out_of_field_fraction = double(masked) / double(pixels);
  return {};
}

void log_figures(const RendererFigures& f) {
  spdlog::info(
      "bench drr: {:22s} {:9.3f} ms median, x{:<8.1f} NCC {:.6f} (min {:.6f}), PSNR {:5.1f} dB, {:7.1f} MB, "
      "{:.4f} out of field",
      f.name, f.ms_median, f.speedup_vs_siddon, f.ncc_vs_siddon, f.ncc_min_vs_siddon, f.psnr_db_vs_siddon,
      double(f.bytes) / 1e6, f.out_of_field_fraction);
}

}  // namespace

Result<DrrBenchReport> run_drr_benchmark(const PreparedScene& scene, const DrrBenchOptions& o,
                                         tracking::ThreadPool* pool) {
  if (o.size < 8 || o.size > 4096) return out_of_range("--size must be in 8..4096");
  if (o.poses < 1 || o.repeats < 1) return out_of_range("--poses and --repeats must be at least 1");
  if (o.render_threads < 1) return out_of_range("--render-threads must be at least 1");
  DrrBenchReport report;
  report.ct = scene.scene.ct.path;
  report.rows = report.cols = o.size;
  report.threads = pool ? pool->size() : 1;
  report.render_threads = o.render_threads;
  report.poses = o.poses;
  const auto views = roi_views(scene, o.size);
  for (const auto& v : views) report.views.push_back(v.name);
  const auto poses = sample_envelope_poses(scene, o.poses, o.seed);

  // Renders are timed on their own pool (one thread: the calling thread alone); building light
  // fields uses every core.
  tracking::ThreadPool render_pool(o.render_threads);
  tracking::RendererOptions ropts;
  ropts.pool = &render_pool;
  std::vector<Image<float>> reference;  // Siddon at every pose and view
  for (const std::string& name : {std::string("siddon"), std::string("trilinear")}) {
    auto renderer = make_renderer(name, scene.mu, ropts);
    if (!renderer.ok()) return renderer.status();
    RendererFigures fig;
    LFTRACK_RETURN_IF_ERROR(measure(**renderer, poses, views, o.size, o.repeats, &reference, &fig));
    report.renderers.push_back(fig);
  }
  const double siddon_ms = report.renderers.front().ms_median;
  for (auto& f : report.renderers) {
    f.speedup_vs_siddon = siddon_ms / f.ms_median;
    log_figures(f);
  }

  // The light-field renderers are timed again beside every plastimatch run (below).
  std::vector<std::pair<std::size_t, std::unique_ptr<tracking::DrrRenderer>>> beside_peer;
  if (o.light_fields && o.both_integrations && !o.light_field_dir.empty())
    return invalid_argument("bench drr: the second integration is compared with fields built in the run, not loaded");
  // Times one set of light fields as a renderer, with the precompute it took, into the report.
  // source_image false: the per-ray blend (RendererOptions::light_field_source_image).
  auto time_fields = [&](std::vector<std::shared_ptr<const tracking::LightField>> fields,
                         const std::string& name_suffix, double precompute_s, bool source_image = true) -> Status {
    tracking::RendererOptions lf = ropts;
    lf.light_fields = std::move(fields);
    lf.light_field_mips = false;  // the benchmark's DRRs are full resolution: the field alone
    lf.light_field_source_image = source_image;
    auto renderer = make_renderer("lightfield", nullptr, lf);
    if (!renderer.ok()) return renderer.status();
    RendererFigures fig;
    LFTRACK_RETURN_IF_ERROR(measure(**renderer, poses, views, o.size, o.repeats, &reference, &fig));
    fig.name += name_suffix;
    fig.speedup_vs_siddon = siddon_ms / fig.ms_median;
    fig.precompute_s = precompute_s;
    log_figures(fig);
    report.renderers.push_back(fig);
    beside_peer.emplace_back(report.renderers.size() - 1, std::move(*renderer));
    return {};
  };
  if (o.light_fields) {
    tracking::LightFieldSpec spec = scene.scene.light_field;
    spec.storage = tracking::LightFieldStorage::kFloat32;
    const auto t0 = Clock::now();
    auto built = o.light_field_dir.empty() ? build_light_fields(scene, spec, pool)
                                           : load_light_fields(scene, o.light_field_dir, nullptr, &spec);
    if (!built.ok()) return built.status();
    const auto& float_fields = *built;
    report.precompute_s = o.light_field_dir.empty() ? std::chrono::duration<double>(Clock::now() - t0).count() : 0.0;
    report.integration = tracking::to_string(spec.integration);
    report.light_field_resolution = spec.resolution;
    std::vector<tracking::LightFieldSpec> modes;
    for (auto storage : {tracking::LightFieldStorage::kFloat32, tracking::LightFieldStorage::kFixed16}) {
      spec.storage = storage;
      modes.push_back(spec);
    }
    for (int codebook : o.vq_codebooks) {
      spec.storage = tracking::LightFieldStorage::kVq;
      spec.vq_codebook_size = codebook;
      modes.push_back(spec);
    }
    for (const auto& mode : modes) {
      const auto c0 = Clock::now();
      std::vector<std::shared_ptr<const tracking::LightField>> fields;
      for (const auto& f : float_fields) {
        auto converted = mode.storage == tracking::LightFieldStorage::kFloat32
                             ? Result<std::shared_ptr<const tracking::LightField>>(f)
                             : tracking::LightField::convert(*f, mode, pool);
        if (!converted.ok()) return converted.status();
        fields.push_back(*converted);
      }
      const double convert_s = std::chrono::duration<double>(Clock::now() - c0).count();
      LFTRACK_RETURN_IF_ERROR(time_fields(std::move(fields), "", report.precompute_s + convert_s));
      // The float fields also by the papers' per-ray blend, beside the source image.
      if (mode.storage == tracking::LightFieldStorage::kFloat32)
        LFTRACK_RETURN_IF_ERROR(time_fields(float_fields, "-per-ray", report.precompute_s, false));
    }
    if (o.both_integrations) {
      tracking::LightFieldSpec other = scene.scene.light_field;
      other.storage = tracking::LightFieldStorage::kFloat32;
      other.integration = other.integration == tracking::LightFieldIntegration::kSiddon
                              ? tracking::LightFieldIntegration::kSlices
                              : tracking::LightFieldIntegration::kSiddon;
      report.other_integration = tracking::to_string(other.integration);
      const auto w0 = Clock::now();
      auto other_fields = build_light_fields(scene, other, pool);
      if (!other_fields.ok()) return other_fields.status();
      report.other_precompute_s = std::chrono::duration<double>(Clock::now() - w0).count();
      LFTRACK_RETURN_IF_ERROR(
          time_fields(std::move(*other_fields), "-" + report.other_integration, report.other_precompute_s));
    }
  }

  if (!o.peers) {
    report.peer_note = "peers disabled (--no-peers)";
    return report;
  }
  if (!plastimatch_available()) {
    report.peer_note = "plastimatch is not installed";
    spdlog::warn("bench drr: {}; no peer figures", report.peer_note);
    return report;
  }
  std::error_code ec;
  fs::path work = o.work_dir;
  if (work.empty()) work = fs::temp_directory_path() / ("lftrack-bench-" + std::to_string(::getpid()));
  fs::create_directories(work, ec);
  const fs::path mha = work / "mu.mha";
  LFTRACK_RETURN_IF_ERROR(tracking::write_metaimage(*scene.mu, mha));
  PeerFigures peer;
  peer.name = "plastimatch";
  std::vector<double> ms, wall, ncc, diff;
  std::vector<std::vector<double>> ratios(beside_peer.size());
  const tracking::PixelWindow window = tracking::PixelWindow::full(o.size, o.size);
  Image<float> image(o.size, o.size);
  std::size_t k = 0;
  for (const auto& pose : poses) {
    for (const auto& view : views) {
      auto drr = run_plastimatch_drr(view.transformed(pose.inverse()), mha, work / "out", o.render_threads);
      if (!drr.ok()) return drr.status();
      ms.push_back(1000.0 * drr->reported_render_s);
      for (std::size_t i = 0; i < beside_peer.size(); ++i) {
        std::vector<double> beside_ms;
        for (int rep = 0; rep < o.repeats; ++rep) {
          const auto t0 = Clock::now();
          LFTRACK_RETURN_IF_ERROR(beside_peer[i].second->render(pose, view, window, image.view()));
          beside_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        }
        ratios[i].push_back(ms.back() / median(beside_ms));
      }
      wall.push_back(1000.0 * drr->wall_s);
      ncc.push_back(tracking::normalized_cross_correlation(reference[k].view(), drr->line_integrals.view()));
      diff.push_back(max_abs_diff_rel(reference[k], drr->line_integrals));
      ++k;
    }
  }
  fs::remove_all(work, ec);
  peer.ms_median = median(ms);
  peer.ms_wall_median = median(wall);
  peer.ncc_vs_siddon = mean(ncc);
  peer.ncc_min_vs_siddon = *std::min_element(ncc.begin(), ncc.end());
  peer.max_abs_diff_rel = *std::max_element(diff.begin(), diff.end());
  spdlog::info("bench drr: plastimatch {:9.2f} ms median ({:.0f} ms with loading), NCC {:.6f} (min {:.6f})",
               peer.ms_median, peer.ms_wall_median, peer.ncc_vs_siddon, peer.ncc_min_vs_siddon);
  for (auto& f : report.renderers) f.speedup_vs_plastimatch = peer.ms_median / f.ms_median;
  for (std::size_t i = 0; i < beside_peer.size(); ++i) {
    RendererFigures& f = report.renderers[beside_peer[i].first];
    f.speedup_vs_plastimatch_side_by_side = median(ratios[i]);
    spdlog::info(
        "bench drr: {:22s} x{:.0f} plastimatch (median of ratios taken side by side), x{:.0f} (ratio of "
        "medians)",
        f.name, f.speedup_vs_plastimatch_side_by_side, f.speedup_vs_plastimatch);
  }
  report.peers.push_back(peer);
  return report;
}

nlohmann::json to_json(const DrrBenchReport& r) {
  auto finite_or_null = [](double v) {
    return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr);
  };
  nlohmann::json j;
  j["ct"] = r.ct;
  j["size"] = {r.rows, r.cols};
  j["threads"] = r.threads;
  j["render_threads"] = r.render_threads;
  if (r.precompute_s > 0) {
    j["light_field"] = {{"resolution", r.light_field_resolution},
                        {"precompute_s_all_views", r.precompute_s},
                        {"integration", r.integration}};
    if (r.other_precompute_s > 0) {
      j["light_field"]["other_integration"] = r.other_integration;
      j["light_field"]["other_precompute_s_all_views"] = r.other_precompute_s;
    }
  }
  j["poses"] = r.poses;
  j["views"] = r.views;
  j["renderers"] = nlohmann::json::array();
  for (const auto& f : r.renderers) {
    nlohmann::json entry = {{"name", f.name},
                            {"ms_median", f.ms_median},
                            {"ms_min", f.ms_min},
                            {"speedup_vs_siddon", f.speedup_vs_siddon},
                            {"ncc_vs_siddon", f.ncc_vs_siddon},
                            {"ncc_min_vs_siddon", f.ncc_min_vs_siddon},
                            {"psnr_db_vs_siddon", finite_or_null(f.psnr_db_vs_siddon)},
                            {"bytes", f.bytes},
                            {"out_of_field_fraction", f.out_of_field_fraction}};
    if (f.precompute_s > 0) entry["precompute_s"] = f.precompute_s;
    if (f.speedup_vs_plastimatch > 0) entry["speedup_vs_plastimatch"] = f.speedup_vs_plastimatch;
    if (f.speedup_vs_plastimatch_side_by_side > 0) {
      entry["speedup_vs_plastimatch_side_by_side"] = f.speedup_vs_plastimatch_side_by_side;
    }
    j["renderers"].push_back(entry);
  }
  j["peers"] = nlohmann::json::array();
  for (const auto& p : r.peers) {
    j["peers"].push_back({{"name", p.name},
                          {"ms_median", p.ms_median},
                          {"ms_wall_median", p.ms_wall_median},
                          {"ncc_vs_siddon", p.ncc_vs_siddon},
                          {"ncc_min_vs_siddon", p.ncc_min_vs_siddon},
                          {"max_abs_diff_rel", p.max_abs_diff_rel}});
  }
  if (!r.peer_note.empty()) j["peer_note"] = r.peer_note;
  return j;
}

}  // namespace lftrack::studies

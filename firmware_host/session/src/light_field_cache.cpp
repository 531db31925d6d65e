// A scene's light-field files, named after what each field depends on (scene.hpp, "Light-field
// files"): loading them, naming what differs when one is missing, and building only those missing.

#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <system_error>

#include "lftrack/session/progress_bar.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/light_field.hpp"

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;
using Fields = std::vector<std::shared_ptr<const tracking::LightField>>;

// One view's field as asked for: its plan, what it depends on, and its file.
struct Wanted {
  std::string view;
  tracking::LightFieldPlanInput plan;
  std::uint64_t ct_hash = 0, plan_hash = 0;
  fs::path file;
};

// FNV-1a over what a field depends on beyond its plan: its volume and storage (a VQ field also
// on its codebook's size, training tiles and seed).
std::uint64_t field_key(std::uint64_t ct_hash, std::uint64_t plan_hash, const tracking::LightFieldSpec& spec) {
  std::uint64_t h = 1469598103934665603ull;
  const auto mix = [&](std::uint64_t v) {
    for (int i = 0; i < 8; ++i) {
      h ^= (v >> (8 * i)) & 0xffu;
      h *= 1099511628211ull;
    }
  };
  mix(ct_hash);
  mix(plan_hash);
  mix(static_cast<std::uint64_t>(spec.storage));
  if (spec.storage == tracking::LightFieldStorage::kVq) {
    mix(static_cast<std::uint64_t>(spec.vq_codebook_size));
    mix(static_cast<std::uint64_t>(spec.vq_training_tiles));
    mix(spec.vq_seed);
  }
  return h;
}

std::vector<Wanted> wanted_fields(const PreparedScene& p, const fs::path& dir, const tracking::MuVolume& mu,
                                  const tracking::LightFieldSpec& spec) {
  const std::uint64_t ct_hash = tracking::volume_hash(mu);
  std::vector<Wanted> out;
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    Wanted w;
    w.view = p.scene.detectors[i].view.name;
    w.plan = p.light_field_plan(int(i));
    w.ct_hash = ct_hash;
    w.plan_hash = tracking::plan_hash(w.plan, spec);
    char key[16];
    std::snprintf(key, sizeof key, "%012llx",
                  static_cast<unsigned long long>(field_key(ct_hash, w.plan_hash, spec) & 0xffffffffffffull));
    w.file = dir / (w.view + "-" + key + ".lf");
    out.push_back(std::move(w));
  }
  return out;
}

// The name lftrack gave a view's field before fields were named after what they depend on.
fs::path earlier_name(const fs::path& dir, const std::string& view) { return dir / (view + ".lf"); }

// `file`'s field if it is the one `w` and `spec` ask for; else why not.
Result<std::shared_ptr<const tracking::LightField>> load_exact(const fs::path& file, const Wanted& w,
                                                              const tracking::LightFieldSpec& spec) {
  auto field = tracking::LightField::load(file, w.ct_hash, w.plan_hash);
  if (!field.ok()) return field.status();
  const auto& h = (*field)->header();
  if (h.storage != spec.storage ||
      (h.storage == tracking::LightFieldStorage::kVq && h.codebook_size != spec.vq_codebook_size))
    return failed_precondition(file.string() + ": stores " + tracking::to_string(h.storage) +
                               (h.storage == tracking::LightFieldStorage::kVq
                                    ? " with " + std::to_string(h.codebook_size) + " codewords"
                                    : std::string()) +
                               ", " + tracking::to_string(spec.storage) + " is asked for");
  return field;
}

// Why view `w` has no field in `dir`: what the newest other field of the view there was built
// with, setting by setting (`*others`: whether there is one).
std::string why_missing(const Wanted& w, const fs::path& dir, const tracking::LightFieldSpec& spec, bool* others) {
  *others = false;
  std::string why = w.file.string() + ": no light field of view " + w.view + " for these settings in " + dir.string();
  std::error_code ec;
  fs::path newest;
  fs::file_time_type newest_time{};
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    const bool of_view = name == w.view + ".lf" ||
                         (name.size() == w.view.size() + 16 && name.rfind(w.view + "-", 0) == 0 &&
                          name.compare(name.size() - 3, 3, ".lf") == 0);
    std::error_code time_ec;
    const auto time = it->last_write_time(time_ec);
    if (!of_view || time_ec || !it->is_regular_file(time_ec)) continue;
    if (newest.empty() || time > newest_time) {
      newest = it->path();
      newest_time = time;
    }
  }
  if (newest.empty()) return why;
  *others = true;
  auto header = tracking::LightField::read_header(newest);
  if (!header.ok()) return why + " (" + header.status().message() + ")";
  const auto differences = tracking::light_field_differences(*header, w.ct_hash, w.plan, spec);
  std::string list;
  for (const std::string& d : differences) list += (list.empty() ? "" : "; ") + d;
  return why + "; the newest field of view " + w.view + " there, " + newest.filename().string() +
         (differences.empty() ? std::string(", is for these settings but did not load")
                              : ", was built with other settings: " + list);
}

// View `w`'s field from `dir`: its own file, else one of the earlier name that is the same field.
// Not there: not found, saying why (`*others`: other fields of the view are there).
Result<std::shared_ptr<const tracking::LightField>> load_view(const Wanted& w, const fs::path& dir,
                                                             const tracking::LightFieldSpec& spec, bool* others) {
  *others = false;
  std::error_code ec;
  if (fs::exists(fs::symlink_status(w.file, ec))) return load_exact(w.file, w, spec);
  const fs::path earlier = earlier_name(dir, w.view);
  if (fs::is_regular_file(earlier, ec))
    if (auto field = load_exact(earlier, w, spec); field.ok()) return field;
  return not_found(why_missing(w, dir, spec, others));
}

}  // namespace

fs::path default_light_field_dir(const Scene& scene) {
  const std::string stem = scene.source.rfind("builtin:", 0) == 0
                               ? "builtin-" + scene.source.substr(8)
                               : fs::path(scene.source).stem().string();
  return fs::path("out") / "lightfields" / stem;
}

std::vector<fs::path> light_field_files(const PreparedScene& p, const fs::path& dir, const tracking::MuVolume* mu,
                                        const tracking::LightFieldSpec* spec) {
  std::vector<fs::path> files;
  for (const Wanted& w : wanted_fields(p, dir, mu != nullptr ? *mu : *p.mu, spec != nullptr ? *spec : p.scene.light_field))
    files.push_back(w.file);
  return files;
}

Result<Fields> build_light_fields(const PreparedScene& p, const tracking::LightFieldSpec& spec,
                                  tracking::ThreadPool* pool, const tracking::MuVolume* mu) {
  if (mu == nullptr) mu = p.mu.get();
  Fields fields;
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    const std::string& name = p.scene.detectors[i].view.name;
    ProgressBar bar("view " + name);
    auto field = tracking::LightField::build(*mu, p.light_field_plan(int(i)), spec, pool,
                                             [&](double f) { bar.update(f); });
    if (!field.ok()) return field.status().with_context("view " + name);
    bar.finish();
    fields.push_back(*field);
  }
  return fields;
}

Result<Fields> load_light_fields(const PreparedScene& p, const fs::path& dir, const tracking::MuVolume* mu,
                                 const tracking::LightFieldSpec* spec_or_null) {
  const tracking::LightFieldSpec& spec = spec_or_null != nullptr ? *spec_or_null : p.scene.light_field;
  Fields fields;
  for (const Wanted& w : wanted_fields(p, dir, mu != nullptr ? *mu : *p.mu, spec)) {
    bool others = false;
    auto field = load_view(w, dir, spec, &others);
    if (!field.ok())
      return field.status().code() == StatusCode::kNotFound
                 ? not_found(field.status().message() + "; run `lftrack precompute`")
                 : field.status();
    fields.push_back(*field);
  }
  return fields;
}

Result<Fields> load_or_build_light_fields(const PreparedScene& p, const tracking::MuVolume& mu,
                                          const tracking::LightFieldSpec& spec, const fs::path& dir,
                                          tracking::ThreadPool* pool, LightFieldCacheReport* report) {
  LightFieldCacheReport local;
  LightFieldCacheReport& r = report != nullptr ? *report : local;
  r = {};
  const std::vector<Wanted> wanted = wanted_fields(p, dir, mu, spec);
  Fields fields;
  for (std::size_t i = 0; i < wanted.size(); ++i) {
    const Wanted& w = wanted[i];
    r.files.push_back(w.file);
    bool others = false;
    auto loaded = load_view(w, dir, spec, &others);
    r.built.push_back(!loaded.ok());
    if (loaded.ok()) {
      fields.push_back(*loaded);
      continue;
    }
    // A first build is news; a field that is there but not this one (stale, or damaged) is a warning.
    if (loaded.status().code() == StatusCode::kNotFound && !others)
      spdlog::info("view {}: no light field yet in {}; building it", w.view, dir.string());
    else
      spdlog::warn("{}; building view {}'s field now", loaded.status().message(), w.view);
    tracking::LightFieldSpec float_spec = spec;
    float_spec.storage = tracking::LightFieldStorage::kFloat32;
    ProgressBar bar("view " + w.view);
    const auto t0 = std::chrono::steady_clock::now();
    auto built = tracking::LightField::build(mu, w.plan, float_spec, pool, [&](double f) { bar.update(f); });
    if (!built.ok()) return built.status().with_context("view " + w.view);
    bar.finish();
    std::shared_ptr<const tracking::LightField> field = *built;
    if (spec.storage != tracking::LightFieldStorage::kFloat32) {
      auto converted = tracking::LightField::convert(*field, spec, pool);
      if (!converted.ok()) return converted.status().with_context("view " + w.view);
      field = *converted;
    }
    spdlog::info("view {}: built in {:.1f} s; saving {}", w.view,
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), w.file.string());
    std::error_code ec;
    fs::create_directories(dir, ec);
    Status saved = ec ? io_error(dir.string() + ": cannot create folder: " + ec.message()) : field->save(w.file);
    if (!saved.ok()) {
      spdlog::warn("{}", saved.message());
      if (r.saved.ok()) r.saved = saved;
    }
    fields.push_back(std::move(field));
  }
  return fields;
}

}  // namespace lftrack::session

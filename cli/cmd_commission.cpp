// `lftrack commission`: the registration verdict commissioned for one scene (issue 52). Runs the
// known-good and known-bad cases (verdict_commissioning.hpp), prints per kind how the verdict
// judges them at the measure's default floors and at the floors it chose, checks the choice on
// cases it was not chosen from, and writes the scene's commissioning file (commissioning_file.hpp)
// with a report folder: every case as CSV and a plot of the two checks with their floors.

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <optional>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <unistd.h>

#include "cli_commands.hpp"
#include "lftrack/session/commissioning_file.hpp"
#include "lftrack/session/detector_calibration_file.hpp"
#include "lftrack/session/progress_bar.hpp"
#include "lftrack/session/scene_verdict.hpp"
#include "lftrack/studies/plot.hpp"
#include "lftrack/studies/verdict_commissioning.hpp"
#include "lftrack/tracking/thread_pool.hpp"

namespace lftrack::cli {

using session::commissioning_fingerprint;
using session::CommissioningRecord;
using session::PreparedScene;
using session::ProgressBar;
using session::scene_verdict_limits;
using session::utc_now;
using session::verdict_limits;
using session::write_commissioning_file;

using studies::choose_floors;
using studies::choose_view_shift_limit;
using studies::ChosenFloors;
using studies::CommissionCase;
using studies::CommissionCaseResult;
using studies::CommissionOptions;
using studies::CommissionTally;
using studies::draw_grouped_scatter;
using studies::floor_margins;
using studies::FloorMargins;
using studies::GroupedScatterPlot;
using studies::is_right_result;
using studies::kCommissionCaseKinds;
using studies::kDefaultFloorMarginFraction;
using studies::kMinViewShiftLimitMm;
using studies::largest_view_shift_mm;
using studies::lowest_view_check_ncc;
using studies::lowest_view_similarity;
using studies::must_refuse;
using studies::other_checks;
using studies::OtherChecks;
using studies::PointGroup;
using studies::run_commission_cases;
using studies::without_floors;

using loop::judge_registration;
using loop::judges_view_shift;
using loop::VerdictLimits;
namespace {

namespace fs = std::filesystem;

struct CommissionCliOptions {
  SceneOptions scene;
  std::string out, report_dir, other_scene, lf_dir;
  int good = 100, bad = 1000;
  std::uint64_t seed = 1;
  double tolerance_mm = 0, level_mm = 30, max_false_reject_rate = 0.05;
  double min_margin = kDefaultFloorMarginFraction;
  bool replace = false, dry_run = false, check = false;
  std::string command_line;
};

// Where the commissioning file may go: not a folder, a device, a link, the scene itself or into the
// report folder; an existing file only with --replace, and only when it is a commissioning file
// (a replace never destroys anything else).
Status check_output_file(const fs::path& out, bool replace, const std::string& scene, const fs::path& report) {
  std::error_code ec;
  const fs::file_status status = fs::symlink_status(out, ec);
  if (fs::is_directory(status)) return invalid_argument(out.string() + ": a folder; --out names the commissioning file");
  if (fs::exists(status) && !fs::is_regular_file(status))
    return invalid_argument(out.string() + ": not a regular file (a link, a device or a pipe); the commissioning file "
                                           "is written as a file of its own");
  const fs::path out_abs = fs::weakly_canonical(out, ec);
  if (out_abs == fs::weakly_canonical(scene, ec))
    return invalid_argument(out.string() + ": the scene itself; the commissioning file goes beside it");
  const fs::path report_abs = fs::weakly_canonical(report, ec);
  if (out_abs.parent_path() == report_abs)
    return invalid_argument(out.string() + ": inside the report folder " + report.string() +
                            ", whose files a run rewrites; put it elsewhere");
  if (!fs::exists(status)) return {};
  if (!replace) return failed_precondition(out.string() + ": exists; say --replace to commission the scene again over it");
  std::ifstream in(out);
  std::string first_lines, line;
  for (int i = 0; i < 8 && std::getline(in, line); ++i) first_lines += line + '\n';
  if (first_lines.find("\nlftrack_commissioning: ") == std::string::npos)
    return failed_precondition(out.string() + ": not a commissioning file; --replace replaces only one of those");
  return {};
}

// A file can be made in `folder` (made and removed at once).
Status check_writable(const fs::path& folder, const std::string& what) {
  const fs::path probe = folder / (".lftrack-write-probe-" + std::to_string(::getpid()));
  {
    std::ofstream f(probe);
    if (!f) return io_error(folder.string() + ": cannot write in " + what);
  }
  std::error_code ec;
  fs::remove(probe, ec);
  return {};
}


std::string rate(int n, int of) {
  char s[32];
  if (of == 0) return "-";
  std::snprintf(s, sizeof s, "%.2f %%", 100.0 * n / of);
  return s;
}

using Tallies = std::array<CommissionTally, kCommissionCaseKinds + 1>;

// The least evidence a commissioning file is written from.
constexpr int kMinGoodToWrite = 10;
constexpr int kMinBadToWrite = 70;

// SplitMix64's finaliser of `index`: which half of the held-out split a case falls in.
bool in_fit_half(std::uint64_t index) {
  std::uint64_t z = index + 0x9e3779b97f4a7c15ULL;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return ((z ^ (z >> 31)) & 1) == 0;
}

void print_tallies(const char* title, const Tallies& t) {
  std::printf("%s\n  %-20s %6s %9s %9s %9s %9s\n", title, "kind", "cases", "acc.right", "FALSE ACC", "false rej",
              "rej.wrong");
  for (int k = 0; k <= kCommissionCaseKinds; ++k) {
    const CommissionTally& x = t[std::size_t(k)];
    if (x.cases == 0) continue;
    std::printf("  %-20s %6d %9d %9d %9d %9d\n", k == kCommissionCaseKinds ? "all" : to_string(CommissionCase(k)),
                x.cases, x.accepted_right, x.accepted_wrong, x.rejected_right, x.rejected_wrong);
  }
}

std::string tally_yaml(const Tallies& t, const char* indent) {
  std::ostringstream y;
  for (int k = 0; k <= kCommissionCaseKinds; ++k) {
    const CommissionTally& x = t[std::size_t(k)];
    if (x.cases == 0) continue;
    y << indent << '"' << (k == kCommissionCaseKinds ? "all" : to_string(CommissionCase(k))) << "\": {cases: " << x.cases
      << ", accepted_right: " << x.accepted_right << ", false_accepts: " << x.accepted_wrong
      << ", false_rejects: " << x.rejected_right << ", rejected_wrong: " << x.rejected_wrong << "}\n";
  }
  return y.str();
}

std::string number(double v) {
  if (!std::isfinite(v)) return ".nan";  // YAML's not-a-number (the file); printed as "none" (margin_text)
  std::ostringstream s;
  s.precision(6);
  s << v;
  return s.str();
}

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

void print_other_checks(const OtherChecks& o, const VerdictLimits& defaults) {
  std::printf("the verdict's other checks, at the measure's default floors: false accepts %d without them, %d with "
              "the envelope's edge band (%.3g mm, %.3g deg; it refused %d right)",
              o.accepted_wrong_without, o.accepted_wrong_edge, defaults.envelope_edge_mm, defaults.envelope_edge_deg,
              o.rejected_right_edge);
  if (!o.view_check) {
    std::printf("; no view check (safety.max_view_shift_mm: 0, or one view)\n");
    return;
  }
  std::printf(", %d with the view check too\n", o.accepted_wrong_both);
  std::printf("  view check (each view registered alone, at most %.3g mm across it): right results' largest shift "
              "median %.3g mm, max %.3g mm (%d results; %d refused); %.1f ms median, %.1f ms p95 a result\n",
              defaults.max_view_shift_mm, o.right_shift_median_mm, o.right_shift_max_mm, o.right_with_shift,
              o.rejected_right_view, o.check_ms_median, o.check_ms_p95);
}

std::string other_checks_yaml(const OtherChecks& o, const std::string& indent) {
  std::ostringstream y;
  y << indent << "other_checks_at_defaults: {false_accepts_without: " << o.accepted_wrong_without
    << ", with_edge_band: " << o.accepted_wrong_edge << ", with_view_check_too: " << o.accepted_wrong_both
    << ", right_refused_by_edge_band: " << o.rejected_right_edge << ", right_refused_by_view_check: "
    << o.rejected_right_view << ", right_largest_view_shift_mm: {median: " << number(o.right_shift_median_mm)
    << ", max: " << number(o.right_shift_max_mm) << "}, view_check_ms: {median: " << number(o.check_ms_median)
    << ", p95: " << number(o.check_ms_p95) << "}}\n";
  return y.str();
}

// Every case: its kind, the patient's pose, the two checks, the TRE, the result's pose, and the
// verdict at the measure's default floors.
Status write_cases_csv(const fs::path& file, const std::vector<CommissionCaseResult>& cases,
                       const VerdictLimits& defaults) {
  std::ofstream f(file);
  if (!f) return io_error(file.string() + ": cannot write");
  f << "kind,gold_tx_mm,gold_ty_mm,gold_tz_mm,gold_rx_deg,gold_ry_deg,gold_rz_deg,registered,lowest_similarity,"
       "lowest_check_ncc,tre_mean_mm,ms,result_tx_mm,result_ty_mm,result_tz_mm,result_rx_deg,result_ry_deg,"
       "result_rz_deg,verdict_at_defaults,largest_view_shift_mm,view_check_ms\n";
  f.precision(6);
  for (const CommissionCaseResult& c : cases) {
    f << to_string(c.kind);
    for (int i = 0; i < 6; ++i) f << ',' << (i < 3 ? c.gold_delta[i] : tracking::rad_to_deg(c.gold_delta[i]));
    f << ',' << c.registered << ',' << (c.registered ? lowest_view_similarity(c.input) : kNaN) << ','
      << (c.registered ? lowest_view_check_ncc(c.input) : kNaN) << ',' << c.tre_mean_mm << ',' << c.ms;
    const tracking::Vector6d& d = c.input.delta_from_nominal;
    for (int i = 0; i < 6; ++i) f << ',' << (c.registered ? (i < 3 ? d[i] : tracking::rad_to_deg(d[i])) : kNaN);
    f << ',' << to_string(judge_registration(defaults, c.input).reason) << ',' << largest_view_shift_mm(c.input) << ','
      << c.view_check_ms << '\n';
  }
  f.flush();
  if (!f) return io_error(file.string() + ": write failed (disk full?)");
  return {};
}

Status draw_plot(const fs::path& png, const std::vector<CommissionCaseResult>& cases, double tolerance_mm,
                 const VerdictLimits& defaults, const ChosenFloors& floors, const std::string& scene,
                 const std::string& measure) {
  GroupedScatterPlot plot;
  plot.title = "Verdict commissioning: " + scene + " (the cases the floors decide: those the other checks pass)";
  plot.x_label = measure + " at the result (lowest view)";
  plot.y_label = "check NCC at the result (lowest view)";
  PointGroup right, wrong_good;
  right.name = "good, right (TRE < " + number(tolerance_mm) + " mm)";
  wrong_good.name = "good start, wrong result";
  std::array<PointGroup, kCommissionCaseKinds> bad;
  for (int k = 0; k < kCommissionCaseKinds; ++k) bad[std::size_t(k)].name = to_string(CommissionCase(k));
  const VerdictLimits open = without_floors(defaults);
  for (const CommissionCaseResult& c : cases) {
    if (!c.registered || !judge_registration(open, c.input).ok) continue;
    const double x = lowest_view_similarity(c.input), y = lowest_view_check_ncc(c.input);
    PointGroup* g = must_refuse(c.kind)                     ? &bad[std::size_t(c.kind)]
                    : is_right_result(c, tolerance_mm) ? &right
                                                            : &wrong_good;
    g->x.push_back(x);
    g->y.push_back(y);
  }
  plot.groups.push_back(right);
  if (!wrong_good.x.empty()) plot.groups.push_back(wrong_good);
  for (const PointGroup& g : bad)
    if (!g.x.empty()) plot.groups.push_back(g);
  plot.lines = {{true, floors.min_similarity, "commissioned", false},
                {true, defaults.min_similarity, "default", true},
                {false, floors.min_check_ncc, "commissioned check floor", false},
                {false, defaults.min_check_ncc, "default check floor", true}};
  plot.key_position = "outside right";
  auto drawn = draw_grouped_scatter(plot, png);
  if (!drawn.ok()) return drawn.status();
  return {};
}

// --check: the cases judged by the verdict as the scene has it (its commissioning file's floors,
// or the defaults): no wrong result may be accepted, and no more right ones rejected than allowed.
Status check_scene_verdict(const PreparedScene& p, const VerdictLimits& limits, const std::string& floors_from,
                           const std::vector<CommissionCaseResult>& cases, double tolerance,
                           double max_false_reject_rate, double seconds) {
  const Tallies t = tally_commission(cases, limits, tolerance);
  const CommissionTally& all = t[kCommissionCaseKinds];
  const int right = all.accepted_right + all.rejected_right, wrong = all.accepted_wrong + all.rejected_wrong;
  std::printf("checked %s: %zu cases in %.0f s (%s, tolerance %.2f mm); floors: %s\n", p.scene.source.c_str(),
              cases.size(), seconds, p.scene.registration.similarity.c_str(), tolerance, floors_from.c_str());
  print_tallies("at the scene's floors", t);
  std::printf("  false accepts %s of %d wrong, false rejects %s of %d right (floors %s %.4f, check NCC %.4f)\n",
              rate(all.accepted_wrong, wrong).c_str(), wrong, rate(all.rejected_right, right).c_str(), right,
              p.scene.registration.similarity.c_str(), limits.min_similarity, limits.min_check_ncc);
  if (all.accepted_wrong > 0)
    return failed_precondition("the scene's verdict accepted " + std::to_string(all.accepted_wrong) +
                               " wrong result(s): commission it again, or do not treat with it");
  if (right > 0 && double(all.rejected_right) / right > max_false_reject_rate)
    return failed_precondition("the scene's verdict rejected " + rate(all.rejected_right, right) +
                               " of right results (allowed " + rate(int(std::lround(max_false_reject_rate * 1000)), 1000) +
                               ")");
  return {};
}

Status run(const CommissionCliOptions& o) {
  if (!o.check && !o.dry_run && (o.good < kMinGoodToWrite || o.bad < kMinBadToWrite))
    return invalid_argument("a commissioning file is measured from at least " + std::to_string(kMinGoodToWrite) +
                            " good and " + std::to_string(kMinBadToWrite) +
                            " bad cases (10 of each bad kind); fewer is a --dry-run or a --check");
  if (o.scene.scene.rfind("builtin:", 0) == 0 && o.out.empty() && !o.dry_run && !o.check)
    return invalid_argument("a built-in scene names no commissioning file: give --out FILE (or --dry-run)");
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = load_prepared_scene(o.scene, &pool);
  if (!prepared.ok()) return prepared.status();
  const PreparedScene& p = *prepared;
  // --check judges with the scene's verdict: a stale or missing commissioning file fails now,
  // not after the cases.
  std::optional<VerdictLimits> scene_limits;
  std::string floors_from;
  if (o.check) {
    auto limits = scene_verdict_limits(p, p.scene.registration.similarity, &floors_from);
    if (!limits.ok()) return limits.status();
    scene_limits = *limits;
  }
  fs::path out = o.out.empty() ? fs::path(p.scene.commissioning_file) : fs::path(o.out);
  if (out.empty())
    out = fs::path(p.scene.source).parent_path() / (fs::path(p.scene.source).stem().string() + ".commissioning.yaml");
  std::error_code ec;
  // --check's cases go beside the commissioning's report, never over it.
  const std::string report_name = fs::path(p.scene.source).stem().string() + (o.check ? "-check" : "");
  const fs::path report = o.report_dir.empty() ? fs::path("out/commission") / report_name : fs::path(o.report_dir);
  if (!o.dry_run && !o.check) LFTRACK_RETURN_IF_ERROR(check_output_file(out, o.replace, p.scene.source, report));
  // The report folder and the file's folder before the cases: minutes of work are not lost to a
  // folder that cannot be made or written.
  fs::create_directories(report, ec);
  if (ec || !fs::is_directory(report, ec))
    return io_error(report.string() + ": cannot create the report folder" + (ec ? ": " + ec.message() : ""));
  LFTRACK_RETURN_IF_ERROR(check_writable(report, "the report folder"));
  if (!o.dry_run && !o.check) {
    const fs::path folder = out.parent_path().empty() ? fs::path(".") : out.parent_path();
    if (!fs::is_directory(folder, ec)) return invalid_argument(out.string() + ": no folder " + folder.string());
    LFTRACK_RETURN_IF_ERROR(check_writable(folder, "the commissioning file's folder"));
  }
  std::optional<PreparedScene> other;
  if (!o.other_scene.empty()) {
    SceneOptions other_options = o.scene;
    other_options.scene = o.other_scene;
    other_options.ct.clear();
    auto loaded = load_prepared_scene(other_options, &pool);
    if (!loaded.ok()) return loaded.status().with_context("--other-scene");
    if (commissioning_fingerprint(*loaded).ct == commissioning_fingerprint(p).ct)
      return invalid_argument("--other-scene " + o.other_scene +
                              ": the same CT as the scene; another patient's frames need another patient's CT");
    other.emplace(std::move(loaded).value());
  }
  auto defaults = verdict_limits(p.scene, p.scene.registration.similarity);
  if (!defaults.ok()) return defaults.status();
  if (o.tolerance_mm > p.scene.safety.beam_tolerance_mm)
    return invalid_argument("--tolerance-mm " + number(o.tolerance_mm) + " exceeds the scene's safety.beam_tolerance_mm (" +
                            number(p.scene.safety.beam_tolerance_mm) +
                            " mm): results that far off would count as right and loosen the floors");
  const double tolerance = o.tolerance_mm > 0 ? o.tolerance_mm : p.scene.safety.beam_tolerance_mm;
  if (o.level_mm < 2 * tolerance)
    return invalid_argument("--level-mm " + number(o.level_mm) + " is under twice the tolerance (" + number(tolerance) +
                            " mm): a result one such level off is nearly right, not a wrong level");

  CommissionOptions options;
  options.good_cases = o.good;
  options.bad_cases = o.bad;
  options.seed = o.seed;
  options.tolerance_mm = tolerance;
  options.level_mm = o.level_mm;
  options.other_patient = other ? &*other : nullptr;
  options.renderer = p.scene.renderer;  // the loop's registration renderer, which the fingerprint records
  options.light_field_dir = o.lf_dir;
  options.pool = &pool;
  ProgressBar bar("commission " + p.scene.source);
  options.progress = [&](int done, int total) { bar.update(double(done) / total); };
  auto cases = run_commission_cases(p, options);
  if (!cases.ok()) return cases.status();
  const double seconds = bar.finish();

  if (scene_limits) {
    LFTRACK_RETURN_IF_ERROR(write_cases_csv(report / "cases.csv", *cases, *defaults));
    std::printf("report: %s (cases.csv)\n", report.string().c_str());
    return check_scene_verdict(p, *scene_limits, floors_from, *cases, tolerance, o.max_false_reject_rate, seconds);
  }
  const ChosenFloors floors = choose_floors(*cases, *defaults, tolerance, o.min_margin);
  VerdictLimits commissioned = *defaults;
  commissioned.min_similarity = floors.min_similarity;
  commissioned.min_check_ncc = floors.min_check_ncc;
  commissioned.max_view_shift_mm = choose_view_shift_limit(*cases, *defaults, tolerance);
  const Tallies before = tally_commission(*cases, *defaults, tolerance);
  const Tallies after = tally_commission(*cases, commissioned, tolerance);
  // Held out: floors chosen from half the cases, judged on the other half. The halves are drawn
  // by a hash of the case's index, not its parity: cases alternate within a kind (the wrong
  // level's up and down), and parity would put each direction in one half.
  std::vector<CommissionCaseResult> fit, held;
  for (std::size_t i = 0; i < cases->size(); ++i) (in_fit_half(i) ? fit : held).push_back((*cases)[i]);
  const ChosenFloors fit_floors = choose_floors(fit, *defaults, tolerance, o.min_margin);
  VerdictLimits fit_limits = *defaults;
  fit_limits.min_similarity = fit_floors.min_similarity;
  fit_limits.min_check_ncc = fit_floors.min_check_ncc;
  fit_limits.max_view_shift_mm = choose_view_shift_limit(fit, *defaults, tolerance);
  const Tallies held_out = tally_commission(held, fit_limits, tolerance);

  const CommissionTally& all_before = before[kCommissionCaseKinds];
  const CommissionTally& all_after = after[kCommissionCaseKinds];
  const CommissionTally& all_held = held_out[kCommissionCaseKinds];
  const auto wrong = [](const CommissionTally& t) { return t.accepted_wrong + t.rejected_wrong; };
  const auto right = [](const CommissionTally& t) { return t.accepted_right + t.rejected_right; };
  std::printf("commissioned %s: %zu cases in %.0f s (%s, tolerance %.2f mm)\n", p.scene.source.c_str(), cases->size(),
              seconds, p.scene.registration.similarity.c_str(), tolerance);
  print_tallies("at the measure's default floors", before);
  std::printf("  false accepts %s of %d wrong, false rejects %s of %d right (floors %s %.4f, check NCC %.4f)\n",
              rate(all_before.accepted_wrong, wrong(all_before)).c_str(), wrong(all_before),
              rate(all_before.rejected_right, right(all_before)).c_str(), right(all_before),
              p.scene.registration.similarity.c_str(), defaults->min_similarity, defaults->min_check_ncc);
  print_tallies("at the commissioned floors", after);
  std::printf("  false accepts %s of %d wrong, false rejects %s of %d right (floors %s %.4f, check NCC %.4f)\n",
              rate(all_after.accepted_wrong, wrong(all_after)).c_str(), wrong(all_after),
              rate(all_after.rejected_right, right(all_after)).c_str(), right(all_after),
              p.scene.registration.similarity.c_str(), floors.min_similarity, floors.min_check_ncc);
  if (judges_view_shift(commissioned)) {
    const bool capped = commissioned.max_view_shift_mm >= defaults->max_view_shift_mm;
    std::printf("  view check: each view alone moves the target at most %.3g mm (%s)\n", commissioned.max_view_shift_mm,
                (capped ? std::string("the scene's safety.max_view_shift_mm")
                        : "twice the right results' largest shift, and at least " + number(kMinViewShiftLimitMm) + " mm")
                    .c_str());
  }
  const auto margin_text = [](double v) { return std::isfinite(v) ? number(v) : std::string("none"); };
  std::printf("  margins: %s floor %.4f between wrong %s and right %s; check NCC floor %.4f between wrong %s and right %s\n",
              p.scene.registration.similarity.c_str(), floors.min_similarity,
              margin_text(floors.wrong_similarity_below).c_str(), margin_text(floors.right_similarity_above).c_str(),
              floors.min_check_ncc, margin_text(floors.wrong_check_below).c_str(),
              margin_text(floors.right_check_above).c_str());
  const FloorMargins margins = floor_margins(*defaults, o.min_margin);
  std::printf("  each wrong result refused by a floor by at least its margin: %s %s, check NCC %s (--min-margin %s)\n",
              p.scene.registration.similarity.c_str(), number(margins.similarity).c_str(),
              number(margins.check_ncc).c_str(), number(o.min_margin).c_str());
  std::printf("held out (floors chosen from half the cases, judged on the other half): false accepts %s of %d, false "
              "rejects %s of %d\n",
              rate(all_held.accepted_wrong, wrong(all_held)).c_str(), wrong(all_held),
              rate(all_held.rejected_right, right(all_held)).c_str(), right(all_held));
  VerdictLimits defaults_with_view_limit = *defaults;
  defaults_with_view_limit.max_view_shift_mm = commissioned.max_view_shift_mm;
  const OtherChecks others = other_checks(*cases, defaults_with_view_limit, tolerance);
  print_other_checks(others, defaults_with_view_limit);

  LFTRACK_RETURN_IF_ERROR(write_cases_csv(report / "cases.csv", *cases, *defaults));
  if (Status drawn = draw_plot(report / "verdict.png", *cases, tolerance, *defaults, floors, p.scene.source,
                               p.scene.registration.similarity);
      !drawn.ok())
    spdlog::warn("verdict.png not drawn: {}", drawn.message());  // the figures are printed and written anyway
  std::printf("report: %s (cases.csv, verdict.png)\n", report.string().c_str());

  const int right_cases = right(all_after);
  const double false_reject_rate = right_cases > 0 ? double(all_after.rejected_right) / right_cases : 1.0;
  if (right_cases == 0)
    return failed_precondition("no good case registered right (TRE under " + number(tolerance) +
                               " mm): there is nothing to set floors against; nothing written (--good 0, or a scene "
                               "whose registration fails: see the report)");
  const int held_right = right(all_held);
  if (held_right > 0 && double(all_held.rejected_right) / held_right > o.max_false_reject_rate)
    return failed_precondition("floors chosen from half the cases rejected " +
                               rate(all_held.rejected_right, held_right) + " of the other half's right results (allowed " +
                               rate(int(std::lround(o.max_false_reject_rate * 1000)), 1000) +
                               "): they do not generalise; nothing written. Run more cases (--good, --bad)");
  if (all_held.accepted_wrong > 0)
    return failed_precondition(
        "floors chosen from half the cases accepted " + std::to_string(all_held.accepted_wrong) +
        " wrong result(s) of the other half: the floors do not generalise from this many cases; nothing written. Run "
        "more cases (--good, --bad) or look at the plot for wrong results among the right ones");
  if (false_reject_rate > o.max_false_reject_rate || all_after.accepted_wrong > 0)
    return failed_precondition(
        "the verdict cannot be commissioned for this scene as it is: at floors that refuse every wrong result it "
        "rejects " + rate(all_after.rejected_right, right_cases) + " of " + std::to_string(right_cases) +
        " right ones (allowed: " + rate(int(std::lround(o.max_false_reject_rate * 1000)), 1000) +
        "); nothing written. The plot shows where they overlap; a plan or ROI that registers this anatomy better "
        "comes first");
  if (o.dry_run) {
    std::printf("dry run: no commissioning file written\n");
    return {};
  }
  CommissioningRecord record;
  record.fingerprint = commissioning_fingerprint(p);
  record.measure = p.scene.registration.similarity;
  record.min_similarity = floors.min_similarity;
  record.min_check_ncc = floors.min_check_ncc;
  record.max_view_shift_mm = judges_view_shift(commissioned) ? commissioned.max_view_shift_mm : 0;
  record.scene = p.scene.source;
  record.made_utc = utc_now();
  record.command = o.command_line;
  std::ostringstream measured;
  measured << "measured:\n  cases: " << cases->size() << "\n  tolerance_mm: " << number(tolerance)
           << "\n  seconds: " << number(seconds) << "\n  defaults:\n    floors: {min_similarity: "
           << number(defaults->min_similarity) << ", min_check_ncc: " << number(defaults->min_check_ncc) << "}\n"
           << tally_yaml(before, "    ") << "  commissioned:\n" << tally_yaml(after, "    ")
           << "  margins:\n    similarity: {wrong_below: " << number(floors.wrong_similarity_below)
           << ", right_above: " << number(floors.right_similarity_above) << "}\n    check_ncc: {wrong_below: "
           << number(floors.wrong_check_below) << ", right_above: " << number(floors.right_check_above)
           << "}\n  held_out:\n    floors: {min_similarity: " << number(fit_floors.min_similarity)
           << ", min_check_ncc: " << number(fit_floors.min_check_ncc)
           << ", max_view_shift_mm: " << number(fit_limits.max_view_shift_mm) << "}\n" << tally_yaml(held_out, "    ")
           << "  min_margin: {fraction: " << number(o.min_margin) << ", similarity: " << number(margins.similarity)
           << ", check_ncc: " << number(margins.check_ncc) << "}\n" << other_checks_yaml(others, "  ");
  LFTRACK_RETURN_IF_ERROR(write_commissioning_file(out, record, measured.str(), o.replace));
  std::printf("wrote %s\n", out.string().c_str());
  if (p.scene.commissioning_file.empty() || fs::weakly_canonical(p.scene.commissioning_file, ec) != fs::weakly_canonical(out, ec))
    std::printf("the scene does not name it yet: add to %s\n  safety:\n    commissioning: %s\n", p.scene.source.c_str(),
                out.string().c_str());
  return {};
}

}  // namespace

Command add_commission_command(CLI::App* parent, int argc, char** argv) {
  auto* app = parent->add_subcommand(
      "commission", "Commission the registration verdict for a scene: its floors from known-good and known-bad cases");
  auto o = std::make_shared<CommissionCliOptions>();
  // The command as a user types it: the program by its name, not the path it ran from.
  for (int i = 0; i < argc; ++i)
    o->command_line += std::string(i ? " " : "") + (i == 0 ? fs::path(argv[0]).filename().string() : argv[i]);
  add_scene_options(app, &o->scene);
  auto* out = app->add_option("--out", o->out,
                               "The commissioning file (default: the scene's safety.commissioning, else "
                               "<scene>.commissioning.yaml beside it)")
                   ->check(not_empty());
  auto* replace =
      app->add_flag("--replace", o->replace, "Replace an existing commissioning file (only a commissioning file)");
  auto* dry_run = app->add_flag("--dry-run", o->dry_run, "Measure and report; write no commissioning file");
  app->add_flag("--check", o->check,
                "Judge new cases with the scene's verdict as it stands (its commissioning file): fail on any false "
                "accept, or on more false rejects than allowed; no commissioning file is written (the cases go to "
                "out/commission/<scene stem>-check)")
      ->excludes(out)
      ->excludes(replace)
      ->excludes(dry_run);
  app->add_option("--good", o->good, "Known-good cases (half alignments, half tracking)")
      ->check(CLI::Range(0, 100000))
      ->capture_default_str();
  app->add_option("--bad", o->bad, "Known-bad cases, spread over the bad kinds")
      ->check(CLI::Range(0, 1000000))
      ->capture_default_str();
  app->add_option("--seed", o->seed, "Seed of the cases' poses and noise")->check(seed_value())->capture_default_str();
  app->add_option("--other-scene", o->other_scene,
                  "Another patient's scene (same detector sizes): its frames are cases to refuse")
      ->check(not_empty());
  app->add_option("--tolerance-mm", o->tolerance_mm,
                  "A result is right when its mean TRE is under this (default: the scene's safety.beam_tolerance_mm)")
      ->check(finite_in(0, 50, true));
  app->add_option("--level-mm", o->level_mm, "One vertebral level along the room's z (the wrong-level cases)")
      ->check(finite_in(1, 200))
      ->capture_default_str();
  app->add_option("--max-false-rejects", o->max_false_reject_rate,
                  "The largest fraction of right results the floors may reject before nothing is written")
      ->check(finite_in(0, 1))
      ->capture_default_str();
  app->add_option("--min-margin", o->min_margin,
                  "Each wrong result must lie below a floor by this fraction of the floor's default above what "
                  "unrelated images score (mi: of 0.3; check NCC: of 0.76)")
      ->check(finite_in(0, 1))
      ->capture_default_str();
  app->add_option("--report", o->report_dir, "Report folder (default: out/commission/<scene stem>, -check for --check)")
      ->check(not_empty());
  app->add_option("--lf-dir", o->lf_dir, "Light-field folder (default: out/lightfields/<scene>)")->check(not_empty());
  return [o] { return run(*o); };
}

}  // namespace lftrack::cli

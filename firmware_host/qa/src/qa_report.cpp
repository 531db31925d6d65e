#include "lftrack/qa/qa_report.hpp"

#include "lftrack/qa/qa_time.hpp"
#include "lftrack/session/scene_fingerprint.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <ctime>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <vector>

namespace lftrack::qa {
namespace {

namespace fs = std::filesystem;
using tracking::rad_to_deg;

nlohmann::json pose_json(const tracking::Vector6d& v) {
  return {{"translation_mm", {v(0), v(1), v(2)}},
          {"rotation_deg", {rad_to_deg(v(3)), rad_to_deg(v(4)), rad_to_deg(v(5))}}};
}

nlohmann::json to_json(const DailyQaReport& r) {
  nlohmann::json j;
  j["kind"] = fmt::format("lftrack {} QA", r.kind);  // daily, e2e, detector
  j["scene"] = r.scene_name;
  j["scene_file"] = r.scene_source;
  j["room_fingerprint"] = r.room_fingerprint;
  j["started_utc"] = r.started_utc;
  j["started_local"] = r.started_local;
  j["date"] = r.date;
  j["passed"] = r.passed();
  j["standard"] = r.standard;
  j["interrupted"] = r.interrupted;
  if (r.kind == "e2e")
    j["tolerance"] = {{"mm", r.tolerance_mm}};
  else if (r.kind == "daily")  // the detector QA's tolerances are its checks' own
    j["tolerance"] = {{"mm", r.tolerance_mm}, {"deg", r.tolerance_deg}};
  for (const QaCheck& c : r.checks)
    j["checks"].push_back({{"name", c.name},
                           {"passed", c.passed},
                           {"tolerance", c.tolerance},
                           {"measured", c.measured},
                           {"why", c.why}});
  for (const OffsetResult& o : r.offsets)
    j["offsets"].push_back({{"shift", pose_json(o.shift)},
                            {"registered", pose_json(o.registered)},
                            {"couch_moved", pose_json(o.couch_moved)},
                            {"registration_error_mm", o.registration_error_mm},
                            {"registration_error_deg", o.registration_error_deg},
                            {"couch_error_mm", o.couch_error_mm},
                            {"couch_error_deg", o.couch_error_deg},
                            {"final_offset_mm", o.final_offset_mm},
                            {"aligned", o.aligned},
                            {"passed", o.passed},
                            {"why", o.why}});
  j["not_checked"] = r.not_checked;
  if (r.kind == "e2e") {
    j["marker_offset_room_mm"] = {r.marker_offset_room_mm.x(), r.marker_offset_room_mm.y(),
                                  r.marker_offset_room_mm.z()};
    j["marker_error_mm"] = r.marker_error_mm;
  }
  return j;
}

// The result cell of a check or a shift: "pass", or "FAIL: why" (escaped).
std::string result_cell(bool passed, const std::string& why);

std::string escaped(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::string result_cell(bool passed, const std::string& why) {
  if (passed) return "<td class='pass'>pass</td>";
  std::string cell = "<td class='fail'>FAIL: ";
  cell += escaped(why);
  cell += "</td>";
  return cell;
}

// A picture's frame: the tolerance as a dashed line, the scale's top value, the baseline.
void svg_axes(std::ostringstream& s, double tolerance_mm, double scale_mm, double y_tolerance, int left,
              int width, int top, double baseline) {
  s << fmt::format("<line x1='{}' y1='{:.1f}' x2='{}' y2='{:.1f}' stroke='#c00' stroke-dasharray='4 3'/>",
                   left, y_tolerance, width - 10, y_tolerance);
  s << fmt::format("<text x='{}' y='{:.1f}' font-size='11' fill='#c00'>tolerance {} mm</text>", width - 130,
                   y_tolerance - 4, tolerance_mm);
  s << fmt::format("<text x='2' y='{}' font-size='11'>{:.2f} mm</text>", top + 4, scale_mm);
  s << fmt::format("<line x1='{}' y1='{:.1f}' x2='{}' y2='{:.1f}' stroke='#333'/>", left, baseline,
                   width - 10, baseline);
}

// Each shift's registration and couch errors as bars, the tolerance as a line across them.
std::string offset_picture(const DailyQaReport& r) {
  const int bar = 14, gap = 10, width = 640, left = 40, height = 220, top = 20, bottom = 40;
  double scale_mm = 2 * r.tolerance_mm;
  for (const OffsetResult& o : r.offsets)
    scale_mm =
        std::max({scale_mm, std::min(o.registration_error_mm, 10.0), std::min(o.couch_error_mm, 10.0)});
  const double plot = height - top - bottom;
  auto y = [&](double mm) { return top + plot * (1 - std::min(mm, scale_mm) / scale_mm); };
  std::ostringstream s;
  s << "<svg xmlns='http://www.w3.org/2000/svg' width='" << width << "' height='" << height
    << "' role='img' aria-label='offset test errors'>";
  svg_axes(s, r.tolerance_mm, scale_mm, y(r.tolerance_mm), left, width, top, top + plot);
  int x = left + gap;
  for (std::size_t i = 0; i < r.offsets.size(); ++i) {
    const OffsetResult& o = r.offsets[i];
    s << fmt::format(
        "<rect x='{}' y='{:.1f}' width='{}' height='{:.1f}' fill='{}'><title>alignment {:.3f} "
        "mm</title></rect>",
        x, y(o.registration_error_mm), bar, top + plot - y(o.registration_error_mm),
        o.passed ? "#2a7" : "#c33", o.registration_error_mm);
    s << fmt::format(
        "<rect x='{}' y='{:.1f}' width='{}' height='{:.1f}' fill='{}'><title>couch {:.3f} mm</title></rect>",
        x + bar, y(o.couch_error_mm), bar, top + plot - y(o.couch_error_mm), o.passed ? "#7bd" : "#e88",
        o.couch_error_mm);
    s << fmt::format("<text x='{}' y='{}' font-size='11'>{}</text>", x + 4, top + plot + 14, i + 1);
    x += 2 * bar + gap;
  }
  s << fmt::format(
      "<text x='{}' y='{}' font-size='11'>shift; bars: alignment error (left), couch error "
      "(right)</text></svg>",
      left, height - 6);
  return s.str();
}

// The hidden marker's error in each beam-on cycle, the tolerance as a line.
std::string marker_picture(const DailyQaReport& r) {
  const int width = 640, height = 220, left = 40, top = 20, bottom = 40;
  double scale = 2 * r.tolerance_mm;
  for (double e : r.marker_error_mm) scale = std::max(scale, std::min(e, 20.0));
  const double plot_w = width - left - 10, plot_h = height - top - bottom;
  auto y = [&](double mm) { return top + plot_h * (1 - std::min(mm, scale) / scale); };
  std::ostringstream s;
  s << "<svg xmlns='http://www.w3.org/2000/svg' width='" << width << "' height='" << height
    << "' role='img' aria-label='hidden marker error'><polyline fill='none' stroke='#27a' points='";
  const std::size_t n = r.marker_error_mm.size();
  for (std::size_t i = 0; i < n; ++i)
    s << fmt::format(
        "{:.1f},{:.1f} ",
        left + plot_w * static_cast<double>(i) / static_cast<double>(std::max<std::size_t>(n - 1, 1)),
        y(r.marker_error_mm[i]));
  s << "'/>";
  svg_axes(s, r.tolerance_mm, scale, y(r.tolerance_mm), left, width, top, top + plot_h);
  s << fmt::format(
      "<text x='{}' y='{}' font-size='11'>beam-on cycles ({}); the hidden marker's error</text></svg>", left,
      height - 6, n);
  return s.str();
}

std::string to_html(const DailyQaReport& r) {
  std::ostringstream h;
  const bool e2e = r.kind == "e2e";
  const std::string title = e2e ? "end-to-end" : r.kind;
  h << "<!doctype html><html lang='en'><head><meta charset='utf-8'><title>lftrack " << title << " QA "
    << escaped(r.date)
    << "</title><style>body{font-family:sans-serif;margin:2em}td,th{padding:4px 8px;border-bottom:1px solid "
       "#ddd;"
       "text-align:left;vertical-align:top}.pass{color:#175}.fail{color:#b00;font-weight:bold}</style></"
       "head><body>";
  h << "<h1>" << char(std::toupper(static_cast<unsigned char>(title[0]))) << title.substr(1)
    << " QA: <span class='" << (r.passed() ? "pass'>PASSED" : "fail'>FAILED") << "</span></h1>";
  h << "<p>" << escaped(r.scene_name) << " (" << escaped(r.scene_source) << "), started "
    << escaped(r.started_local)
    << (r.interrupted                      ? " (interrupted by the operator: the checks not made failed)"
        : r.kind == "daily" && !r.standard ? " (not the standard QA: looser settings)"
                                           : "")
    << "</p>";
  h << "<table><tr><th>check</th><th>result</th><th>tolerance</th><th>measured</th></tr>";
  for (const QaCheck& c : r.checks)
    h << "<tr><td>" << escaped(c.name) << "</td>" << result_cell(c.passed, c.why) << "<td>"
      << escaped(c.tolerance) << "</td><td>" << escaped(c.measured) << "</td></tr>";
  h << "</table>";
  if (e2e) h << "<h2>The hidden marker</h2>" << marker_picture(r);
  if (!r.offsets.empty()) {
    auto pose = [](const tracking::Vector6d& v) {
      return fmt::format("{:+.2f} {:+.2f} {:+.2f} mm; {:+.2f} {:+.2f} {:+.2f} deg", v(0), v(1), v(2),
                         rad_to_deg(v(3)), rad_to_deg(v(4)), rad_to_deg(v(5)));
    };
    h << "<h2>Offset test</h2>" << offset_picture(r);
    h << "<table><tr><th>#</th><th>shift</th><th>alignment found</th><th>alignment error</th><th>couch "
         "error</th><th>result</th></tr>";
    for (std::size_t i = 0; i < r.offsets.size(); ++i) {
      const OffsetResult& o = r.offsets[i];
      h << "<tr><td>" << i + 1 << "</td><td>" << pose(o.shift) << "</td><td>" << pose(o.registered)
        << "</td><td>"
        << fmt::format("{:.3f} mm, {:.3f} deg", o.registration_error_mm, o.registration_error_deg)
        << "</td><td>" << fmt::format("{:.3f} mm, {:.3f} deg", o.couch_error_mm, o.couch_error_deg) << "</td>"
        << result_cell(o.passed, o.why) << "</tr>";
    }
    h << "</table>";
  }
  if (!r.not_checked.empty()) {
    h << "<h2>Not checked</h2><ul>";
    for (const std::string& n : r.not_checked) h << "<li>" << escaped(n) << "</li>";
    h << "</ul>";
  }
  h << "</body></html>\n";
  return h.str();
}

// Creates `file` exclusively (never replacing anything) and writes `text`; false if it exists.
Result<bool> write_new(const fs::path& file, const std::string& text) {
  const int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC | O_NOFOLLOW, 0644);
  if (fd < 0) {
    if (errno == EEXIST) return false;
    return io_error(file.string() + ": cannot create: " + std::strerror(errno));
  }
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n <= 0) {
      ::close(fd);
      return io_error(file.string() + ": write failed: " + std::strerror(errno));
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0 || ::close(fd) != 0)
    return io_error(file.string() + ": cannot be saved: " + std::strerror(errno));
  return true;
}

}  // namespace

Status check_report_folder(const fs::path& folder) {
  if (folder.empty()) return invalid_argument("the QA folder (--out) is empty");
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec || !fs::is_directory(folder, ec))
    return io_error(folder.string() + ": not a folder the QA reports can go in" +
                    (ec ? ": " + ec.message() : ""));
  const fs::path probe = folder / (".qa-write-check-" + std::to_string(::getpid()));
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC | O_NOFOLLOW, 0644);
  if (fd < 0)
    return io_error(folder.string() + ": QA reports cannot be written there: " + std::strerror(errno));
  ::close(fd);
  ::unlink(probe.c_str());
  return {};
}

Result<WrittenReport> write_daily_qa_report(const DailyQaReport& report, const fs::path& folder) {
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec) return io_error(folder.string() + ": cannot create the QA folder: " + ec.message());
  std::string stamp = report.started_utc;  // 2026-11-30T23:50:01Z -> 20261130-235001
  stamp.erase(
      std::remove_if(stamp.begin(), stamp.end(), [](char c) { return c == '-' || c == ':' || c == 'Z'; }),
      stamp.end());
  std::replace(stamp.begin(), stamp.end(), 'T', '-');
  // A name or path that is not UTF-8 is written with replacement characters, not refused after
  // the QA has run.
  const std::string json =
      to_json(report).dump(2, ' ', false, nlohmann::json::error_handler_t::replace) + "\n";
  const std::string html = to_html(report);
  for (int n = 1; n < 1000; ++n) {
    const std::string prefix = "qa-" + report.kind;
    const std::string base =
        n == 1 ? fmt::format("{}-{}", prefix, stamp) : fmt::format("{}-{}-{}", prefix, stamp, n);
    WrittenReport w{folder / (base + ".json"), folder / (base + ".html")};
    if (fs::exists(w.json, ec) || fs::is_symlink(w.json, ec)) continue;
    // The page first, the JSON last: `lftrack run` reads the JSON, so a report is complete when
    // its JSON exists.
    auto page = write_new(w.html, html);
    if (!page.ok()) return page.status();
    if (!*page) continue;
    auto made = write_new(w.json, json);
    if (!made.ok()) return made.status();
    if (!*made) return io_error(w.json.string() + ": appeared while the QA report was written");
    return w;
  }
  return io_error(folder.string() + ": a thousand QA reports for " + stamp + " already");
}

DailyQaStatus daily_qa_status(const fs::path& folder, const std::string& room, const std::string& date) {
  DailyQaStatus status;
  std::error_code ec;
  std::string newest_start;
  nlohmann::json newest;
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    const fs::path& file = it->path();
    if (file.extension() != ".json" || file.filename().string().rfind("qa-daily-", 0) != 0) continue;
    if (it->is_symlink(ec) || !it->is_regular_file(ec) || it->file_size(ec) > (1u << 20))
      continue;  // a few kB
    std::ifstream in(file);
    const nlohmann::json j = nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
    // Fields of the wrong type make the file no report of ours (value() would throw).
    auto text = [&](const char* key) {
      const auto f = j.find(key);
      return f != j.end() && f->is_string() ? f->get<std::string>() : std::string();
    };
    auto flag = [&](const char* key) {
      const auto f = j.find(key);
      return f != j.end() && f->is_boolean() && f->get<bool>();
    };
    if (!j.is_object() || text("kind") != "lftrack daily QA") continue;
    if (text("room_fingerprint") != room || text("date") != date) continue;
    // The newest QA of the day decides: a pass followed by a failed re-run is a failed day.
    const std::string start = text("started_utc");
    if (status.file.empty() || start > newest_start) {
      status.file = file;
      newest_start = start;
      status.passed = flag("passed") && flag("standard");
      status.detail = !flag("passed") ? "the newest QA of the room today failed: " + file.string()
                      : !flag("standard")
                          ? "the newest QA of the room today passed with looser settings than the "
                            "standard QA: " +
                                file.string()
                          : "passed today: " + file.string();
    }
  }
  if (status.file.empty())
    status.detail = "none of this room today (" + date + ") in " + folder.string() +
                    ": lftrack qa daily --scene <the room's phantom scene>";
  return status;
}

session::PreflightItem daily_qa_item(const session::Scene& scene, const fs::path& folder) {
  const DailyQaStatus s =
      daily_qa_status(folder, session::to_hex(session::room_fingerprint(scene)), qa_now().local_date);
  return {"daily QA",
          s.passed                 ? session::CheckResult::kPass
          : scene.require_daily_qa ? session::CheckResult::kFail
                                   : session::CheckResult::kWarn,
          s.detail};
}

}  // namespace lftrack::qa

// The monitor page in a real browser (issue 22): headless Chromium, driven through ChromeDriver's
// WebDriver protocol (both from Debian), loads the page of a running `lftrack sim --fast
// --monitor`, sees the state and a trace that grows, presses Resume without the operator token
// (refused, and journaled) and with it (the HOLD is left), and saves a screenshot.

#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>

#include "../closed_loop/loop_fixture.hpp"
#include "child_process.hpp"
#include "lftrack/loop/journal.hpp"
#include "lftrack/records/journal_reader.hpp"
#include "lftrack/watch/igtl_server.hpp"
#include "lftrack/watch/listen_address.hpp"
#include "lftrack/tracking/status.hpp"
#include "test_data.hpp"
// After Eigen: httplib.h brings in <resolv.h>, whose _res macro breaks Eigen's headers.
#include <httplib.h>

#include "igtl_test_client.hpp"

namespace lftrack::session {

using loop::JournalRecord;
using loop::OperatorCommand;
using loop::OperatorRefusal;

using watch::open_listening_socket;
using watch::ras_from_lps;

using records::read_journal;
namespace {

namespace fs = std::filesystem;

const char* kChromium = "/usr/bin/chromium";
const char* kChromeDriver = "/usr/bin/chromedriver";

// The small scene's light fields, kept in the build folder between test runs (each test is a
// process of its own): a field is checked against the scene before use and rebuilt if stale.
std::string cached_light_fields() { return (fs::path(LFTRACK_BINARY_DIR) / "test-light-fields" / "small").string(); }

int free_port() {
  int port = 0;
  auto fd = open_listening_socket({"127.0.0.1", 0}, &port);
  if (fd.ok()) ::close(*fd);
  return port;
}

// A WebDriver session (W3C protocol) on a ChromeDriver at `port`.
class Browser {
 public:
  Browser(int port, const fs::path& profile) : http_("127.0.0.1", port) {
    http_.set_read_timeout(60, 0);
    const nlohmann::json args = {"--headless=new",
                                 "--no-sandbox",
                                 "--disable-gpu",
                                 "--disable-dev-shm-usage",
                                 "--disable-quic",
                                 "--no-first-run",
                                 "--disable-background-networking",
                                 "--disable-component-update",
                                 "--disable-sync",
                                 "--window-size=1500,1000",
                                 "--user-data-dir=" + profile.string()};
    const nlohmann::json caps = {
        {"capabilities",
         {{"alwaysMatch", {{"browserName", "chrome"}, {"goog:chromeOptions", {{"binary", kChromium}, {"args", args}}}}}}}};
    // ChromeDriver takes a moment to listen.
    for (int attempt = 0; attempt < 100 && session_.empty(); ++attempt) {
      auto res = http_.Post("/session", caps.dump(), "application/json");
      if (res && res->status == 200) {
        session_ = nlohmann::json::parse(res->body)["value"]["sessionId"].get<std::string>();
        break;
      }
      if (res) {
        error_ = res->body;
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }
  ~Browser() {
    if (!session_.empty()) http_.Delete(("/session/" + session_).c_str());
  }
  bool ok() const { return !session_.empty(); }
  const std::string& error() const { return error_; }

  nlohmann::json command(const std::string& method, const std::string& path, const nlohmann::json& body = {}) {
    const std::string url = "/session/" + session_ + path;
    auto res = method == "GET" ? http_.Get(url.c_str()) : http_.Post(url.c_str(), body.dump(), "application/json");
    if (!res) return {{"error", "no answer"}};
    return nlohmann::json::parse(res->body, nullptr, false)["value"];
  }
  void go(const std::string& url) { command("POST", "/url", {{"url", url}}); }
  std::string text(const std::string& id) {
    auto v = command("POST", "/execute/sync",
                     {{"script", "var e = document.getElementById(arguments[0]); return e ? e.textContent : null;"},
                      {"args", {id}}});
    return v.is_string() ? v.get<std::string>() : std::string();
  }
  // A real click on the element with this id (WebDriver's element click).
  void click(const std::string& id) {
    auto element = command("POST", "/element", {{"using", "css selector"}, {"value", "#" + id}});
    const std::string key = "element-6066-11e4-a52e-4f735466cecf";
    ASSERT_TRUE(element.contains(key)) << element.dump();
    command("POST", "/element/" + element[key].get<std::string>() + "/click", nlohmann::json::object());
  }
  // Waits up to `seconds` for the element's text to satisfy `ok`; the last text.
  std::string wait_for(const std::string& id, const std::function<bool(const std::string&)>& ok, int seconds = 30) {
    std::string t;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(seconds);
    do {
      t = text(id);
      if (ok(t)) return t;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    } while (std::chrono::steady_clock::now() < deadline);
    return t;
  }
  std::string screenshot_png() {
    auto v = command("GET", "/screenshot");
    if (!v.is_string()) return {};
    const std::string b64 = v.get<std::string>();
    std::string out;
    int bits = 0;
    unsigned buffer = 0;
    for (char ch : b64) {
      const char* alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
      const char* at = std::strchr(alphabet, ch);
      if (ch == '=' || at == nullptr) continue;
      buffer = (buffer << 6) | unsigned(at - alphabet);
      bits += 6;
      if (bits >= 8) {
        bits -= 8;
        out += char((buffer >> bits) & 0xff);
      }
    }
    return out;
  }

 private:
  httplib::Client http_;
  std::string session_, error_;
};

TEST(MonitorPage, ShowsTheLoopLiveAndActsOnlyWithTheToken) {
  const bool required = std::getenv("LFTRACK_REQUIRE_BROWSER") != nullptr;
  for (const char* tool : {kChromium, kChromeDriver})
    if (::access(tool, X_OK) != 0) {
      ASSERT_FALSE(required) << tool << " is missing (scripts/setup.sh installs chromium and chromium-driver)";
      GTEST_SKIP() << tool << " is not installed (scripts/setup.sh installs chromium and chromium-driver)";
    }
  test::TempDir dir;
  // The small closed-loop scene; the patient slides 4 mm at 3 s (twice the step limit): the loop
  // holds for the operator.
  const fs::path scene = dir.path() / "shift.yaml";
  std::ofstream(scene) << small_scene_text(
      "motion:\n  setup_error: {translation_mm: [3, -2, 2], rotation_deg: [1, -0.5, 1]}\n"
      "  shifts: [{time_s: 3.0, translation_mm: [0, 4, 0]}]\n",
      kRayCastFrames);  // ray-cast frames: only the registration's small field is built
  const fs::path journal = dir.path() / "run.lfj";
  test::ChildProcess sim({LFTRACK_BIN_PATH, "sim", "--scene", scene.string(), "--fast", "--cycles", "0", "--threads",
                          "1", "--monitor", "127.0.0.1:0", "--monitor-token-file", (dir.path() / "token").string(),
                          "--journal", journal.string(), "--lf-dir", cached_light_fields()});
  ASSERT_TRUE(sim.started());
  std::string url, token;
  for (int lines = 0; lines < 50 && token.empty(); ++lines) {
    auto line = sim.read_line(std::chrono::seconds(300));  // the light field is built first
    ASSERT_TRUE(line) << "lftrack sim said nothing about its monitor";
    std::smatch m;
    if (std::regex_search(*line, m, std::regex(R"(^monitor: (http://\S+/) \(view only\))"))) url = m[1];
    if (std::regex_search(*line, m, std::regex(R"(^monitor: operator token ([0-9a-f]{64}) )"))) token = m[1];
  }
  ASSERT_FALSE(url.empty());
  ASSERT_EQ(token.size(), 64u);

  test::ChildProcess driver({kChromeDriver, "--port=" + std::to_string(free_port())});
  // ChromeDriver's port: the one asked for (read back from its first line when it says so).
  int driver_port = 0;
  for (int lines = 0; lines < 5 && driver_port == 0; ++lines) {
    auto line = driver.read_line(std::chrono::seconds(10));
    if (!line) break;
    std::smatch m;
    if (std::regex_search(*line, m, std::regex(R"(on port (\d+))"))) driver_port = std::stoi(m[1]);
  }
  ASSERT_GT(driver_port, 0) << "ChromeDriver did not start";
  Browser browser(driver_port, dir.path() / "profile");
  ASSERT_TRUE(browser.ok()) << "no WebDriver session: " << browser.error();

  // View only: the state and a trace that grows.
  browser.go(url);
  const std::string state = browser.wait_for("state", [](const std::string& t) { return t == "TRACK" || t == "HOLD"; });
  EXPECT_TRUE(state == "TRACK" || state == "HOLD") << state;
  const int trace = std::atoi(browser.wait_for("trace-count", [](const std::string& t) { return std::atoi(t.c_str()) > 5; }).c_str());
  EXPECT_GT(std::atoi(browser.wait_for("trace-count", [&](const std::string& t) { return std::atoi(t.c_str()) > trace; }).c_str()), trace)
      << "the trace grows as cycles arrive";
  EXPECT_EQ(browser.text("token-status").rfind("view only", 0), 0u);
  // The correction's latency chain: a --fast run's clock is simulated, and the page says so.
  const std::string chain = browser.wait_for("latency-chain", [](const std::string& t) {
    return t.find("not timed") != std::string::npos || t.find("no correction") != std::string::npos;
  });
  EXPECT_TRUE(chain.find("not timed") != std::string::npos ||
              chain.find("no correction") != std::string::npos)
      << chain;
  // The shift: HOLD, and the gate's reason.
  EXPECT_EQ(browser.wait_for("state", [](const std::string& t) { return t == "HOLD"; }, 60), "HOLD");
  const int hold_seen_at = std::atoi(browser.text("cycle").c_str());
  EXPECT_NE(browser.text("state-reason"), "") << "why it holds";
  EXPECT_NE(browser.text("gate-reason"), "-");
  EXPECT_NE(browser.text("hold-id"), "-");
  // Resume without the token: refused, the HOLD stays.
  browser.click("resume");
  const std::string refused =
      browser.wait_for("action-result", [](const std::string& t) { return t.find("refused") != std::string::npos; });
  EXPECT_NE(refused.find("no operator token"), std::string::npos) << refused;
  // Still held some cycles later (a wait on the page's cycle, not on the clock).
  const int refused_at = std::atoi(browser.text("cycle").c_str());
  EXPECT_GT(std::atoi(browser.wait_for("cycle", [&](const std::string& t) { return std::atoi(t.c_str()) > refused_at + 3; })
                          .c_str()),
            refused_at + 3)
      << "the page kept showing new cycles";
  EXPECT_EQ(browser.text("state"), "HOLD");
  // With the token (taken from the address, then removed from it): accepted, the loop tracks.
  browser.go(url + "#token=" + token);
  EXPECT_EQ(browser.wait_for("state", [](const std::string& t) { return t == "HOLD"; }), "HOLD");
  EXPECT_EQ(browser.text("token-status").rfind("operator", 0), 0u);
  const auto address = browser.command("POST", "/execute/sync", {{"script", "return location.href;"}, {"args", nlohmann::json::array()}});
  EXPECT_EQ(address.get<std::string>().find(token), std::string::npos) << "the token left the address bar";
  browser.wait_for("image-cycle", [](const std::string& t) { return !t.empty(); });
  // A person looks before resuming: the loop counts a resume only once the HOLD has been shown
  // for a second of its clock (10 cycles).
  browser.wait_for("cycle", [&](const std::string& t) { return std::atoi(t.c_str()) > hold_seen_at + 15; });
  EXPECT_EQ(browser.text("state"), "HOLD");
  EXPECT_NE(browser.text("gate-decision"), "APPLY") << "nothing is applied in HOLD";
  browser.click("resume");
  const std::string accepted =
      browser.wait_for("action-result", [](const std::string& t) { return t.find("accepted") != std::string::npos; });
  EXPECT_NE(accepted.find("resume: accepted"), std::string::npos) << accepted;
  EXPECT_EQ(browser.wait_for("state", [](const std::string& t) { return t == "TRACK"; }), "TRACK");
  browser.command("POST", "/execute/sync", {{"script", "document.getElementById('overlay').value = 'checker';"
                                                      "document.getElementById('overlay').dispatchEvent(new Event('change'));"},
                                           {"args", nlohmann::json::array()}});
  browser.command("POST", "/execute/sync", {{"script", "document.getElementById('overlay').value = 'edges';"
                                                      "document.getElementById('overlay').dispatchEvent(new Event('change'));"},
                                           {"args", nlohmann::json::array()}});
  // The overlay is drawn at once (the change handler); the screenshot is taken once a newer
  // cycle's images have been drawn with it as well.
  const auto image_cycle = [](const std::string& t) { return t.rfind("(cycle ", 0) == 0 ? std::atoi(t.c_str() + 7) : -1; };
  const int overlaid_at = image_cycle(browser.text("image-cycle"));
  EXPECT_GT(image_cycle(browser.wait_for("image-cycle", [&](const std::string& t) { return image_cycle(t) > overlaid_at; })),
            overlaid_at)
      << "new images kept arriving";
  const std::string png = browser.screenshot_png();
  EXPECT_GT(png.size(), 20000u);
  EXPECT_EQ(png.substr(1, 3), "PNG");
  std::ofstream(fs::path(LFTRACK_BINARY_DIR) / "monitor-screenshot.png", std::ios::binary) << png;

  // The run ends on SIGTERM; its journal holds the refusal and the operator's resume.
  sim.signal(SIGTERM);
  EXPECT_EQ(sim.wait(std::chrono::seconds(30)), 0);
  auto records = read_journal(journal);
  ASSERT_TRUE(records.ok()) << records.status().message();
  bool refusal = false, resumed = false;
  for (const JournalRecord& r : records->records) {
    refusal = refusal || r.operator_refusal == static_cast<std::uint8_t>(OperatorRefusal::kBadToken);
    resumed = resumed || r.operator_command == 1 + static_cast<std::uint8_t>(OperatorCommand::kResume);
  }
  EXPECT_TRUE(refusal) << "the resume without the token is journaled as refused";
  EXPECT_TRUE(resumed) << "the resume with the token is journaled as the operator's";
  EXPECT_FALSE(fs::exists(dir.path() / "token")) << "the token file goes with the run";
}

// OpenIGTLink across processes: a client of `lftrack sim --igtl` receives each registered cycle's
// pose, and the poses it received are the journal's, in order.
TEST(IgtlAcrossProcesses, TheClientsPosesAreTheJournals) {
  test::TempDir dir;
  const fs::path scene = dir.path() / "scene.yaml";
  std::ofstream(scene) << small_scene_text(kBreathing, kRayCastFrames);
  const fs::path journal = dir.path() / "run.lfj";
  test::ChildProcess sim({LFTRACK_BIN_PATH, "sim", "--scene", scene.string(), "--fast", "--cycles", "0", "--threads",
                          "1", "--igtl", "127.0.0.1:0", "--journal", journal.string(), "--lf-dir",
                          cached_light_fields()});
  int port = 0;
  for (int lines = 0; lines < 50 && port == 0; ++lines) {
    auto line = sim.read_line(std::chrono::seconds(300));
    ASSERT_TRUE(line) << "lftrack sim said nothing about its OpenIGTLink server";
    std::smatch m;
    if (std::regex_search(*line, m, std::regex(R"(^igtl: OpenIGTLink server on port (\d+))"))) port = std::stoi(m[1]);
  }
  std::vector<Eigen::Matrix4d> poses;
  {
    test::IgtlClient client(port);
    ASSERT_TRUE(client.connected());
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(30);
    while (std::chrono::steady_clock::now() < until && poses.size() < 40 && !client.closed())
      if (auto m = client.next(); m && m->type == "TRANSFORM" && m->device == "T_room_from_ct") poses.push_back(m->matrix);
  }
  sim.signal(SIGTERM);
  ASSERT_EQ(sim.wait(std::chrono::seconds(30)), 0);
  ASSERT_GT(poses.size(), 20u);
  auto contents = read_journal(journal);
  ASSERT_TRUE(contents.ok());
  auto loaded = load_scene(scene.string());
  ASSERT_TRUE(loaded.ok());
  tracking::ThreadPool pool(1);
  auto prepared = prepare_scene(*loaded, "", &pool);
  ASSERT_TRUE(prepared.ok());
  std::vector<Eigen::Matrix4d> journaled;
  for (const JournalRecord& r : contents->records)
    if (r.similarity[0] != 0) {
      Eigen::Map<const tracking::Vector6d> delta(r.pose_delta);
      journaled.push_back(ras_from_lps(tracking::apply_delta(prepared->nominal_T_room_from_ct,
                                                             tracking::PoseDelta::from_vector(delta),
                                                             prepared->registration_origin_room_mm())
                                           .matrix()));
    }
  // The client joined at some cycle; from there on every pose is the journal's, in order.
  auto same = [](const Eigen::Matrix4d& a, const Eigen::Matrix4d& b) { return (a - b).cwiseAbs().maxCoeff() < 2e-3; };
  std::size_t first = 0;
  while (first < journaled.size() && !same(journaled[first], poses[0])) ++first;
  ASSERT_LT(first, journaled.size()) << "the first pose received is in the journal";
  ASSERT_LE(first + poses.size(), journaled.size());
  for (std::size_t i = 0; i < poses.size(); ++i) ASSERT_TRUE(same(poses[i], journaled[first + i])) << i;
}

}  // namespace
}  // namespace lftrack::session

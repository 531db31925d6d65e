// Option values out of range are usage errors (README "Commands": exit 2, CLI11's reason naming
// the option), refused when the options are parsed, before any work; a value checked only after
// parsing exited 1 like a refusal (issue 50). One case per option value.

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cctype>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <ostream>
#include <string>
#include <vector>

#include "cli_text.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

using test::quoted;

namespace fs = std::filesystem;

struct UsageCase {
  std::vector<std::string> args;  // after `lftrack`
  std::string option;             // the option the message names
};

// A failing case shows its command line.
void PrintTo(const UsageCase& c, std::ostream* os) {
  *os << "lftrack";
  for (const auto& a : c.args) *os << ' ' << a;
}

class UsageError : public ::testing::TestWithParam<UsageCase> {};

// The cases carry options that keep the work short (missing folders, a short duration, one run),
// so a value the parser lets through fails by its exit code rather than by a long run.
TEST_P(UsageError, ExitsTwoNamingTheOption) {
  test::TempDir dir;
  std::string command = "cd " + quoted(dir.path().string()) + " && " + quoted(LFTRACK_BIN_PATH);
  for (const auto& a : GetParam().args) command += " " + quoted(a);
  const fs::path log = dir.path() / "out.txt";
  command += " >" + quoted(log.string()) + " 2>&1";
  const int status = std::system(command.c_str());
  std::ifstream in(log);
  const std::string out{std::istreambuf_iterator<char>(in), {}};
  ASSERT_TRUE(status != -1 && WIFEXITED(status)) << out;
  EXPECT_EQ(WEXITSTATUS(status), 2) << out;
  EXPECT_NE(out.find(GetParam().option), std::string::npos) << out;
}

std::vector<UsageCase> detector(const std::string& option, const std::string& value) {
  return {{{"calibrate", "detector", "--dark", "no-dark", "--flood", "no-flood", option, value}, option}};
}
std::vector<UsageCase> rt_check(const std::string& option, const std::string& value) {
  std::vector<std::string> args{"rt-check", option, value};
  if (option != "--duration") args.insert(args.end(), {"--duration", "0.01"});
  return {{args, option}};
}

std::vector<UsageCase> cases() {
  std::vector<UsageCase> all;
  const auto add = [&](std::vector<UsageCase> c) { all.insert(all.end(), c.begin(), c.end()); };
  // The cases the issue names.
  add(detector("--bits", "17"));
  add(detector("--min-frames", "0"));
  add(detector("--dark-sd", "nan"));
  add(rt_check("--interval-us", "0"));
  add(rt_check("--priority", "100"));
  // The rest of calibrate detector and rt-check.
  add(detector("--bits", "7"));
  add(detector("--saturation", "0"));
  add(detector("--saturation", "65536"));
  add(detector("--min-frames", "1"));
  add(detector("--dark-sd", "0.5"));
  add(detector("--noise-sd", "inf"));
  add(detector("--gain-low", "1"));
  add(detector("--gain-high", "1"));
  add(detector("--line-low", "-0.1"));
  add(detector("--line-high", "101"));
  add(detector("--max-saturated", "2"));
  add(rt_check("--duration", "0"));
  add(rt_check("--duration", "nan"));
  add(rt_check("--duration", "3601"));
  add(rt_check("--interval-us", "2000000"));
  add(rt_check("--priority", "0"));
  add(rt_check("--priority", "50.5"));
  add(rt_check("--budget-us", "-5"));
  add(rt_check("--budget-us", "inf"));
  add(rt_check("--histogram-max-us", "0"));
  add(rt_check("--cpus", "x"));
  // The sweep of every command's numbers.
  add({{{"bench", "drr", "--size", "4", "--no-peers"}, "--size"},
       {{"bench", "drr", "--poses", "0", "--no-peers"}, "--poses"},
       {{"bench", "drr", "--repeats", "0", "--no-peers"}, "--repeats"},
       {{"bench", "drr", "--render-threads", "0", "--no-peers"}, "--render-threads"},
       {{"bench", "drr", "--vq-codebooks", "16,1", "--no-peers"}, "--vq-codebooks"},
       {{"bench", "octree", "--size", "0"}, "--size"},
       {{"bench", "octree", "--poses", "0"}, "--poses"},
       {{"bench", "octree", "--pivots", "nan"}, "--pivots"},
       {{"study", "sensitivity", "--runs", "1", "--start-tre", "nan"}, "--start-tre"},
       {{"study", "sensitivity", "--runs", "1", "--start-tre", "0"}, "--start-tre"},
       {{"calibrate", "views", "--sim", "--photons", "-1"}, "--photons"},
       {{"calibrate", "couch", "--photons", "nan"}, "--photons"},
       {{"serve", "couch", "--duration", "nan"}, "--duration"},
       {{"serve", "detectors", "--scene", "builtin:phantom", "--settle", "nan", "--duration", "0.01"}, "--settle"},
       {{"drr", "--pose", "nan,0,0,0,0,0", "-o", "drr"}, "--pose"},
       {{"register", "--sim", "--gold", "0,0,0,inf,0,0"}, "--gold"},
       {{"register", "--sim", "--init", "0,nan,0,0,0,0"}, "--init"},
       // Seeds CLI11 took as the largest one without a word (issue 50 probe).
       {{"register", "--sim", "--seed", "-1"}, "--seed"},
       {{"register", "--sim", "--seed", "18446744073709551616"}, "--seed"},
       {{"register", "--sim", "--seed", "99999999999999999999999"}, "--seed"},
       // A measure that is not one (the outside probe of 2026-11-30: "no similarity expectation").
       {{"register", "--sim", "--similarity", "RNCC"}, "--similarity"},
       {{"register", "--sim", "--similarity", ""}, "--similarity"},
       {{"commission", "--good", "-1"}, "--good"},
       {{"commission", "--bad", "nan"}, "--bad"},
       {{"commission", "--tolerance-mm", "0"}, "--tolerance-mm"},
       {{"commission", "--tolerance-mm", "inf"}, "--tolerance-mm"},
       {{"commission", "--level-mm", "1e12"}, "--level-mm"},
       {{"commission", "--max-false-rejects", "2"}, "--max-false-rejects"},
       {{"commission", "--out", ""}, "--out"},
       {{"commission", "--seed", "-1"}, "--seed"},
       {{"commission", "--min-margin", "nan"}, "--min-margin"},
       {{"commission", "--min-margin", "-1"}, "--min-margin"},
       {{"commission", "--min-margin", "1e12"}, "--min-margin"},
       {{"study", "sensitivity", "--runs", "1", "--out", ""}, "--out"},
       {{"study", "trade", "--out", "x", "--seed", "1.5"}, "--seed"}});
  return all;
}

std::string case_name(const ::testing::TestParamInfo<UsageCase>& info) {
  std::string name;
  for (const auto& a : info.param.args)
    for (char c : a) name += std::isalnum(static_cast<unsigned char>(c)) ? c : '_';
  return name + "_" + std::to_string(info.index);
}

INSTANTIATE_TEST_SUITE_P(Cli, UsageError, ::testing::ValuesIn(cases()), case_name);

// `study sensitivity --out` is checked before the scene loads: a folder with an earlier study's
// files in it, or a file, is refused at once (exit 1), and nothing in it is replaced.
TEST(StudySensitivityOut, AFolderThatIsNotNewOrEmptyIsRefusedBeforeAnyWork) {
  test::TempDir dir;
  const fs::path earlier = dir.path() / "earlier";
  fs::create_directories(earlier);
  { std::ofstream(earlier / "runs.csv") << "an earlier study\n"; }
  std::ofstream(dir.path() / "afile") << "x\n";
  for (const fs::path& out : {earlier, dir.path() / "afile"}) {
    const fs::path log = dir.path() / "out.txt";
    const std::string command = quoted(LFTRACK_BIN_PATH) + " study sensitivity --scene builtin:nothing --runs 1 --out " +
                                quoted(out.string()) + " >" + quoted(log.string()) + " 2>&1";
    const int status = std::system(command.c_str());
    std::ifstream in(log);
    const std::string text{std::istreambuf_iterator<char>(in), {}};
    ASSERT_TRUE(status != -1 && WIFEXITED(status)) << text;
    EXPECT_EQ(WEXITSTATUS(status), 1) << text;
    EXPECT_TRUE(text.find("is not empty") != std::string::npos || text.find("not a folder") != std::string::npos)
        << text;
    EXPECT_EQ(text.find("builtin:nothing"), std::string::npos) << "refused before the scene is looked at: " << text;
  }
  std::ifstream kept(earlier / "runs.csv");
  const std::string still{std::istreambuf_iterator<char>(kept), {}};
  EXPECT_EQ(still, "an earlier study\n");
}

}  // namespace
}  // namespace lftrack::session

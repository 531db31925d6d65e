// The lftrack program as a user runs it: exit codes, messages, files written.

#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>

#include <nlohmann/json.hpp>

#include "lftrack/host/plastimatch_peer.hpp"
#include "lftrack/tracking/image_io.hpp"
#include "test_data.hpp"

namespace lftrack::host {
namespace {

std::string lftrack_bin() {
  return LFTRACK_BIN_PATH;
}

TEST(Cli, DrrWritesBothViewsOfTheDefaultScene) {
  test::TempDir dir;
  std::string out;
  const Status s =
      run_process({lftrack_bin(), "drr", "--scene", "builtin:phantom", "-o", dir.path().string()}, &out);
  ASSERT_TRUE(s.ok()) << out;
  for (const char* view : {"A", "B"}) {
    const auto png = dir.path() / ("drr_" + std::string(view) + ".png");
    const auto pfm = dir.path() / ("drr_" + std::string(view) + "_mu_mm.pfm");
    EXPECT_NE(out.find(png.string()), std::string::npos) << "prints where the files are";
    auto image = tracking::read_png(png);
    auto data = tracking::read_pfm(pfm);
    ASSERT_TRUE(image.ok() && data.ok());
    EXPECT_EQ(image->rows(), 512);
    EXPECT_EQ(data->cols(), 512);
    float hi = 0;
    for (float v : data->pixels()) hi = std::max(hi, v);
    EXPECT_GT(hi, 3.0f) << "a torso absorbs: line integrals of several mu*mm";
  }
}

TEST(Cli, BadSceneFailsWithFileLineAndReason) {
  test::TempDir dir;
  const auto file = dir.path() / "bad.yaml";
  std::ofstream(file) << "version: 1\nct: {path: builtin:phantom}\ndetectors:\n  - name: A\n    rows: -3\n";
  std::string out;
  const Status s = run_process({lftrack_bin(), "info", "--scene", file.string()}, &out);
  EXPECT_FALSE(s.ok());
  EXPECT_NE(out.find(file.string() + ":5:"), std::string::npos) << out;
}

TEST(Cli, UnknownViewAndRendererAreErrors) {
  test::TempDir dir;
  std::string out;
  EXPECT_FALSE(run_process({lftrack_bin(), "drr", "--view", "C", "-o", dir.path().string()}, &out).ok());
  EXPECT_NE(out.find("no view 'C'"), std::string::npos) << out;
  EXPECT_FALSE(
      run_process({lftrack_bin(), "drr", "--renderer", "magic", "-o", dir.path().string()}, &out).ok());
  EXPECT_NE(out.find("unknown renderer 'magic'"), std::string::npos) << out;
}

TEST(Cli, BenchDrrJsonHasTheDocumentedFields) {
  std::string out;
  const Status s = run_process(
      {lftrack_bin(), "-q", "bench", "drr", "--size", "24", "--poses", "1", "--repeats", "1", "--json"},
      &out);
  ASSERT_TRUE(s.ok()) << out;
  const auto json = nlohmann::json::parse(out.substr(out.find('{')));
  for (const char* key : {"ct", "size", "renderers", "peers"}) EXPECT_TRUE(json.contains(key)) << key;
  for (const auto& r : json["renderers"])
    for (const char* key : {"name", "ms_median", "ncc_vs_siddon", "psnr_db_vs_siddon"})
      EXPECT_TRUE(r.contains(key)) << key;
  for (const auto& p : json["peers"])
    for (const char* key : {"name", "ms_median", "ncc_vs_siddon"}) EXPECT_TRUE(p.contains(key)) << key;
}

}  // namespace
}  // namespace lftrack::host

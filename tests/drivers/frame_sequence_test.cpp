// The archived-sequence index: what the writer writes the reader reads; every malformed index is
// refused with its file and line; a torn last line (a crash while archiving) is ignored.

#include "lftrack/drivers/frame_sequence.hpp"

#include <gtest/gtest.h>

#include <fstream>

#include "test_data.hpp"

namespace lftrack::drivers {
namespace {

void write_text(const std::filesystem::path& file, const std::string& text) {
  std::ofstream(file, std::ios::trunc) << text;
}

const char* kHeader = "# lftrack frame sequence 1\npair,detector,sequence,timestamp_ns,file\n";

TEST(FrameSequence, WriterAndReaderAgree) {
  test::TempDir dir;
  SequenceIndexWriter writer;
  ASSERT_TRUE(writer.open(dir.path(), true).ok());
  const double travel[6] = {1.5, -2, 0.25, 0.001, -0.002, 0.003};
  for (std::int64_t p = 0; p < 3; ++p) {
    ASSERT_TRUE(writer.append(p, "A", std::uint32_t(10 + p), 1000 + 100 * p, "frames/a.tif").ok());
    ASSERT_TRUE(writer.append(p, "B", std::uint32_t(20 + p), 1004 + 100 * p, "frames/b.tif").ok());
    if (p != 1) {
      ASSERT_TRUE(writer.append_actuator(p, travel).ok());
    }
  }
  ASSERT_TRUE(writer.close().ok());
  auto s = read_frame_sequence(dir.path());
  ASSERT_TRUE(s.ok()) << s.status().message();
  ASSERT_EQ(s->detectors, (std::vector<std::string>{"A", "B"}));
  ASSERT_EQ(s->pairs.size(), 3u);
  EXPECT_TRUE(s->has_actuator);
  for (std::int64_t p = 0; p < 3; ++p) {
    const SequencePair& pair = s->pairs[std::size_t(p)];
    EXPECT_EQ(pair.index, p);
    ASSERT_EQ(pair.frames.size(), 2u);
    EXPECT_TRUE(pair.frames[1].present);
    EXPECT_EQ(pair.frames[1].sequence, std::uint32_t(20 + p));
    EXPECT_EQ(pair.frames[1].timestamp_ns, 1004 + 100 * p);
    EXPECT_EQ(pair.frames[0].path, (dir.path() / "frames/a.tif").string());
    EXPECT_EQ(pair.has_actuator, p != 1);
  }
  EXPECT_DOUBLE_EQ(s->pairs[2].actuator_travel[0], 1.5);
  EXPECT_DOUBLE_EQ(s->pairs[2].actuator_travel[5], 0.003);
}

TEST(FrameSequence, APairWithoutADetectorsRowHasThatFrameMissing) {
  test::TempDir dir;
  write_text(dir.path() / "index.csv",
             std::string(kHeader) + "0,A,1,100,a0.tif\n0,B,1,100,b0.tif\n1,A,2,200,a1.tif\n");
  auto s = read_frame_sequence(dir.path());
  ASSERT_TRUE(s.ok()) << s.status().message();
  ASSERT_EQ(s->pairs.size(), 2u);
  EXPECT_TRUE(s->pairs[1].frames[0].present);
  EXPECT_FALSE(s->pairs[1].frames[1].present);
  EXPECT_FALSE(s->has_actuator);
}

TEST(FrameSequence, MalformedIndexesAreRefusedWithFileAndLine) {
  struct Case {
    const char* rows;
    const char* says;
  };
  const Case cases[] = {
      {"0,A,1,100\n1,A,2,200,a.tif\n", ":3: 5 fields expected, found 4"},
      {"x,A,1,100,a.tif\n1,A,2,200,a.tif\n", ":3: pair 'x' is not a count"},
      {"0,A,-1,100,a.tif\n1,A,2,200,a.tif\n", ":3: sequence '-1' is not a 32-bit count"},
      {"0,A,1,1e9,a.tif\n1,A,2,200,a.tif\n", ":3: timestamp_ns '1e9' is not an integer"},
      {"0,,1,100,a.tif\n1,A,2,200,a.tif\n", ":3: no detector name"},
      {"0,A,1,100,\n1,A,2,200,a.tif\n", ":3: no file"},
      {"1,A,1,100,a.tif\n0,A,2,200,a.tif\n", ":4: pair 0 after pair 1: pairs must ascend"},
      {"0,A,1,100,a.tif\n0,A,2,200,a.tif\n", ":4: detector A appears twice in pair 0"},
      {"0,A,1,-5,a.tif\n", ":3: timestamp_ns -5 is negative"},
      {"0,A,1,100,a.tif\n1,A,2,50,b.tif\n", ":4: timestamp_ns 50 is before the previous pair's (100)"},
      {"0,A,1,100,a.tif\n1,A,2,4000000000000100,b.tif\n", ":4: timestamp_ns 4000000000000100 is more than an hour"},
      {"0,A,1,100,/etc/passwd\n", ":3: file '/etc/passwd' is absolute"},
      {"0,A,1,100,frames/../../x.tif\n", ":3: file 'frames/../../x.tif' leaves the sequence folder"},
  };
  for (const Case& c : cases) {
    test::TempDir dir;
    write_text(dir.path() / "index.csv", std::string(kHeader) + c.rows);
    auto s = read_frame_sequence(dir.path());
    ASSERT_FALSE(s.ok()) << c.rows;
    EXPECT_EQ(s.status().code(), StatusCode::kCorruptData);
    EXPECT_NE(s.status().message().find(std::string("index.csv") + c.says), std::string::npos)
        << s.status().message();
  }
}

TEST(FrameSequence, MissingDirectoryIndexHeaderOrRowsAreRefused) {
  EXPECT_EQ(read_frame_sequence("/nonexistent/sequence").status().code(), StatusCode::kNotFound);
  test::TempDir dir;
  EXPECT_EQ(read_frame_sequence(dir.path()).status().code(), StatusCode::kNotFound);
  write_text(dir.path() / "index.csv", "frame,file\n0,a.tif\n");
  EXPECT_NE(read_frame_sequence(dir.path()).status().message().find("the header must be"), std::string::npos);
  write_text(dir.path() / "index.csv", kHeader);
  EXPECT_NE(read_frame_sequence(dir.path()).status().message().find("lists no frames"), std::string::npos);
}

TEST(FrameSequence, ATornLastLineIsIgnoredWithANote) {
  test::TempDir dir;
  write_text(dir.path() / "index.csv", std::string(kHeader) + "0,A,1,100,a0.tif\n1,A,2,200,fra");
  auto s = read_frame_sequence(dir.path());
  ASSERT_TRUE(s.ok()) << s.status().message();
  EXPECT_EQ(s->pairs.size(), 1u);
  EXPECT_NE(s->note.find("ignored line 4: it has no newline"), std::string::npos) << s->note;
  write_text(dir.path() / "index.csv", std::string(kHeader) + "0,A,1,100,a0.tif\n1,A,2,200,a1.tif\n");
  s = read_frame_sequence(dir.path());
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->pairs.size(), 2u);
  EXPECT_TRUE(s->note.empty());
}

TEST(FrameSequence, BadActuatorFileIsRefused) {
  test::TempDir dir;
  write_text(dir.path() / "index.csv", std::string(kHeader) + "0,A,1,100,a0.tif\n");
  write_text(dir.path() / "actuator.csv", "pair,tx_mm,ty_mm,tz_mm,rx_rad,ry_rad,rz_rad\n0,1,2,3,nan,0,0\n");
  auto s = read_frame_sequence(dir.path());
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("actuator.csv:2: a pair number and 6 finite numbers"),
            std::string::npos)
      << s.status().message();
}

// Read-backs the index cannot vouch for, and a version this build does not read.
TEST(FrameSequence, ActuatorRowsOutsideTheIndexTwiceOrBeyondAnyTravelAndOtherVersionsAreRefused) {
  struct Case {
    const char* rows;
    const char* says;
  };
  const Case cases[] = {
      {"0,1,2,3,0,0,0\n7,1,2,3,0,0,0\n", "actuator.csv:3: pair 7 is not in the index"},
      {"0,1,2,3,0,0,0\n0,1,2,3,0,0,0\n", "actuator.csv:3: pair 0 has a second read-back"},
      {"0,1e9,2,3,0,0,0\n", "actuator.csv:2: pair 0: translation 1e+09 mm is beyond any couch's travel"},
      {"0,1,2,3,0,0,7\n", "actuator.csv:2: pair 0: rotation 7 rad is beyond any couch's travel"},
  };
  for (const Case& c : cases) {
    test::TempDir dir;
    write_text(dir.path() / "index.csv", std::string(kHeader) + "0,A,1,100,a0.tif\n");
    write_text(dir.path() / "actuator.csv", std::string("pair,tx_mm,ty_mm,tz_mm,rx_rad,ry_rad,rz_rad\n") + c.rows);
    auto s = read_frame_sequence(dir.path());
    ASSERT_FALSE(s.ok()) << c.rows;
    EXPECT_NE(s.status().message().find(c.says), std::string::npos) << s.status().message();
  }
  test::TempDir dir;
  write_text(dir.path() / "index.csv",
             "# lftrack frame sequence 2\npair,detector,sequence,timestamp_ns,file\n0,A,1,100,a0.tif\n");
  auto s = read_frame_sequence(dir.path());
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("index.csv:1: frame sequence version '2'; this build reads version 1"),
            std::string::npos)
      << s.status().message();
}

}  // namespace
}  // namespace lftrack::drivers

// The built-in phantom's cache (host/phantom_cache.hpp): a copy is used only when it is this
// build's copy of the same phantom, bit for bit; anything else is made anew, and the cache never
// fails a run.

#include "lftrack/session/phantom_cache.hpp"

#include <gtest/gtest.h>
#include <sys/stat.h>

#include <cstdlib>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "lftrack/phantom/spine_phantom.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;

phantom::SpinePhantomOptions small() {
  phantom::SpinePhantomOptions o;
  o.size = {128, 128, 40};
  o.spacing_mm = {2.0, 2.0, 2.0};
  o.centre_mm = {0, 20, -350};
  return o;
}

class PhantomCache : public ::testing::Test {
 protected:
  // The phantom from the cache folder, with which path the call took.
  phantom::SpinePhantom cached(const phantom::SpinePhantomOptions& o, PhantomCacheUse expected_use) {
    PhantomCacheUse use = PhantomCacheUse::kOff;
    auto p = cached_spine_phantom(o, dir_.path() / "cache", &pool_, &use);
    EXPECT_TRUE(p.ok()) << p.status().message();
    EXPECT_EQ(use, expected_use);
    return p.ok() ? *std::move(p) : phantom::SpinePhantom{};
  }
  void expect_same(const phantom::SpinePhantom& a, const phantom::SpinePhantom& b) {
    EXPECT_TRUE(a.ct.values == b.ct.values) << "the voxels differ";
    EXPECT_EQ(a.ct.geometry.size, b.ct.geometry.size);
    EXPECT_EQ(a.ct.geometry.origin_mm, b.ct.geometry.origin_mm);
    EXPECT_EQ(a.ct.geometry.spacing_mm, b.ct.geometry.spacing_mm);
    EXPECT_EQ(a.vertebral_body_centres_mm, b.vertebral_body_centres_mm);
    EXPECT_EQ(a.target_vertebra, b.target_vertebra);
  }
  // The one file in the cache folder.
  fs::path the_file() {
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(dir_.path() / "cache")) files.push_back(e.path());
    EXPECT_EQ(files.size(), 1u);
    return files.empty() ? fs::path() : files.front();
  }
  void overwrite_at(const fs::path& file, std::streamoff at, const std::string& bytes) {
    std::fstream f(file, std::ios::binary | std::ios::in | std::ios::out);
    f.seekp(at);
    f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  }

  tracking::ThreadPool pool_{2};
  test::TempDir dir_;
};

TEST(ProgramBuildId, TheTestProgramHasOne) {
  const auto id = program_build_id();
  ASSERT_TRUE(id.has_value()) << "linked without --build-id: the cache would be off";
  EXPECT_GE(id->size(), 16u);
  EXPECT_EQ(id->find_first_not_of("0123456789abcdef"), std::string::npos) << *id;
  EXPECT_EQ(program_build_id(), id);
}

TEST(SpinePhantomLayout, IsTheGeneratedPhantomWithoutItsVoxels) {
  auto layout = phantom::spine_phantom_layout(small());
  auto made = phantom::make_spine_phantom(small());
  ASSERT_TRUE(layout.ok() && made.ok());
  EXPECT_TRUE(layout->ct.values.empty());
  EXPECT_EQ(layout->ct.geometry.origin_mm, made->ct.geometry.origin_mm);
  EXPECT_EQ(layout->vertebral_body_centres_mm, made->vertebral_body_centres_mm);
  EXPECT_EQ(layout->target_vertebra, made->target_vertebra);
  phantom::SpinePhantomOptions tiny = small();
  tiny.size = {10, 10, 10};
  EXPECT_FALSE(phantom::spine_phantom_layout(tiny).ok());
}

TEST_F(PhantomCache, TheSecondCallReadsBackTheFirstCallsPhantomBitForBit) {
  const auto made = phantom::make_spine_phantom(small());
  ASSERT_TRUE(made.ok());
  const phantom::SpinePhantom first = cached(small(), PhantomCacheUse::kGenerated);
  const phantom::SpinePhantom second = cached(small(), PhantomCacheUse::kLoaded);
  expect_same(first, *made);
  expect_same(second, *made);
  // Other options are another phantom and another file, never this one's voxels.
  phantom::SpinePhantomOptions other = small();
  other.seed = 2;
  const phantom::SpinePhantom reseeded = cached(other, PhantomCacheUse::kGenerated);
  EXPECT_FALSE(reseeded.ct.values == made->ct.values);
  other.noise_hu = 12.000000000000002;  // the options are named to the last bit
  cached(other, PhantomCacheUse::kGenerated);
}

TEST_F(PhantomCache, ADamagedCopyIsMadeAnewAndReplaced) {
  const auto made = phantom::make_spine_phantom(small());
  ASSERT_TRUE(made.ok());
  cached(small(), PhantomCacheUse::kGenerated);
  const fs::path file = the_file();
  const auto size = fs::file_size(file);
  overwrite_at(file, static_cast<std::streamoff>(size / 2), "\x7f\x7f\x7f\x7f");  // a voxel, not the header
  expect_same(cached(small(), PhantomCacheUse::kGenerated), *made);
  expect_same(cached(small(), PhantomCacheUse::kLoaded), *made);

  fs::resize_file(the_file(), size - 4);  // cut short
  expect_same(cached(small(), PhantomCacheUse::kGenerated), *made);
  { std::ofstream(the_file(), std::ios::app) << "x"; }  // one byte too many
  expect_same(cached(small(), PhantomCacheUse::kGenerated), *made);
  fs::resize_file(the_file(), 100);  // the header cut short
  expect_same(cached(small(), PhantomCacheUse::kGenerated), *made);
  EXPECT_EQ(fs::file_size(the_file()), size);
}

TEST_F(PhantomCache, ACopyWhoseHeaderNamesAnotherBuildIsNotUsed) {
  const auto made = phantom::make_spine_phantom(small());
  ASSERT_TRUE(made.ok());
  cached(small(), PhantomCacheUse::kGenerated);
  const fs::path file = the_file();
  std::string header(64, '\0');
  std::ifstream(file, std::ios::binary).read(header.data(), 64);
  const auto build = header.find("build ");
  ASSERT_NE(build, std::string::npos) << header;
  overwrite_at(file, static_cast<std::streamoff>(build + 6), "zz");  // as if renamed from another build
  expect_same(cached(small(), PhantomCacheUse::kGenerated), *made);
  expect_same(cached(small(), PhantomCacheUse::kLoaded), *made);
}

TEST_F(PhantomCache, AFolderThatCannotBeWrittenStillGivesThePhantom) {
  const auto made = phantom::make_spine_phantom(small());
  ASSERT_TRUE(made.ok());
  { std::ofstream(dir_.path() / "cache") << "a file, not a folder"; }
  expect_same(cached(small(), PhantomCacheUse::kUnwritten), *made);
  EXPECT_EQ(fs::file_size(dir_.path() / "cache"), 20u) << "the file in its way is left as it was";
}

TEST_F(PhantomCache, AFifoLinkOrFolderInTheCopysPlaceIsNeverRead) {
  const auto made = phantom::make_spine_phantom(small());
  ASSERT_TRUE(made.ok());
  cached(small(), PhantomCacheUse::kGenerated);
  const fs::path file = the_file();
  fs::remove(file);
  ASSERT_EQ(::mkfifo(file.c_str(), 0600), 0);
  // Opening the FIFO for reading would wait for a writer forever; the copy is made and renamed
  // over it instead.
  expect_same(cached(small(), PhantomCacheUse::kGenerated), *made);
  EXPECT_TRUE(fs::is_regular_file(file));
  // Links to what claims to be a plain file of no size and blocks on read (/proc), to a device
  // that never ends, to nothing, and to themselves: never read, replaced by a copy.
  for (const fs::path& target : {fs::path("/proc/self/status"), fs::path("/dev/zero"),
                                file.parent_path() / "nowhere", file}) {
    fs::remove(file);
    fs::create_symlink(target, file);
    expect_same(cached(small(), PhantomCacheUse::kGenerated), *made);
    EXPECT_TRUE(fs::is_regular_file(fs::symlink_status(file))) << target;
  }
  fs::remove(file);
  fs::create_directories(file / "inside");
  expect_same(cached(small(), PhantomCacheUse::kUnwritten), *made);
  EXPECT_TRUE(fs::is_directory(file / "inside")) << "a folder in the way is left as it was";
}

TEST_F(PhantomCache, TheFileNamesThisBuildAndFourWritersAtOnceLeaveOneWholeCopy) {
  const auto made = phantom::make_spine_phantom(small());
  ASSERT_TRUE(made.ok());
  std::vector<phantom::SpinePhantom> got(4);
  std::vector<std::thread> writers;
  for (auto& g : got)
    writers.emplace_back([&g, this] { g = *cached_spine_phantom(small(), dir_.path() / "cache", nullptr); });
  for (auto& w : writers) w.join();
  for (const auto& g : got) expect_same(g, *made);
  const std::string name = the_file().filename().string();  // one file, no temporary left
  EXPECT_NE(name.find("-" + program_build_id().value_or("?") + "-"), std::string::npos) << name;
  EXPECT_EQ(name.substr(name.size() - 3), ".ct");
}

TEST_F(PhantomCache, ANewCopyReplacesOtherBuildsCopiesAndOldTemporaryFiles) {
  cached(small(), PhantomCacheUse::kGenerated);
  const fs::path file = the_file();
  const std::string name = file.filename().string();
  const std::string prefix = name.substr(0, name.find(program_build_id().value()));
  const fs::path other_build = file.parent_path() / (prefix + "0123456789abcdef-00000000.ct");
  const fs::path other_phantom = file.parent_path() / "spine-phantom-00000000-00000000-0123456789abcdef-0.ct";
  const fs::path old_temporary = file.parent_path() / (name + ".tmp-AbCdEf");
  const fs::path new_temporary = file.parent_path() / (name + ".tmp-GhIjKl");
  for (const fs::path& f : {other_build, other_phantom, old_temporary, new_temporary}) std::ofstream(f) << "x";
  fs::last_write_time(old_temporary, fs::file_time_type::clock::now() - std::chrono::hours(2));
  cached(small(), PhantomCacheUse::kLoaded);
  EXPECT_FALSE(fs::exists(old_temporary)) << "a temporary file two hours old, when the copy is read back";
  EXPECT_FALSE(fs::exists(other_build)) << "another build's copy, when the copy is read back";
  for (const fs::path& f : {other_build, old_temporary}) std::ofstream(f) << "x";
  fs::last_write_time(old_temporary, fs::file_time_type::clock::now() - std::chrono::hours(2));
  fs::remove(file);
  cached(small(), PhantomCacheUse::kGenerated);
  EXPECT_TRUE(fs::exists(file));
  EXPECT_FALSE(fs::exists(other_build)) << "another build's copy of this phantom by this program";
  EXPECT_FALSE(fs::exists(old_temporary)) << "a temporary file two hours old";
  EXPECT_TRUE(fs::exists(other_phantom)) << "another phantom's copy is kept";
  EXPECT_TRUE(fs::exists(new_temporary)) << "a temporary file another process may be writing is kept";
}

TEST_F(PhantomCache, PrepareSceneUsesTheFolderTheEnvironmentNames) {
  const char* before = std::getenv(kCacheDirVariable);
  const std::string restore = before != nullptr ? before : "";
  ASSERT_EQ(::setenv(kCacheDirVariable, (dir_.path() / "from-env").c_str(), 1), 0);
  EXPECT_EQ(cache_dir_from_environment(), dir_.path() / "from-env");
  auto scene = load_scene("builtin:phantom");
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  auto prepared = prepare_scene(*scene, "", &pool_);
  ASSERT_TRUE(prepared.ok()) << prepared.status().message();
  std::size_t copies = 0;
  for (const auto& e : fs::directory_iterator(dir_.path() / "from-env"))
    copies += e.path().extension() == ".ct" ? 1 : 0;
  EXPECT_EQ(copies, 1u) << "prepare_scene wrote the built-in phantom's copy where LFTRACK_CACHE_DIR says";
  ASSERT_EQ(::setenv(kCacheDirVariable, "", 1), 0);
  EXPECT_TRUE(cache_dir_from_environment().empty());
  if (before != nullptr) ::setenv(kCacheDirVariable, restore.c_str(), 1);
  else ::unsetenv(kCacheDirVariable);
}

TEST_F(PhantomCache, NoFolderIsNoCacheAndBadOptionsFailAsWithout) {
  PhantomCacheUse use = PhantomCacheUse::kLoaded;
  auto p = cached_spine_phantom(small(), fs::path(), &pool_, &use);
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(use, PhantomCacheUse::kOff);
  phantom::SpinePhantomOptions bad = small();
  bad.spacing_mm.x() = -1;
  auto refused = cached_spine_phantom(bad, dir_.path() / "cache", &pool_, &use);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().message(), phantom::make_spine_phantom(bad).status().message());
  EXPECT_FALSE(fs::exists(dir_.path() / "cache")) << "nothing written for options that make no phantom";
}

}  // namespace
}  // namespace lftrack::session

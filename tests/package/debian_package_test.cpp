// `make deb` as CI makes it (issue 59): scripts/make-deb.sh packages this build's program with
// debhelper, lintian passes it, and the package, unpacked into a temporary root (dpkg -x), holds
// the program, its scenes, its man pages, its units, its user and its configuration; the program
// from there says its version and passes the start-up checks (`--check`) of the loop command its
// unit runs on the room it ships as configuration (`sim --room`: the room is simulated, and `run`
// has no simulator); the units pass `systemd-analyze verify`.

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <string>

#include "qa_phantom_support.hpp"

namespace lftrack::test {
namespace {

namespace fs = std::filesystem;

// `lftrack --version`'s number (run in `dir`).
std::string program_version(const fs::path& dir) {
  const CliRun r = shell(quoted(LFTRACK_BIN_PATH) + " --version", dir, "version.txt");
  std::smatch m;
  return std::regex_search(r.out, m, std::regex(R"(lftrack (\S+))")) ? m[1].str() : std::string();
}

// The package of this build, made once for all the suite's tests (each runs in a process of its
// own): under a lock, in the test cache, again whenever the program, debian/, the scripts or the
// scenes are newer than the last one made. A failed make leaves no stamp, so every test shows it.
class DebianPackage : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir;
    const fs::path source(LFTRACK_SOURCE_DIR);
    const fs::path build_dir = fs::path(LFTRACK_BIN_PATH).parent_path().parent_path();
    const fs::path out = test_cache_dir() / "deb";
    fs::create_directories(out);
    // "making" is touched before the package is made and renamed "made" after: a program rebuilt
    // while it was made is newer than the stamp, and the next test makes the package again.
    const fs::path stamp = out / "made", making = out / "making";
    std::string inputs;
    for (const fs::path& p :
         {fs::path(LFTRACK_BIN_PATH), source / "debian", source / "scripts", source / "scenes",
          source / "docs", source / "CMakeLists.txt", source / "README.md"})
      inputs += " " + quoted(p.string());
    const std::string stale = "[ ! -f " + quoted(stamp.string()) + " ] || [ -n \"$(find" + inputs +
                              " -newer " + quoted(stamp.string()) + " | head -n 1)\" ]";
    const std::string make = "rm -f " + quoted(stamp.string()) + " && touch " + quoted(making.string()) +
                             " && bash " + quoted((source / "scripts/make-deb.sh").string()) + " " +
                             quoted(build_dir.string()) + " " + quoted(out.string()) + " && mv " +
                             quoted(making.string()) + " " + quoted(stamp.string());
    make_ = new CliRun(shell("flock " + quoted((test_cache_dir() / "deb.lock").string()) + " sh -c " +
                                 quoted("if " + stale + "; then " + make + "; else echo reused; fi"),
                             dir_->path(), "make-deb.txt"));
    deb_ = new fs::path(out / ("lftrack_" + program_version(dir_->path()) + "_amd64.deb"));
    root_ = new fs::path(dir_->path() / "root");
    if (make_->exit_code == 0)
      shell("dpkg -x " + quoted(deb_->string()) + " root", dir_->path(), "dpkg-x.txt");
  }
  static void TearDownTestSuite() {
    delete make_;
    delete deb_;
    delete root_;
    delete dir_;
  }
  void SetUp() override {
    ASSERT_EQ(make_->exit_code, 0) << make_->out;
    ASSERT_TRUE(fs::exists(*root_ / "usr/bin/lftrack")) << contents(dir_->path() / "dpkg-x.txt");
  }

  static std::string field(const std::string& name) {
    const CliRun r = shell("dpkg-deb -f " + quoted(deb_->string()) + " " + name, dir_->path(), "field.txt");
    return r.out;
  }

  static TempDir* dir_;
  static CliRun* make_;
  static fs::path* deb_;
  static fs::path* root_;
};
TempDir* DebianPackage::dir_ = nullptr;
CliRun* DebianPackage::make_ = nullptr;
fs::path* DebianPackage::deb_ = nullptr;
fs::path* DebianPackage::root_ = nullptr;

TEST_F(DebianPackage, IsNamedAfterTheProgramsVersionAndLintsClean) {
  const std::string version = program_version(dir_->path());
  ASSERT_FALSE(version.empty());
  EXPECT_EQ(deb_->filename().string(), "lftrack_" + version + "_amd64.deb");
  EXPECT_EQ(field("Version"), version + "\n");
  EXPECT_EQ(field("Package"), "lftrack\n");
  // lintian ran (its report is beside the package) and found no error or warning.
  const std::string lintian = contents(deb_->parent_path() / "lintian.txt");
  EXPECT_EQ(lintian.find("E: lftrack"), std::string::npos) << lintian;
  EXPECT_EQ(lintian.find("W: lftrack"), std::string::npos) << lintian;
  EXPECT_NE(lintian.find(": no error or warning"), std::string::npos) << "no lintian verdict: " << lintian;
}

TEST_F(DebianPackage, DependsOnTheLibrariesTheProgramLinks) {
  const std::string depends = field("Depends");
  // From the shared libraries (${shlibs:Depends}): the devices', the formats' and the console's.
  for (const char* library :
       {"libmodbus", "libaravis-0.8", "libdcmtk", "libyaml-cpp", "libnifti2", "libspdlog", "libopenigtlink"})
    EXPECT_NE(depends.find(library), std::string::npos) << library << " missing from Depends: " << depends;
  // The system user is made by systemd-sysusers in the postinst.
  EXPECT_NE(depends.find("systemd-sysusers"), std::string::npos) << depends;
}

TEST_F(DebianPackage, HoldsTheProgramScenesManPagesUnitsUserAndConfiguration) {
  for (const char* file :
       {"usr/bin/lftrack", "usr/share/lftrack/scenes/lumbar-ct.yaml",
        "usr/share/lftrack/scenes/room/gige-modbus.yaml", "usr/share/lftrack/scenes/qa-phantom.yaml",
        "usr/share/man/man1/lftrack.1.gz", "usr/share/man/man1/lftrack-run.1.gz",
        "usr/share/man/man1/lftrack-rt-check.1.gz", "usr/share/man/man1/lftrack-qa-daily.1.gz",
        "usr/share/doc/lftrack/copyright", "lib/systemd/system/lftrack@.service",
        "lib/systemd/system/lftrack-precompute@.service", "lib/systemd/system/lftrack-qa@.service",
        "usr/lib/sysusers.d/lftrack.conf", "usr/lib/tmpfiles.d/lftrack.conf", "etc/lftrack/qa-phantom.yaml",
        "etc/lftrack/qa-phantom.env"})
    EXPECT_TRUE(fs::exists(*root_ / file)) << file << " is not in the package";
  // The configuration is a conffile (an upgrade keeps the physicist's edits).
  const CliRun conffiles =
      shell("dpkg-deb --ctrl-tarfile " + quoted(deb_->string()) + " | tar -xO ./conffiles", dir_->path(),
            "conffiles.txt");
  EXPECT_NE(conffiles.out.find("/etc/lftrack/qa-phantom.yaml"), std::string::npos) << conffiles.out;
  EXPECT_NE(conffiles.out.find("/etc/lftrack/qa-phantom.env"), std::string::npos) << conffiles.out;
  const std::string sysusers = contents(*root_ / "usr/lib/sysusers.d/lftrack.conf");
  EXPECT_NE(sysusers.find("u lftrack - "), std::string::npos) << sysusers;
  EXPECT_NE(sysusers.find("/var/lib/lftrack"), std::string::npos) << sysusers;
}

TEST_F(DebianPackage, TheUnitsVerifyAndCarryTheRealTimeAndHardeningSettings) {
  const std::string unit = contents(*root_ / "lib/systemd/system/lftrack@.service");
  for (const char* setting :
       {"User=lftrack", "CPUSchedulingPolicy=fifo", "LimitRTPRIO=99", "LimitMEMLOCK=infinity", "Restart=no",
        "ProtectSystem=strict", "ReadWritePaths=/var/lib/lftrack/%i", "NoNewPrivileges=yes",
        "DevicePolicy=closed", "DeviceAllow=char-video4linux rw", "AF_CAN", "LFTRACK_LOOP=run",
        "/usr/bin/lftrack $LFTRACK_LOOP --scene /etc/lftrack/%i.yaml", "EnvironmentFile=-/etc/lftrack/%i.env",
        "--control /run/lftrack/%i/", "ReadWritePaths=/run/lock"})
    EXPECT_NE(unit.find(setting), std::string::npos) << setting << " missing from lftrack@.service";
  // The QA's unit sees the loop's couch lock (actuator_lock.hpp), not one in its private /tmp, and
  // reaches the room's devices as the loop's does (a room whose couch is a device: Modbus TCP,
  // CAN, serial lines).
  const std::string qa_unit = contents(*root_ / "lib/systemd/system/lftrack-qa@.service");
  for (const char* setting :
       {"ReadWritePaths=/run/lock", "AF_INET AF_INET6", "AF_CAN", "DeviceAllow=char-ttyUSB rw"})
    EXPECT_NE(qa_unit.find(setting), std::string::npos) << setting << " missing from lftrack-qa@.service";
  EXPECT_EQ(qa_unit.find("PrivateDevices=yes"), std::string::npos) << "the QA drives the room's devices";
  // systemd-analyze verify reads the units as the service manager would; the program's path is
  // the unpacked root's (verify checks that ExecStart's program exists). It exits 0 on settings
  // it ignores, so any message it prints is a failure too.
  const fs::path units = dir_->path() / "units";
  fs::create_directories(units);
  for (const char* name : {"lftrack@.service", "lftrack-precompute@.service", "lftrack-qa@.service"}) {
    std::string text = contents(*root_ / "lib/systemd/system" / name);
    text = std::regex_replace(text, std::regex("/usr/bin/lftrack"), (*root_ / "usr/bin/lftrack").string());
    std::ofstream(units / name) << text;
  }
  const CliRun verify =
      shell("systemd-analyze verify --man=no units/lftrack@qa-phantom.service", dir_->path(), "verify.txt");
  EXPECT_EQ(verify.exit_code, 0) << verify.out;
  EXPECT_EQ(verify.out, "") << "systemd-analyze verify said something about the units";
}

TEST_F(DebianPackage, TheInstalledProgramChecksTheRoomItShipsAsConfiguration) {
  const fs::path program = *root_ / "usr/bin/lftrack";
  const CliRun version = shell(quoted(program.string()) + " --version", dir_->path(), "version.txt");
  EXPECT_EQ(version.exit_code, 0);
  EXPECT_EQ(version.out, "lftrack " + program_version(dir_->path()) + "\n");
  // The room the unit's instance qa-phantom runs, with the light fields the installed program
  // builds (its precompute unit's command), checked as the unit's loop command (the installed
  // qa-phantom.env's LFTRACK_LOOP) checks it before a treatment. The room is simulated: `run`,
  // which has no simulator, refuses it by name.
  const fs::path scene = *root_ / "etc/lftrack/qa-phantom.yaml";
  const std::string loop = qa_phantom_loop(*root_ / "etc/lftrack/qa-phantom.env");
  ASSERT_EQ(loop.rfind("sim --room", 0), 0u) << "LFTRACK_LOOP=" << loop;
  const fs::path fields = qa_phantom_fields(program.string(), scene, dir_->path());
  ASSERT_FALSE(fields.empty()) << contents(dir_->path() / "precompute.txt");
  // As root (CI) the real-time set-up is checked too; another user has no grants here and
  // waives it, which the limits test covers.
  const std::string waive = ::geteuid() == 0 ? "" : " --rt ignore";
  const CliRun check = shell(quoted(program.string()) + " -q " + loop + " --check --scene " +
                                 quoted(scene.string()) + " --lf-dir " + quoted(fields.string()) + waive,
                             dir_->path(), "check.txt");
  EXPECT_EQ(check.exit_code, 0) << check.out;
  EXPECT_NE(check.out.find("pre-treatment checklist, QA phantom"), std::string::npos) << check.out;
  EXPECT_EQ(check.out.find("[FAIL]"), std::string::npos) << check.out;
  if (::geteuid() == 0) {
    EXPECT_NE(check.out.find("[ ok ] real-time set-up"), std::string::npos) << check.out;
  }
  const CliRun run = shell(quoted(program.string()) + " -q run --check --scene " + quoted(scene.string()) +
                               " --lf-dir " + quoted(fields.string()) + waive,
                           dir_->path(), "run-check.txt");
  EXPECT_EQ(run.exit_code, 1) << run.out;
  EXPECT_NE(run.out.find("[FAIL] simulated detectors"), std::string::npos) << run.out;
  EXPECT_NE(run.out.find("lftrack sim --room"), std::string::npos) << run.out;
}

}  // namespace
}  // namespace lftrack::test

// The loop as the service runs it (issue 59; on the shipped QA room, whose qa-phantom.env makes
// it `lftrack sim --room`, the real-time set-up `run`'s own): an unprivileged user whose only grants are the
// real-time ones lftrack@.service gives. Without them the start is refused, naming each missing
// limit and the unit setting that grants it, never a bare "permission denied"; with them the loop
// locks its memory, takes SCHED_FIFO on its CPU and tracks.
//
// As root (CI) the run drops to the user nobody (setpriv), so that no capability stands in for a
// limit; as another user it runs as that user.

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "qa_phantom_support.hpp"

namespace lftrack::test {
namespace {

namespace fs = std::filesystem;

// `setpriv` to nobody with no capability (root), or nothing (already unprivileged); `caps`: the
// ambient capabilities to keep (setpriv's list, e.g. "+ipc_lock,+sys_nice").
std::string unprivileged(const std::string& caps = "") {
  if (::geteuid() != 0) return "";
  std::string s = "setpriv --reuid=65534 --regid=65534 --clear-groups ";
  if (!caps.empty()) s += "--inh-caps=" + caps + " --ambient-caps=" + caps + " ";
  return s;
}

// A folder the unprivileged user may work in (journals, the phantom's cache).
void open_to_everyone(const fs::path& dir) {
  fs::permissions(dir, fs::perms::all, fs::perm_options::replace);
}

TEST(ServiceLimits, AStartWithoutTheUnitsLimitsNamesEachMissingOne) {
  TempDir dir;
  open_to_everyone(dir.path());
  const fs::path fields = qa_phantom_fields(LFTRACK_BIN_PATH, qa_phantom_scene(), dir.path());
  ASSERT_FALSE(fields.empty()) << contents(dir.path() / "precompute.txt");
  // Limits as a login without /etc/security/limits.conf entries has them (lowering needs no
  // privilege): 64 KiB of locked memory, no real-time priority.
  const CliRun r =
      shell("prlimit --memlock=65536:65536 --rtprio=0:0 " + unprivileged() + quoted(LFTRACK_BIN_PATH) + " " +
                qa_phantom_loop() + " --cycles 1 --journal '' --scene " +
                quoted(qa_phantom_scene().string()) + " --lf-dir " + quoted(fields.string()),
            dir.path());
  EXPECT_NE(r.exit_code, 0) << r.out;
  for (const char* named : {"RLIMIT_MEMLOCK is 65536 bytes", "RLIMIT_RTPRIO is 0", "LimitMEMLOCK=infinity",
                            "LimitRTPRIO=80", "/etc/security/limits.conf"})
    EXPECT_NE(r.out.find(named), std::string::npos) << "'" << named << "' not in:\n" << r.out;
  EXPECT_EQ(r.out.find("Operation not permitted"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("TRACK"), std::string::npos) << "a refused start ran cycles:\n" << r.out;

  // A cycle CPU outside the process's CPUs names the unit's CPUAffinity=.
  std::string scene = contents(qa_phantom_scene());
  const std::string cpus = "    cpus: [0]";
  ASSERT_NE(scene.find(cpus), std::string::npos);
  scene.replace(scene.find(cpus), cpus.size(), "    cpus: [1023]");
  std::ofstream(dir.path() / "far-cpu.yaml") << scene;
  const CliRun far = shell(quoted(LFTRACK_BIN_PATH) + " " + qa_phantom_loop() +
                               " --check --scene far-cpu.yaml --lf-dir " + quoted(fields.string()),
                           dir.path(), "far.txt");
  EXPECT_EQ(far.exit_code, 1) << far.out;
  EXPECT_NE(far.out.find("CPU 1023 not among this process's CPUs"), std::string::npos) << far.out;
  EXPECT_NE(far.out.find("CPUAffinity="), std::string::npos) << far.out;
}

TEST(ServiceLimits, WithTheGrantsTheLoopRunsAsAnUnprivilegedUser) {
  if (::geteuid() != 0) GTEST_SKIP() << "needs root to become an unprivileged user with only the grants";
  TempDir dir;
  open_to_everyone(dir.path());
  const fs::path fields = qa_phantom_fields(LFTRACK_BIN_PATH, qa_phantom_scene(), dir.path());
  ASSERT_FALSE(fields.empty()) << contents(dir.path() / "precompute.txt");
  // The unit's limits where this host lets root raise them (CAP_SYS_RESOURCE); a container that
  // does not (this project's CI machine) grants the same two things as capabilities instead.
  const bool limits =
      shell("prlimit --memlock=unlimited:unlimited --rtprio=99:99 true", dir.path(), "probe.txt").exit_code ==
      0;
  // Started as the unit starts it: SCHED_FIFO 1 with the reset-on-fork flag a drop-in may set
  // (CPUSchedulingResetOnFork=), which the loop must keep when it raises its cycle's priority.
  const std::string grant = (limits ? "prlimit --memlock=unlimited:unlimited --rtprio=99:99 " + unprivileged()
                                    : unprivileged("+ipc_lock,+sys_nice")) +
                            "chrt --fifo --reset-on-fork 1 ";
  std::cout << "granted as "
            << (limits ? "limits (LimitMEMLOCK, LimitRTPRIO)" : "capabilities (IPC_LOCK, SYS_NICE)") << "\n";
  const CliRun r = shell(grant + quoted(LFTRACK_BIN_PATH) + " " + qa_phantom_loop() +
                             " --cycles 20 --journal journal.lfj --scene " +
                             quoted(qa_phantom_scene().string()) + " --lf-dir " + quoted(fields.string()),
                         dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.out;
  EXPECT_NE(r.out.find("real-time set-up: memory locked, SCHED_FIFO, pinned"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("cycles 20 (cycle count reached)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("holds 0"), std::string::npos) << r.out;
  // The journal belongs to the user the loop ran as.
  const fs::path journal = dir.path() / "journal.lfj";
  ASSERT_TRUE(fs::exists(journal)) << r.out;
  const CliRun owner = shell("stat -c %u " + quoted(journal.string()), dir.path(), "owner.txt");
  EXPECT_EQ(owner.out, "65534\n");
}

}  // namespace
}  // namespace lftrack::test

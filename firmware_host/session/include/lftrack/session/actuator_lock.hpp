#pragma once
// One program at a time drives a room's couch or robot. Every lftrack command that opens a
// scene's device actuator (modbus, can) holds this lock while it may command it: `lftrack run`
// (LoopSession), its start-up check (`run --check` opens the couch and tells it to hold), and
// `lftrack qa daily` in a room (its shifts and its runs). A second program that would drive the
// same couch is refused before it opens it, with the holder's process id and command line, so a
// QA never shifts the couch under a treatment, and a treatment never starts under a QA.
//
// The lock is an exclusive flock(2) on a file named after the couch's identity (couch_identity():
// where it is reached, as the kernel reaches it: a Modbus TCP host by its numeric address, so
// "localhost", "127.1" and "127.0.0.1" are one couch; a serial line or a CAN bridge by its path with
// links followed; a CAN bus by its interface; the Modbus unit, the CAN node and the baud rate are
// not part of it) in the lock folder: /run/lock, else (no such folder) /tmp. The tests' own
// folder is $LFTRACK_TEST_LOCK_DIR (an absolute path, or the lock is refused): a variable for
// tests only, which the service units unset (a room.env or a shell that set it for one program
// would give that program a lock of its own). A lock folder this user cannot write
// refuses the couch: it never falls back to a folder another program would not look in. The
// service units name /run/lock writable, so the loop's unit and the QA's unit (each with a
// private /tmp) see one lock. The lock is this host's: a program on another host that reaches the
// same couch is not refused. Any local user who can write the lock folder can take a lock and so
// refuse a couch: it fails closed. The kernel releases it
// when its holder exits, however it ends: a crashed holder leaves no stale lock, only its file
// (which the next holder reuses). Within one process the lock is shared: a QA that holds it runs
// loop sessions on the same couch.

#include <unistd.h>

#include <memory>
#include <string>

#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::session {

// The environment variable that names the tests' lock folder.
inline constexpr const char* kTestLockDirVariable = "LFTRACK_TEST_LOCK_DIR";

class ActuatorLock {
 public:
  // The lock of `scene`'s actuator (a device: modbus or can; an error for any other), held until
  // the last copy of the returned pointer is gone. Refused with failed_precondition, naming the
  // holder, when another process holds it; an io_error when the lock file cannot be made.
  static Result<std::shared_ptr<const ActuatorLock>> acquire(const Scene& scene);

  // The folder the lock files are in, the couch's identity and its lock file (see above).
  static std::string lock_dir();
  static std::string couch_identity(const Scene& scene);
  static std::string lock_path(const Scene& scene);

  ~ActuatorLock();
  ActuatorLock(const ActuatorLock&) = delete;
  ActuatorLock& operator=(const ActuatorLock&) = delete;

  const std::string& path() const { return path_; }

 private:
  ActuatorLock(int fd, std::string path) : fd_(fd), owner_(::getpid()), path_(std::move(path)) {}
  int fd_;
  pid_t owner_;  // the process that took it (a forked child shares nothing of it)
  std::string path_;
};

}  // namespace lftrack::session

#pragma once
// Another process that holds a scene's actuator lock (lftrack/session/actuator_lock.hpp), as a
// second lftrack driving the same couch would: a forked child takes the lock and keeps it until
// the object is destroyed (or kill() ends it as a crash would). A lock is shared within one
// process, so only another process can be refused by it.

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <optional>
#include <string>

#include "lftrack/session/actuator_lock.hpp"

namespace lftrack::test {

// An environment variable set while this lives, its earlier value (or its absence) back after.
class ScopedEnvironment {
 public:
  ScopedEnvironment(const char* name, const std::string& value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old;
    ::setenv(name, value.c_str(), 1);
  }
  ~ScopedEnvironment() {
    if (old_)
      ::setenv(name_, old_->c_str(), 1);
    else
      ::unsetenv(name_);
  }
  ScopedEnvironment(const ScopedEnvironment&) = delete;
  ScopedEnvironment& operator=(const ScopedEnvironment&) = delete;

 private:
  const char* name_;
  std::optional<std::string> old_;
};

class ActuatorLockHolder {
 public:
  explicit ActuatorLockHolder(const session::Scene& scene) {
    int ready[2], release[2];
    if (::pipe(ready) != 0 || ::pipe(release) != 0) return;
    pid_ = ::fork();
    if (pid_ == 0) {
      ::close(ready[0]);
      ::close(release[1]);
      auto lock = session::ActuatorLock::acquire(scene);
      const char got = lock.ok() ? 'y' : 'n';
      (void)!::write(ready[1], &got, 1);
      char ignored;
      (void)!::read(release[0], &ignored, 1);  // returns at EOF: the parent let go, or died
      ::_exit(0);
    }
    ::close(ready[1]);
    ::close(release[0]);
    release_ = release[1];
    char got = 'n';
    held_ = pid_ > 0 && ::read(ready[0], &got, 1) == 1 && got == 'y';
    ::close(ready[0]);
  }
  ~ActuatorLockHolder() { end(); }
  ActuatorLockHolder(const ActuatorLockHolder&) = delete;
  ActuatorLockHolder& operator=(const ActuatorLockHolder&) = delete;

  bool held() const { return held_; }  // the child took the lock
  pid_t pid() const { return pid_; }
  // The child ended as a crash would end it (SIGKILL: no destructor runs), and waited for.
  void kill() {
    if (pid_ > 0) ::kill(pid_, SIGKILL);
    end();
  }
  // The child let go of the lock and ended, waited for.
  void end() {
    if (release_ >= 0) ::close(release_);
    release_ = -1;
    if (pid_ > 0) ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }

 private:
  pid_t pid_ = -1;
  int release_ = -1;
  bool held_ = false;
};

}  // namespace lftrack::test

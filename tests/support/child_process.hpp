#pragma once
// A program the test starts and keeps running beside it (a device server): its standard output
// is read line by line, and it is stopped (SIGTERM, then SIGKILL) when the object goes.

#include <sys/types.h>

#include <chrono>
#include <optional>
#include <string>
#include <vector>

namespace lftrack::test {

class ChildProcess {
 public:
  // Starts argv[0] with argv; stderr goes to the test's stderr. Fails the test on error.
  explicit ChildProcess(const std::vector<std::string>& argv);
  ~ChildProcess();
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  bool started() const { return pid_ > 0; }
  pid_t pid() const { return pid_; }
  // The next line of standard output, or nothing by `timeout` (or at end of file).
  std::optional<std::string> read_line(std::chrono::milliseconds timeout);
  void signal(int sig);
  // Waits for the exit (at most `timeout`); the exit status, or -1 (still running: SIGKILLed).
  int wait(std::chrono::milliseconds timeout);

 private:
  pid_t pid_ = -1;
  int stdout_fd_ = -1;
  std::string buffer_;
  bool reaped_ = false;
  int status_ = -1;
};

}  // namespace lftrack::test

#pragma once
// A progress bar with elapsed time and ETA on stderr for long jobs (precompute, studies).
// On a terminal it redraws one line; otherwise it prints a line at most every 5 seconds.
// update() may be called from any thread.

#include <chrono>
#include <mutex>
#include <string>

namespace lftrack::session {

class ProgressBar {
 public:
  explicit ProgressBar(std::string label);
  void update(double fraction);
  // Prints the final line (100 %, total time); returns the seconds taken.
  double finish();

 private:
  std::string label_;
  bool terminal_;
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_print_;
  std::mutex mutex_;
};

}  // namespace lftrack::session

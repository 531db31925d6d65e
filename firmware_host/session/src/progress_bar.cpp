#include "lftrack/session/progress_bar.hpp"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

namespace lftrack::session {

ProgressBar::ProgressBar(std::string label)
    : label_(std::move(label)),
      terminal_(isatty(STDERR_FILENO) != 0),
      start_(std::chrono::steady_clock::now()),
      last_print_(start_) {}

void ProgressBar::update(double fraction) {
  std::lock_guard lock(mutex_);
  const auto now = std::chrono::steady_clock::now();
  if (!terminal_ && now - last_print_ < std::chrono::seconds(5)) return;
  last_print_ = now;
  fraction = std::clamp(fraction, 0.0, 1.0);
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  const double eta = fraction > 0.01 ? elapsed * (1.0 - fraction) / fraction : -1.0;
  constexpr int kWidth = 30;
  const int filled = static_cast<int>(fraction * kWidth);
  const std::string bar =
      std::string(std::size_t(filled), '#') + std::string(std::size_t(kWidth - filled), '.');
  char eta_text[32] = "ETA --";
  if (eta >= 0) std::snprintf(eta_text, sizeof eta_text, "ETA %.0f s", eta);
  std::fprintf(stderr, "%s%s [%s] %3.0f%%  %.0f s, %s%s", terminal_ ? "\r" : "", label_.c_str(), bar.c_str(),
               100.0 * fraction, elapsed, eta_text, terminal_ ? "   " : "\n");
  std::fflush(stderr);
}

double ProgressBar::finish() {
  std::lock_guard lock(mutex_);
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  std::fprintf(stderr, "%s%s [%s] 100%%  %.1f s%s\n", terminal_ ? "\r" : "", label_.c_str(),
               std::string(30, '#').c_str(), elapsed, terminal_ ? "          " : "");
  return elapsed;
}

}  // namespace lftrack::session

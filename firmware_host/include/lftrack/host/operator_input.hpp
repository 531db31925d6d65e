#pragma once
// How an operator talks to the running loop: leaving HOLD is always an explicit action
// (DESIGN.md, "One cycle"). The loop polls once per cycle; polling never blocks and never
// allocates.
//
//   terminal        single keys on the controlling terminal (raw mode while the loop runs):
//                   r = resume, s = stop, x = reset a FAULT, q = quit
//   control socket  datagrams "resume", "stop", "reset", "quit" on a local (AF_UNIX) socket;
//                   e.g.  echo -n resume | socat - UNIX-SENDTO:/tmp/lftrack.sock
//   scripted        an unattended operator that resumes a set time after each HOLD (tests and
//                   benchmark runs; says so in the journal's reason)

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "lftrack/host/tracking_states.hpp"
#include "lftrack/tracking/status.hpp"

namespace lftrack::host {

enum class OperatorCommand : std::uint8_t { kNone, kResume, kStop, kReset, kQuit };
const char* to_string(OperatorCommand command);
// "resume", "stop", "reset", "quit" (surrounding white space ignored) -> the command; else kNone.
OperatorCommand parse_operator_command(const char* text, std::size_t length);

class OperatorInput {
 public:
  virtual ~OperatorInput() = default;
  // One command if one is waiting; `state` and `cycles_in_state` let a scripted operator decide.
  virtual OperatorCommand poll(TrackingState state, std::int64_t cycles_in_state) = 0;
};

// Keys on standard input when it is a terminal (raw, non-blocking; restored on destruction).
class TerminalOperator final : public OperatorInput {
 public:
  // Fails when standard input is not a terminal.
  static Result<std::unique_ptr<TerminalOperator>> open();
  ~TerminalOperator() override;
  OperatorCommand poll(TrackingState state, std::int64_t cycles_in_state) override;

 private:
  TerminalOperator() = default;
  bool restore_ = false;
  unsigned char saved_[64] = {};  // struct termios, kept opaque here
  int saved_flags_ = 0;
};

// A datagram socket at `path` (removed on destruction); one command per datagram.
class ControlSocket final : public OperatorInput {
 public:
  static Result<std::unique_ptr<ControlSocket>> open(const std::filesystem::path& path);
  ~ControlSocket() override;
  OperatorCommand poll(TrackingState state, std::int64_t cycles_in_state) override;
  const std::filesystem::path& path() const { return path_; }

 private:
  ControlSocket() = default;
  int fd_ = -1;
  std::filesystem::path path_;
};

// Resumes `after_cycles` cycles into each HOLD (and resets a FAULT never).
class ScriptedOperator final : public OperatorInput {
 public:
  explicit ScriptedOperator(std::int64_t after_cycles) : after_cycles_(after_cycles) {}
  OperatorCommand poll(TrackingState state, std::int64_t cycles_in_state) override;

 private:
  std::int64_t after_cycles_;
};

// Polls several inputs in order; the first command wins.
class OperatorInputs final : public OperatorInput {
 public:
  void add(std::unique_ptr<OperatorInput> input) { inputs_.push_back(std::move(input)); }
  bool empty() const { return inputs_.empty(); }
  OperatorCommand poll(TrackingState state, std::int64_t cycles_in_state) override;

 private:
  std::vector<std::unique_ptr<OperatorInput>> inputs_;
};

}  // namespace lftrack::host

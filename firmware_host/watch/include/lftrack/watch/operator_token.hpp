#pragma once
// Who may act from the monitor page (DESIGN.md, "The operator boundary"): a secret token made
// for each run, and single-use nonces that keep a captured request from being sent again.
//
// The token is 32 random bytes (OpenSSL's RAND_bytes) written as 64 hexadecimal digits. It is
// printed at start and stored in a file of mode 0600 that only the user running lftrack can read;
// a request carries it as "Authorization: Bearer TOKEN", and it is compared in constant time
// (CRYPTO_memcmp), so the time a refusal takes says nothing about how much of a guess was right.

#include <array>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>

#include "lftrack/tracking/status.hpp"

namespace lftrack::watch {

// Random bytes from OpenSSL's generator as lower-case hexadecimal (2 digits a byte).
Result<std::string> random_hex(std::size_t bytes);

// True when `offered` is exactly `expected`, in time that depends only on expected's length.
bool token_matches(const std::string& expected, const std::string& offered);

// A token file that belongs to one run: created new with mode 0600 (never through a symbolic
// link); an earlier run's file at that path (a regular file of this user holding only a token)
// is replaced unless a running lftrack holds it (the file is locked, flock, for as long as its
// run serves), anything else is refused. The file is removed when the object is destroyed, if it
// is still the one written.
class TokenFile {
 public:
  static Result<std::unique_ptr<TokenFile>> write(const std::filesystem::path& path, const std::string& token);
  // Whether write() would take `path`: nothing there, or an earlier run's token file no running
  // lftrack holds. For checking options before the CT is loaded; write() checks again.
  static Status check(const std::filesystem::path& path);
  ~TokenFile();
  const std::filesystem::path& path() const { return path_; }

 private:
  TokenFile() = default;
  std::filesystem::path path_;
  std::uint64_t device_ = 0, inode_ = 0;
  std::string token_;
  int fd_ = -1;  // the file, locked while the run serves
};

// Nonces the server hands out (GET /api/nonce), each good for one request within kNonceLifetime.
// At most kNonces are outstanding; handing out another forgets the oldest. Thread-safe.
class NonceBook {
 public:
  static constexpr int kNonces = 64;
  static constexpr std::chrono::seconds kNonceLifetime{30};
  using Clock = std::chrono::steady_clock;

  Result<std::string> issue(Clock::time_point now = Clock::now());
  // True (and the nonce is spent) when `nonce` was handed out, is unused and not too old.
  bool spend(const std::string& nonce, Clock::time_point now = Clock::now());

 private:
  struct Entry {
    std::string value;
    Clock::time_point issued{};
    bool spent = true;
  };
  std::mutex mutex_;
  std::array<Entry, kNonces> entries_;
  int next_ = 0;
};

}  // namespace lftrack::watch

#include "lftrack/watch/operator_token.hpp"

#include <fcntl.h>
#include <openssl/crypto.h>
#include <openssl/rand.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <iterator>
#include <vector>

namespace lftrack::watch {

Result<std::string> random_hex(std::size_t bytes) {
  std::vector<unsigned char> raw(bytes);
  if (RAND_bytes(raw.data(), static_cast<int>(raw.size())) != 1)
    return internal_error("the random generator (OpenSSL RAND_bytes) failed");
  static const char digits[] = "0123456789abcdef";
  std::string hex;
  for (unsigned char b : raw) {
    hex += digits[b >> 4];
    hex += digits[b & 15];
  }
  return hex;
}

bool token_matches(const std::string& expected, const std::string& offered) {
  if (expected.empty() || offered.size() != expected.size()) return false;
  return CRYPTO_memcmp(expected.data(), offered.data(), expected.size()) == 0;
}

namespace {

// An earlier run's token file, exactly as write() leaves it: a regular file of this user, mode
// 0600, one line of 64 lowercase hexadecimal digits. Anything else (a user's file that merely
// looks like a token, with another mode) is never replaced.
bool is_earlier_token_file(const std::filesystem::path& path) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode) || st.st_uid != ::geteuid() ||
      (st.st_mode & 07777) != 0600 || st.st_size != 65)
    return false;
  std::ifstream in(path);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  return text.size() == 65 && text.back() == '\n' &&
         text.find_first_not_of("0123456789abcdef") == 64;
}

}  // namespace

Status TokenFile::check(const std::filesystem::path& path) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0) return {};  // nothing there
  if (!is_earlier_token_file(path))
    return failed_precondition(path.string() + " exists and is not an earlier lftrack token file; not replacing it");
  // A running lftrack holds its token file's lock until it exits (issue 50 probe: a second run
  // took a live run's token file over and removed it at its exit).
  const int earlier = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_CLOEXEC);
  const bool live = earlier >= 0 && ::flock(earlier, LOCK_EX | LOCK_NB) != 0 && errno == EWOULDBLOCK;
  if (earlier >= 0) ::close(earlier);
  if (live)
    return failed_precondition(path.string() + " is the token file of a running lftrack; give another "
                                               "--monitor-token-file or port");
  return {};
}

Result<std::unique_ptr<TokenFile>> TokenFile::write(const std::filesystem::path& path, const std::string& token) {
  const int flags = O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC;
  int fd = ::open(path.c_str(), flags, 0600);
  if (fd < 0 && errno == EEXIST) {
    LFTRACK_RETURN_IF_ERROR(check(path));
    if (::unlink(path.c_str()) != 0) return io_error(path.string() + ": cannot remove the earlier token file");
    fd = ::open(path.c_str(), flags, 0600);
  }
  if (fd < 0) return io_error(path.string() + ": cannot create the token file: " + std::strerror(errno));
  const std::string line = token + "\n";
  const bool written = ::flock(fd, LOCK_EX | LOCK_NB) == 0 && ::fchmod(fd, 0600) == 0 &&
                       ::write(fd, line.data(), line.size()) == static_cast<ssize_t>(line.size());
  struct stat st {};
  ::fstat(fd, &st);
  if (!written) {
    ::close(fd);
    ::unlink(path.c_str());
    return io_error(path.string() + ": cannot write the token file");
  }
  std::unique_ptr<TokenFile> file(new TokenFile);
  file->fd_ = fd;  // open, and locked, for as long as this run serves
  file->path_ = path;
  file->device_ = st.st_dev;
  file->inode_ = st.st_ino;
  file->token_ = token;
  return file;
}

TokenFile::~TokenFile() {
  // Still the file written (a file made since may reuse the inode: the text must match too).
  struct stat st {};
  if (::lstat(path_.c_str(), &st) != 0 || st.st_dev != device_ || st.st_ino != inode_ || !S_ISREG(st.st_mode)) {
    if (fd_ >= 0) ::close(fd_);
    return;
  }
  std::ifstream in(path_);
  std::string line;
  std::getline(in, line);
  if (line == token_) ::unlink(path_.c_str());
  if (fd_ >= 0) ::close(fd_);
}

Result<std::string> NonceBook::issue(Clock::time_point now) {
  auto nonce = random_hex(16);
  if (!nonce.ok()) return nonce.status();
  std::lock_guard<std::mutex> lock(mutex_);
  Entry& e = entries_[std::size_t(next_)];
  next_ = (next_ + 1) % kNonces;
  e.value = *nonce;
  e.issued = now;
  e.spent = false;
  return *nonce;
}

bool NonceBook::spend(const std::string& nonce, Clock::time_point now) {
  if (nonce.size() != 32) return false;
  std::lock_guard<std::mutex> lock(mutex_);
  for (Entry& e : entries_)
    if (!e.spent && e.value == nonce) {
      e.spent = true;  // spent even when too old: it can never be used again
      return now - e.issued <= kNonceLifetime && now >= e.issued;
    }
  return false;
}

}  // namespace lftrack::watch

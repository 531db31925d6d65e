#pragma once
// Status and Result: the error values of lftrack. Library code never throws across its API:
// set-up and load functions return a Status or a Result<T> with a message a person can act on,
// cycle functions return a Status. Both are cheap to copy when OK (no allocation).

#include <cassert>
#include <optional>
#include <string>
#include <utility>

namespace lftrack {

enum class StatusCode {
  kOk,
  kInvalidArgument,     // caller passed something malformed (bad option, bad geometry)
  kNotFound,            // a file or named thing does not exist
  kIoError,             // the OS refused a read or write
  kCorruptData,         // a file exists but its content is inconsistent or truncated
  kUnsupported,         // well-formed input that lftrack cannot handle (codec, data type)
  kOutOfRange,          // a value outside its allowed range
  kFailedPrecondition,  // called in the wrong state
  kInternal,            // a broken invariant inside lftrack
};

const char* to_string(StatusCode code);

class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  static Status ok_status() { return {}; }
  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }
  // "code: message", for logs and CLI errors.
  std::string to_string() const;

  // Returns a copy whose message is prefixed with `context: `; OK stays OK.
  Status with_context(const std::string& context) const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

inline Status invalid_argument(std::string m) {
  return {StatusCode::kInvalidArgument, std::move(m)};
}
inline Status not_found(std::string m) {
  return {StatusCode::kNotFound, std::move(m)};
}
inline Status io_error(std::string m) {
  return {StatusCode::kIoError, std::move(m)};
}
inline Status corrupt_data(std::string m) {
  return {StatusCode::kCorruptData, std::move(m)};
}
inline Status unsupported(std::string m) {
  return {StatusCode::kUnsupported, std::move(m)};
}
inline Status out_of_range(std::string m) {
  return {StatusCode::kOutOfRange, std::move(m)};
}
inline Status failed_precondition(std::string m) {
  return {StatusCode::kFailedPrecondition, std::move(m)};
}
inline Status internal_error(std::string m) {
  return {StatusCode::kInternal, std::move(m)};
}

// A value or the Status that explains why there is none. Accessing value() of a failed Result is
// a programming error (asserted).
template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : value_(std::move(value)) {}         // NOLINT(google-explicit-constructor)
  Result(Status status) : status_(std::move(status)) {  // NOLINT(google-explicit-constructor)
    assert(!status_.ok() && "a Result built from a Status must carry an error");
  }

  bool ok() const { return value_.has_value(); }
  const Status& status() const { return status_; }
  T& value() & {
    assert(ok());
    return *value_;
  }
  const T& value() const& {
    assert(ok());
    return *value_;
  }
  T&& value() && {
    assert(ok());
    return std::move(*value_);
  }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

 private:
  std::optional<T> value_;
  Status status_;
};

}  // namespace lftrack

// Returns early from the enclosing function with the Status of `expr` if it is not OK.
#define LFTRACK_RETURN_IF_ERROR(expr)                  \
  do {                                                 \
    ::lftrack::Status lftrack_status_ = (expr);        \
    if (!lftrack_status_.ok()) return lftrack_status_; \
  } while (false)

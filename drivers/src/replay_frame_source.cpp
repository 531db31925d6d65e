#include "lftrack/drivers/replay_frame_source.hpp"

#include <algorithm>
#include <chrono>
#include <cstring>

#include "lftrack/drivers/frame_files.hpp"

namespace lftrack::drivers {
ReplayFrameSource::ReplayFrameSource(FrameSequence sequence, std::vector<DetectorShape> detectors,
                                     const ReplayOptions& options)
    : sequence_(std::move(sequence)), detectors_(std::move(detectors)), options_(options) {}

ReplayFrameSource::~ReplayFrameSource() {
  close();
}

std::int64_t ReplayFrameSource::offset_ns(std::size_t pair) const {
  return pair_start_ns_[pair] - pair_start_ns_[0];
}

Status ReplayFrameSource::open(FramePair* pair) {
  if (thread_.joinable()) return failed_precondition("replay: already open");
  if (sequence_.pairs.empty()) return failed_precondition(sequence_.directory.string() + ": no frames");
  column_.clear();
  for (const DetectorShape& d : detectors_) {
    auto it = std::find(sequence_.detectors.begin(), sequence_.detectors.end(), d.name);
    if (it == sequence_.detectors.end()) {
      std::string have;
      for (const std::string& n : sequence_.detectors) have += (have.empty() ? "" : ", ") + n;
      return failed_precondition(sequence_.directory.string() + ": the sequence has no frames of detector '" +
                                 d.name + "' (it has " + have + ")");
    }
    if (d.rows <= 0 || d.cols <= 0) return invalid_argument("replay: detector " + d.name + " has no size");
    column_.push_back(std::size_t(it - sequence_.detectors.begin()));
  }
  // A sequence with frames of a detector the scene does not have was recorded in another room
  // (or by another scene): refused, never half-used.
  for (const std::string& n : sequence_.detectors) {
    const bool known = std::any_of(detectors_.begin(), detectors_.end(), [&](const DetectorShape& d) { return d.name == n; });
    if (!known) {
      std::string want;
      for (const DetectorShape& d : detectors_) want += (want.empty() ? "" : ", ") + d.name;
      return failed_precondition(sequence_.directory.string() + ": the sequence has frames of detector '" + n +
                                 "', which the scene does not have (it has " + want + ")");
    }
  }
  // Each pair's start: its earliest frame of these detectors; a pair with none listed starts
  // where the one before it did (its acquire() faults anyway).
  pair_start_ns_.assign(sequence_.pairs.size(), INT64_MAX);
  for (std::size_t p = 0; p < sequence_.pairs.size(); ++p) {
    for (std::size_t c : column_) {
      const SequenceFrame& f = sequence_.pairs[p].frames[c];
      if (f.present) pair_start_ns_[p] = std::min(pair_start_ns_[p], f.timestamp_ns);
    }
    if (pair_start_ns_[p] == INT64_MAX) pair_start_ns_[p] = p > 0 ? pair_start_ns_[p - 1] : 0;
  }
  pair->frames.assign(detectors_.size(), Frame{});
  loaded_.clear();
  for (std::size_t v = 0; v < detectors_.size(); ++v) {
    pair->frames[v].pixels = tracking::Image<std::uint16_t>(detectors_[v].rows, detectors_[v].cols);
    loaded_.emplace_back(detectors_[v].rows, detectors_[v].cols);
  }
  loaded_status_.assign(detectors_.size(), Status{});
  stopping_ = false;
  thread_ = std::thread([this] { read_loop(); });
  return {};
}

void ReplayFrameSource::request_exposure(std::int64_t exposure_time_ns) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!started_) {
    started_ = true;
    first_request_ns_ = exposure_time_ns;
  }
  std::size_t job = next_;
  if (options_.realtime) {
    const std::int64_t elapsed = exposure_time_ns - first_request_ns_;
    while (job + 1 < sequence_.pairs.size() && offset_ns(job + 1) <= elapsed) ++job;
  }
  requested_ = job;
  requested_exposure_ns_ = exposure_time_ns;
  if (job < sequence_.pairs.size() && job != loaded_job_) {
    has_request_ = true;
    wake_.notify_one();
  }
}

void ReplayFrameSource::load(std::size_t job) {
  const SequencePair& p = sequence_.pairs[job];
  for (std::size_t v = 0; v < detectors_.size(); ++v) {
    const SequenceFrame& f = p.frames[column_[v]];
    loaded_status_[v] = f.present ? read_frame_file(f.path.c_str(), loaded_[v].view())
                                  : not_found("pair " + std::to_string(p.index) +
                                              " has no frame of detector " + detectors_[v].name);
  }
}

void ReplayFrameSource::read_loop() {
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    wake_.wait(lock, [&] { return stopping_ || has_request_; });
    if (stopping_) return;
    has_request_ = false;
    const std::size_t job = requested_;
    loading_ = true;
    lock.unlock();
    load(job);
    lock.lock();
    loading_ = false;
    loaded_job_ = job;
    done_.notify_all();
  }
}

DeviceStatus ReplayFrameSource::acquire(FramePair* pair, Deadline deadline) {
  std::unique_lock<std::mutex> lock(mutex_);
  const std::size_t job = requested_;
  if (job >= sequence_.pairs.size()) {
    exhausted_ = true;
    return DeviceStatus::kDisconnected;
  }
  auto ready = [&] { return !loading_ && !has_request_ && loaded_job_ == job; };
  if (options_.realtime) {
    // A pair not due by the deadline is late whether or not it has been read yet: the index
    // alone says when it is due, so the answer does not wait on the reader thread.
    const auto due =
        std::chrono::steady_clock::time_point(std::chrono::nanoseconds(first_request_ns_ + offset_ns(job)));
    if (due > deadline) {
      ++counters_.late;
      return DeviceStatus::kTimeout;
    }
    if (!done_.wait_until(lock, deadline, ready)) return DeviceStatus::kTimeout;
    lock.unlock();
    std::this_thread::sleep_until(due);
    lock.lock();
  } else {
    done_.wait(lock, ready);
  }
  next_ = job + 1;
  const SequencePair& p = sequence_.pairs[job];
  bool complete = true;
  for (std::size_t v = 0; v < detectors_.size(); ++v) {
    const Status& s = loaded_status_[v];
    if (!s.ok()) {
      complete = false;
      if (s.code() == StatusCode::kNotFound)
        ++counters_.missing;
      else if (s.code() == StatusCode::kOutOfRange)
        ++counters_.wrong_size;
      else
        ++counters_.unreadable;
      continue;
    }
    const SequenceFrame& f = p.frames[column_[v]];
    Frame& out = pair->frames[v];
    std::memcpy(out.pixels.pixels().data(), loaded_[v].pixels().data(),
                loaded_[v].pixels().size() * sizeof(std::uint16_t));
    out.sequence = f.sequence;
    const std::int64_t within_pair = f.timestamp_ns - pair_start_ns_[job];
    out.timestamp_ns =
        (options_.realtime ? first_request_ns_ + offset_ns(job) : requested_exposure_ns_) + within_pair;
  }
  if (!complete) return DeviceStatus::kFault;
  ++counters_.pairs_delivered;
  delivered_ = &p;
  return DeviceStatus::kOk;
}

bool ReplayFrameSource::exhausted() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return exhausted_;
}

void ReplayFrameSource::close() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

}  // namespace lftrack::drivers

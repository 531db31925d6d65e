#include "lftrack/loop/frame_archive.hpp"

#include <chrono>
#include <cstdio>
#include <cstring>

#include "lftrack/drivers/frame_files.hpp"
#include "lftrack/loop/realtime_setup.hpp"

namespace lftrack::loop {

FrameArchive::FrameArchive(const std::filesystem::path& directory,
                           const std::vector<drivers::DetectorShape>& detectors, const FrameArchiveOptions& o)
    : directory_text_(directory.string()),
      with_actuator_(o.with_actuator),
      slots_(std::size_t(o.slots)),
      filled_(std::size_t(o.slots)),
      free_(std::size_t(o.slots)) {
  for (const drivers::DetectorShape& d : detectors) names_.push_back(d.name);
  for (std::size_t s = 0; s < slots_.size(); ++s) {
    for (const drivers::DetectorShape& d : detectors) {
      drivers::Frame frame;
      frame.pixels = tracking::Image<std::uint16_t>(d.rows, d.cols);
      slots_[s].pair.frames.push_back(std::move(frame));
    }
    free_.push(std::uint32_t(s));
  }
}

FrameArchive::~FrameArchive() {
  (void)close();
}

namespace {

// Refuses a directory that holds anything, or with `overwrite` accepts (and with `remove`,
// removes) an earlier archive's own files; a directory that holds anything else is refused, not
// ours to remove.
Status prepare_archive_directory(const std::filesystem::path& directory, bool overwrite, bool remove) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(fs::symlink_status(directory, ec))) return {};
  if (!fs::is_directory(directory, ec))
    return failed_precondition("frame archive " + directory.string() + ": exists and is not a directory");
  if (fs::is_empty(directory, ec) && !ec) return {};
  const std::string refuse_hint = ": choose a new folder (lftrack never writes over an archive)";
  if (!overwrite)
    return failed_precondition("frame archive " + directory.string() + " is not empty" + refuse_hint +
                               ", or pass --overwrite to replace an earlier lftrack archive there");
  std::vector<fs::path> frames;
  bool has_index = false;
  for (const fs::directory_entry& e : fs::directory_iterator(directory, ec)) {
    const std::string name = e.path().filename().string();
    if (name == "index.csv" && e.is_regular_file()) {
      has_index = true;
    } else if (name == "actuator.csv" && e.is_regular_file()) {
    } else if (name == "frames" && e.is_directory() && !e.is_symlink()) {
      for (const fs::directory_entry& f : fs::directory_iterator(e.path(), ec)) {
        if (!f.is_regular_file() || f.is_symlink() || f.path().extension() != ".tif")
          return failed_precondition("frame archive " + directory.string() + ": " + f.path().string() +
                                     " is not an archived frame; not removing it" + refuse_hint);
        frames.push_back(f.path());
      }
    } else {
      return failed_precondition("frame archive " + directory.string() + ": holds " + name +
                                 ", which is not part of an lftrack archive; not removing it" + refuse_hint);
    }
  }
  if (ec) return io_error("frame archive " + directory.string() + ": " + ec.message());
  if (!has_index)
    return failed_precondition("frame archive " + directory.string() +
                               " holds no index.csv: not an lftrack archive; not removing it" + refuse_hint);
  if (!remove) return {};
  for (const fs::path& f : frames) fs::remove(f, ec);
  fs::remove(directory / "index.csv", ec);
  fs::remove(directory / "actuator.csv", ec);
  if (ec) return io_error("frame archive " + directory.string() + ": cannot remove the earlier archive: " + ec.message());
  return {};
}

}  // namespace

Status check_archive_directory(const std::filesystem::path& directory, bool overwrite) {
  return prepare_archive_directory(directory, overwrite, /*remove=*/false);
}

Result<std::unique_ptr<FrameArchive>> FrameArchive::open(const std::filesystem::path& directory,
                                                         const std::vector<drivers::DetectorShape>& detectors,
                                                         const FrameArchiveOptions& options) {
  if (detectors.empty()) return invalid_argument("frame archive: no detectors");
  if (options.slots < 1) return invalid_argument("frame archive: at least one slot");
  for (const drivers::DetectorShape& d : detectors)
    if (d.name.empty() || d.name.find_first_of(",\n/") != std::string::npos)
      return invalid_argument("frame archive: detector name '" + d.name +
                              "' cannot name a file or a CSV field");
  LFTRACK_RETURN_IF_ERROR(prepare_archive_directory(directory, options.overwrite, /*remove=*/true));
  std::unique_ptr<FrameArchive> a(new FrameArchive(directory, detectors, options));
  LFTRACK_RETURN_IF_ERROR(a->index_.open(directory, options.with_actuator).with_context("frame archive"));
  a->thread_ = std::thread([p = a.get()] { p->run(); });
  return a;
}

bool FrameArchive::append(std::int64_t pair_index, const drivers::FramePair& pair,
                          const tracking::Vector6d* actuator_travel) {
  bool shaped = !closed_ && pair.frames.size() == names_.size();
  for (std::size_t v = 0; shaped && v < pair.frames.size(); ++v)  // the shapes open() was told
    shaped = pair.frames[v].pixels.rows() == slots_[0].pair.frames[v].pixels.rows() &&
             pair.frames[v].pixels.cols() == slots_[0].pair.frames[v].pixels.cols();
  std::uint32_t s = 0;
  if (!shaped || !free_.pop(&s)) {
    ++dropped_;
    return false;
  }
  Slot& slot = slots_[s];
  slot.pair_index = pair_index;
  slot.has_actuator = with_actuator_ && actuator_travel != nullptr;
  for (int i = 0; slot.has_actuator && i < 6; ++i) slot.actuator_travel[i] = (*actuator_travel)(i);
  for (std::size_t v = 0; v < pair.frames.size(); ++v) {
    const drivers::Frame& in = pair.frames[v];
    drivers::Frame& out = slot.pair.frames[v];
    std::memcpy(out.pixels.pixels().data(), in.pixels.pixels().data(),
                in.pixels.pixels().size() * sizeof(std::uint16_t));
    out.sequence = in.sequence;
    out.timestamp_ns = in.timestamp_ns;
  }
  filled_.push(s);  // cannot fail: as many places as slots
  return true;
}

bool FrameArchive::wait_for_slot(std::chrono::nanoseconds limit) const {
  if (closed_) return false;
  const auto until = std::chrono::steady_clock::now() + limit;
  while (free_.empty()) {
    if (std::chrono::steady_clock::now() >= until) return false;
    std::this_thread::sleep_for(std::chrono::microseconds(50));
  }
  return true;
}

Status FrameArchive::write_slot(const Slot& slot) {
  char relative[256];
  char path[4096];
  for (std::size_t v = 0; v < names_.size(); ++v) {
    const drivers::Frame& f = slot.pair.frames[v];
    std::snprintf(relative, sizeof relative, "frames/%06lld-%s.tif", static_cast<long long>(slot.pair_index),
                  names_[v].c_str());
    std::snprintf(path, sizeof path, "%s/%s", directory_text_.c_str(), relative);
    LFTRACK_RETURN_IF_ERROR(drivers::write_frame_file(path, f.pixels.view()));
    LFTRACK_RETURN_IF_ERROR(
        index_.append(slot.pair_index, names_[v].c_str(), f.sequence, f.timestamp_ns, relative));
  }
  if (slot.has_actuator)
    LFTRACK_RETURN_IF_ERROR(index_.append_actuator(slot.pair_index, slot.actuator_travel));
  return index_.flush();
}

void FrameArchive::run() {
  make_current_thread_best_effort();  // the slots absorb its delays; the cycle must not see them
  for (;;) {
    std::uint32_t s = 0;
    if (filled_.pop(&s)) {
      if (!write_failed_.load(std::memory_order_relaxed)) {
        if (Status st = write_slot(slots_[s]); !st.ok()) {
          first_error_ = st.message();
          write_failed_ = true;
        } else {
          ++written_;
        }
      }
      free_.push(s);
      continue;
    }
    if (stop_.load(std::memory_order_acquire) && filled_.empty()) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
}

Status FrameArchive::close() {
  if (closed_) return {};
  closed_ = true;
  stop_.store(true, std::memory_order_release);
  if (thread_.joinable()) thread_.join();
  const Status index_closed = index_.close();
  if (write_failed_) return io_error("frame archive: " + first_error_ + "; archiving stopped there");
  return index_closed;
}

}  // namespace lftrack::loop

#include "lftrack/drivers/frame_sequence.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <sstream>
#include <string_view>

namespace lftrack::drivers {
namespace fs = std::filesystem;

namespace {

constexpr const char* kHeader = "pair,detector,sequence,timestamp_ns,file";
constexpr const char* kActuatorHeader = "pair,tx_mm,ty_mm,tz_mm,rx_rad,ry_rad,rz_rad";

std::vector<std::string> split_csv(const std::string& line) {
  std::vector<std::string> fields;
  std::string field;
  std::istringstream in(line);
  while (std::getline(in, field, ',')) fields.push_back(field);
  if (!line.empty() && line.back() == ',') fields.emplace_back();
  return fields;
}

template <class T>
bool parse_integer(const std::string& text, T* value) {
  const char* end = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(text.data(), end, *value);
  return ec == std::errc() && ptr == end;
}

// Reads one of the sequence's CSV files: blank lines and '#' comments are skipped, the first
// other line must be `header`, and each further line's fields go to `row`, which returns why
// they are not a row (empty: they are). A last line without its newline is an unfinished write
// (the archive was killed): it is ignored and `note` says so.
Status read_csv_rows(const fs::path& file, const char* header,
                     const std::function<std::string(const std::vector<std::string>&)>& row,
                     std::string* note) {
  std::ifstream in(file);
  if (!in) return not_found(file.string() + ": cannot open");
  std::string line;
  bool header_seen = false;
  for (int line_number = 1; std::getline(in, line); ++line_number) {
    if (in.eof()) {
      if (!line.empty())
        *note += (note->empty() ? "" : "; ") + file.filename().string() + ": ignored line " +
                 std::to_string(line_number) + ": it has no newline (an unfinished write)";
      break;
    }
    if (!line.empty() && line.back() == '\r') line.pop_back();
    // The writer's first line names the format's version; another version is refused.
    constexpr std::string_view kVersionLine = "# lftrack frame sequence ";
    if (!header_seen && line.rfind(kVersionLine, 0) == 0 && line != std::string(kVersionLine) + "1")
      return unsupported(file.string() + ":" + std::to_string(line_number) + ": frame sequence version '" +
                         line.substr(kVersionLine.size()) + "'; this build reads version 1");
    if (line.empty() || line[0] == '#') continue;
    std::string problem;
    if (!header_seen) {
      if (line != header) problem = std::string("the header must be '") + header + "'";
      header_seen = problem.empty();
    } else {
      problem = row(split_csv(line));
    }
    if (!problem.empty())
      return corrupt_data(file.string() + ":" + std::to_string(line_number) + ": " + problem);
  }
  if (!header_seen) return corrupt_data(file.string() + ": empty (no header line)");
  return {};
}

// One index row into the sequence, or why it is not one.
std::string add_index_row(const std::vector<std::string>& f, const fs::path& directory,
                          FrameSequence* sequence) {
  std::int64_t pair = 0, timestamp_ns = 0;
  std::uint32_t counter = 0;
  if (f.size() != 5) return "5 fields expected, found " + std::to_string(f.size());
  if (!parse_integer(f[0], &pair) || pair < 0) return "pair '" + f[0] + "' is not a count";
  if (f[1].empty()) return "no detector name";
  if (!parse_integer(f[2], &counter)) return "sequence '" + f[2] + "' is not a 32-bit count";
  if (!parse_integer(f[3], &timestamp_ns)) return "timestamp_ns '" + f[3] + "' is not an integer";
  if (f[4].empty()) return "no file";
  if (timestamp_ns < 0) return "timestamp_ns " + f[3] + " is negative";
  // Frames live in the sequence's folder: no absolute path, no '..', no control characters.
  const fs::path file(f[4]);
  if (file.is_absolute()) return "file '" + f[4] + "' is absolute; frames are named inside the sequence folder";
  for (const fs::path& part : file)
    if (part == "..") return "file '" + f[4] + "' leaves the sequence folder ('..')";
  if (std::any_of(f[4].begin(), f[4].end(), [](char c) { return static_cast<unsigned char>(c) < 0x20; }))
    return "file name holds a control character";
  std::vector<SequencePair>& pairs = sequence->pairs;
  if (!pairs.empty() && pair < pairs.back().index)
    return "pair " + f[0] + " after pair " + std::to_string(pairs.back().index) + ": pairs must ascend";
  // Time runs forward between pairs, without gaps a replay at the recorded pace would sit out
  // for hours (more than kMaxSequenceGapNs after the previous pair's frames).
  if (!pairs.empty() && pair > pairs.back().index) {
    std::int64_t earliest = INT64_MAX, latest = INT64_MIN;
    for (const SequenceFrame& g : pairs.back().frames)
      if (g.present) {
        earliest = std::min(earliest, g.timestamp_ns);
        latest = std::max(latest, g.timestamp_ns);
      }
    if (timestamp_ns < earliest)
      return "timestamp_ns " + f[3] + " is before the previous pair's (" + std::to_string(earliest) +
             "): time must run forward";
    if (timestamp_ns - latest > kMaxSequenceGapNs)
      return "timestamp_ns " + f[3] + " is more than an hour after the previous pair's";
  }
  auto detector = std::find(sequence->detectors.begin(), sequence->detectors.end(), f[1]);
  if (detector == sequence->detectors.end()) {
    sequence->detectors.push_back(f[1]);
    for (SequencePair& p : pairs) p.frames.emplace_back();
    detector = sequence->detectors.end() - 1;
  }
  // Pairs ascend, so a row belongs to the last pair or starts the next.
  if (pairs.empty() || pair > pairs.back().index)
    pairs.push_back({pair, std::vector<SequenceFrame>(sequence->detectors.size())});
  SequenceFrame& frame = pairs.back().frames[std::size_t(detector - sequence->detectors.begin())];
  if (frame.present) return "detector " + f[1] + " appears twice in pair " + f[0];
  frame.present = true;
  frame.sequence = counter;
  frame.timestamp_ns = timestamp_ns;
  frame.path = (directory / f[4]).string();
  return {};
}

// One actuator.csv row into the pair it names. Refused: a pair the index lacks, a pair's second
// row, travel beyond what a couch or robot can read back (kMaxRecordedTravelMm, ...Rad).
std::string add_actuator_row(const std::vector<std::string>& f, FrameSequence* sequence) {
  std::int64_t pair = 0;
  double travel[6] = {};
  bool ok = f.size() == 7 && parse_integer(f[0], &pair);
  for (std::size_t i = 0; ok && i < 6; ++i) {
    char* end = nullptr;
    travel[i] = std::strtod(f[i + 1].c_str(), &end);
    ok = end != f[i + 1].c_str() && *end == '\0' && std::isfinite(travel[i]);
  }
  if (!ok) return "a pair number and 6 finite numbers expected";
  for (std::size_t i = 0; i < 6; ++i) {
    const double most = i < 3 ? kMaxRecordedTravelMm : kMaxRecordedTravelRad;
    if (std::abs(travel[i]) > most) {
      std::ostringstream m;
      m << "pair " << pair << ": " << (i < 3 ? "translation " : "rotation ") << travel[i]
        << (i < 3 ? " mm" : " rad") << " is beyond any couch's travel (at most " << most << ")";
      return m.str();
    }
  }
  auto it = std::lower_bound(sequence->pairs.begin(), sequence->pairs.end(), pair,
                             [](const SequencePair& p, std::int64_t index) { return p.index < index; });
  if (it == sequence->pairs.end() || it->index != pair)
    return "pair " + f[0] + " is not in the index (a read-back without its frames)";
  if (it->has_actuator) return "pair " + f[0] + " has a second read-back";
  it->has_actuator = true;
  std::copy(travel, travel + 6, it->actuator_travel);
  return {};
}

}  // namespace

Result<FrameSequence> read_frame_sequence(const fs::path& directory) {
  const fs::path index_path = directory / kSequenceIndexName;
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) return not_found(directory.string() + ": no such sequence directory");
  if (!fs::exists(index_path, ec))
    return not_found(index_path.string() + ": no index (a sequence directory holds index.csv)");
  FrameSequence sequence;
  sequence.directory = directory;
  LFTRACK_RETURN_IF_ERROR(read_csv_rows(
      index_path, kHeader, [&](const auto& f) { return add_index_row(f, directory, &sequence); },
      &sequence.note));
  if (sequence.pairs.empty()) return corrupt_data(index_path.string() + ": the index lists no frames");
  const fs::path actuator_path = directory / kSequenceActuatorName;
  if (fs::exists(actuator_path, ec)) {
    LFTRACK_RETURN_IF_ERROR(read_csv_rows(
        actuator_path, kActuatorHeader, [&](const auto& f) { return add_actuator_row(f, &sequence); },
        &sequence.note));
    sequence.has_actuator = true;
  }
  return sequence;
}

SequenceIndexWriter::~SequenceIndexWriter() {
  (void)close();
}

Status SequenceIndexWriter::open(const fs::path& directory, bool with_actuator) {
  std::error_code ec;
  fs::create_directories(directory / "frames", ec);
  if (ec) return io_error((directory / "frames").string() + ": " + ec.message());
  path_ = (directory / kSequenceIndexName).string();
  file_ = std::fopen(path_.c_str(), "w");
  if (file_ == nullptr) return io_error(path_ + ": cannot open for writing");
  if (std::fprintf(file_, "# lftrack frame sequence 1\n%s\n", kHeader) < 0)
    return io_error(path_ + ": write failed");
  actuator_path_ = (directory / kSequenceActuatorName).string();
  if (with_actuator) {
    actuator_ = std::fopen(actuator_path_.c_str(), "w");
    if (actuator_ == nullptr) return io_error(actuator_path_ + ": cannot open for writing");
    if (std::fprintf(actuator_, "%s\n", kActuatorHeader) < 0)
      return io_error(actuator_path_ + ": write failed");
  } else {
    fs::remove(actuator_path_, ec);  // not a stale one from an earlier archive
  }
  return flush();
}

Status SequenceIndexWriter::append_actuator(std::int64_t pair, const double travel[6]) {
  if (actuator_ == nullptr) return failed_precondition("sequence index: opened without an actuator file");
  if (std::fprintf(actuator_, "%lld,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g\n", static_cast<long long>(pair),
                   travel[0], travel[1], travel[2], travel[3], travel[4], travel[5]) < 0)
    return io_error(actuator_path_ + ": write failed");
  return {};
}

Status SequenceIndexWriter::append(std::int64_t pair, const char* detector, std::uint32_t sequence,
                                   std::int64_t timestamp_ns, const char* file) {
  if (file_ == nullptr) return failed_precondition("sequence index: not open");
  if (std::fprintf(file_, "%lld,%s,%u,%lld,%s\n", static_cast<long long>(pair), detector, sequence,
                   static_cast<long long>(timestamp_ns), file) < 0)
    return io_error(path_ + ": write failed");
  return {};
}

Status SequenceIndexWriter::flush() {
  if (file_ != nullptr && std::fflush(file_) != 0) return io_error(path_ + ": write failed");
  if (actuator_ != nullptr && std::fflush(actuator_) != 0) return io_error(actuator_path_ + ": write failed");
  return {};
}

Status SequenceIndexWriter::close() {
  bool ok = true;
  if (actuator_ != nullptr) ok = std::fclose(actuator_) == 0;
  actuator_ = nullptr;
  if (file_ != nullptr) ok = std::fclose(file_) == 0 && ok;
  file_ = nullptr;
  return ok ? Status{} : io_error(path_ + ": write failed");
}

}  // namespace lftrack::drivers

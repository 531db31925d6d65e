#include "lftrack/drivers/frame_sequence.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>

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

// One index row, or why it is not one.
struct IndexRow {
  std::int64_t pair = 0, timestamp_ns = 0;
  std::uint32_t sequence = 0;
  std::string detector, file;
};

std::string parse_row(const std::string& line, IndexRow* row) {
  const std::vector<std::string> f = split_csv(line);
  if (f.size() != 5) return "5 fields expected, found " + std::to_string(f.size());
  if (!parse_integer(f[0], &row->pair) || row->pair < 0) return "pair '" + f[0] + "' is not a count";
  if (f[1].empty()) return "no detector name";
  if (!parse_integer(f[2], &row->sequence)) return "sequence '" + f[2] + "' is not a 32-bit count";
  if (!parse_integer(f[3], &row->timestamp_ns)) return "timestamp_ns '" + f[3] + "' is not an integer";
  if (f[4].empty()) return "no file";
  row->detector = f[1];
  row->file = f[4];
  return {};
}

// Adds a parsed row to the sequence, or says why it does not fit.
std::string add_row(const IndexRow& row, const fs::path& directory, FrameSequence* sequence,
                    std::map<std::int64_t, std::size_t>* pair_slot) {
  if (!sequence->pairs.empty() && row.pair < sequence->pairs.back().index)
    return "pair " + std::to_string(row.pair) + " after pair " +
           std::to_string(sequence->pairs.back().index) + ": pairs must ascend";
  auto detector = std::find(sequence->detectors.begin(), sequence->detectors.end(), row.detector);
  if (detector == sequence->detectors.end()) {
    sequence->detectors.push_back(row.detector);
    for (SequencePair& p : sequence->pairs) p.frames.emplace_back();
    detector = sequence->detectors.end() - 1;
  }
  const std::size_t d = std::size_t(detector - sequence->detectors.begin());
  auto [slot, added] = pair_slot->emplace(row.pair, sequence->pairs.size());
  if (added) sequence->pairs.push_back({row.pair, std::vector<SequenceFrame>(sequence->detectors.size())});
  SequenceFrame& frame = sequence->pairs[slot->second].frames[d];
  if (frame.present) return "detector " + row.detector + " appears twice in pair " + std::to_string(row.pair);
  frame.present = true;
  frame.sequence = row.sequence;
  frame.timestamp_ns = row.timestamp_ns;
  frame.path = (directory / row.file).string();
  return {};
}

// Reads actuator.csv into the pairs it names; rows for pairs the index lacks are ignored.
Status read_actuator_file(const fs::path& file, FrameSequence* sequence) {
  std::ifstream in(file);
  if (!in) return not_found(file.string() + ": cannot open");
  std::map<std::int64_t, SequencePair*> by_index;
  for (SequencePair& p : sequence->pairs) by_index[p.index] = &p;
  std::string line;
  bool header_seen = false;
  for (int line_number = 1; std::getline(in, line); ++line_number) {
    if (in.eof()) break;  // no newline: an unfinished write, ignored like the index's
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    auto where = [&](const std::string& what) {
      return corrupt_data(file.string() + ":" + std::to_string(line_number) + ": " + what);
    };
    if (!header_seen) {
      if (line != kActuatorHeader) return where(std::string("the header must be '") + kActuatorHeader + "'");
      header_seen = true;
      continue;
    }
    const std::vector<std::string> f = split_csv(line);
    std::int64_t pair = 0;
    double travel[6] = {};
    bool ok = f.size() == 7 && parse_integer(f[0], &pair);
    for (std::size_t i = 0; ok && i < 6; ++i) {
      char* end = nullptr;
      travel[i] = std::strtod(f[i + 1].c_str(), &end);
      ok = end != f[i + 1].c_str() && *end == '\0' && std::isfinite(travel[i]);
    }
    if (!ok) return where("a pair number and 6 finite numbers expected");
    auto it = by_index.find(pair);
    if (it == by_index.end()) continue;
    it->second->has_actuator = true;
    std::copy(travel, travel + 6, it->second->actuator_travel);
  }
  if (!header_seen) return corrupt_data(file.string() + ": empty");
  sequence->has_actuator = true;
  return {};
}

}  // namespace

Result<FrameSequence> read_frame_sequence(const fs::path& directory) {
  const fs::path index_path = directory / kSequenceIndexName;
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) return not_found(directory.string() + ": no such sequence directory");
  std::ifstream in(index_path);
  if (!in) return not_found(index_path.string() + ": no index (a sequence directory holds index.csv)");
  FrameSequence sequence;
  sequence.directory = directory;
  std::map<std::int64_t, std::size_t> pair_slot;
  std::string line;
  bool header_seen = false;
  for (int line_number = 1; std::getline(in, line); ++line_number) {
    // A last line without its newline is a write the archive did not finish (a crash): ignored.
    if (in.eof()) {
      if (!line.empty())
        sequence.note =
            "ignored line " + std::to_string(line_number) + ": it has no newline (an unfinished write)";
      break;
    }
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    std::string problem;
    if (!header_seen) {
      if (line != kHeader) problem = std::string("the header must be '") + kHeader + "'";
      header_seen = problem.empty();
    } else {
      IndexRow row;
      problem = parse_row(line, &row);
      if (problem.empty()) problem = add_row(row, directory, &sequence, &pair_slot);
    }
    if (problem.empty()) continue;
    return corrupt_data(index_path.string() + ":" + std::to_string(line_number) + ": " + problem);
  }
  if (!header_seen) return corrupt_data(index_path.string() + ": empty index");
  if (sequence.pairs.empty()) return corrupt_data(index_path.string() + ": the index lists no frames");
  if (fs::exists(directory / kSequenceActuatorName, ec))
    LFTRACK_RETURN_IF_ERROR(read_actuator_file(directory / kSequenceActuatorName, &sequence));
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

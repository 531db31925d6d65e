#pragma once
// An archived frame sequence: the format the journal's frame archive writes and the replay
// source reads. A sequence is a directory holding
//
//   index.csv      # lftrack frame sequence 1
//                  pair,detector,sequence,timestamp_ns,file
//                  0,A,1,1000000000,frames/000000-A.tif
//                  0,B,1,1000000400,frames/000000-B.tif
//                  1,A,2,1100000000,frames/000001-A.tif
//                  ...
//   frames/        one 16-bit TIFF or PNG per frame (frame_files.hpp), raw counts, the whole
//                  detector
//   actuator.csv   optional: the couch's read-back travel at each pair's exposure
//                  pair,tx_mm,ty_mm,tz_mm,rx_rad,ry_rad,rz_rad
//                  (drivers/actuator.hpp's terms). With it a replay separates the patient's own
//                  motion from the corrections made while recording (recorded_actuator.hpp).
//
// `pair` groups the frames exposed together (ascending); `detector` is the scene's detector
// name; `sequence` the detector's frame counter; `timestamp_ns` the middle of the exposure on
// CLOCK_MONOTONIC (only differences matter); `file` is relative to the directory. A pair may
// lack a detector's row (that frame is then missing). Lines starting with '#' are comments; the
// writer's first, "# lftrack frame sequence 1", names the version, and another is refused.
// Index rows are refused for a negative timestamp, time running backwards between pairs, a gap
// of more than an hour, and a file outside the folder (absolute, '..', control characters).
// actuator.csv rows are refused for a pair the index lacks, a pair's second row, and travel
// beyond kMaxRecordedTravelMm / kMaxRecordedTravelRad. The replay refuses a sequence with
// frames of a detector the scene lacks.
// Every line ends with a newline: a last line without one is an unfinished write (the archive
// was killed) and is ignored, with a note.

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/tracking/status.hpp"

namespace lftrack::drivers {

inline constexpr const char* kSequenceIndexName = "index.csv";
inline constexpr const char* kSequenceActuatorName = "actuator.csv";
inline constexpr std::int64_t kMaxSequenceGapNs = 3'600'000'000'000;  // an hour between pairs
inline constexpr double kMaxRecordedTravelMm = 1000;   // no couch travels a metre
inline constexpr double kMaxRecordedTravelRad = 3.1416;  // nor turns more than half a turn

struct SequenceFrame {
  bool present = false;  // the index has a row for this detector in this pair
  std::uint32_t sequence = 0;
  std::int64_t timestamp_ns = 0;
  std::string path;  // absolute (the directory joined with the index's file)
};

struct SequencePair {
  std::int64_t index = 0;             // the index's `pair`
  std::vector<SequenceFrame> frames;  // per detector, in FrameSequence::detectors' order
  bool has_actuator = false;          // actuator.csv has a row for this pair
  double actuator_travel[6] = {};     // its read-back (mm, rad)
};

struct FrameSequence {
  std::filesystem::path directory;
  std::vector<std::string> detectors;  // in order of first appearance in the index
  std::vector<SequencePair> pairs;     // ascending `pair`
  bool has_actuator = false;           // the directory has actuator.csv
  std::string note;                    // e.g. an incomplete last line that was ignored
};

// Reads and checks the index and actuator.csv if present (not the frame files: a missing or bad frame is the
// replay's status, not a reason to refuse the sequence). Errors name the file and line.
Result<FrameSequence> read_frame_sequence(const std::filesystem::path& directory);

// Appends index rows as frames are archived. Not thread-safe; one writer thread owns it.
class SequenceIndexWriter {
 public:
  SequenceIndexWriter() = default;
  ~SequenceIndexWriter();
  SequenceIndexWriter(const SequenceIndexWriter&) = delete;
  SequenceIndexWriter& operator=(const SequenceIndexWriter&) = delete;
  // Creates `directory`/frames and a fresh index.csv (an existing index is replaced), and
  // actuator.csv when `with_actuator`.
  Status open(const std::filesystem::path& directory, bool with_actuator = false);
  // One row; `file` relative to the directory. No C++ heap allocation.
  Status append(std::int64_t pair, const char* detector, std::uint32_t sequence, std::int64_t timestamp_ns,
                const char* file);
  // The actuator's read-back travel (mm, rad) at pair `pair`.
  Status append_actuator(std::int64_t pair, const double travel[6]);
  Status flush();
  Status close();

 private:
  std::FILE* file_ = nullptr;
  std::FILE* actuator_ = nullptr;
  std::string path_, actuator_path_;
};

}  // namespace lftrack::drivers

// The files a scene names besides the CT: a couch calibration (YAML), a detector calibration
// (four-page float TIFF with JSON), a calibration phantom (YAML) and a commissioning file (YAML).
// The first input byte picks the reader.
#include "fuzz_input.hpp"
#include "lftrack/session/calibration_files.hpp"
#include "lftrack/session/commissioning_file.hpp"
#include "lftrack/session/detector_calibration_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  if (size < 1) return 0;
  switch (data[0] % 4) {
    case 0: {
      auto c = session::read_couch_calibration(fuzz::write_input("couch.yaml", data + 1, size - 1).string());
      if (!c.ok()) fuzz::expect_reason(c.status());
      break;
    }
    case 1: {
      auto c = session::load_detector_calibration(fuzz::write_input("detector.tif", data + 1, size - 1));
      if (!c.ok()) fuzz::expect_reason(c.status());
      break;
    }
    case 2: {
      auto c =
          session::load_calibration_phantom(fuzz::write_input("phantom.yaml", data + 1, size - 1).string());
      if (!c.ok()) fuzz::expect_reason(c.status());
      break;
    }
    default: {
      auto c = session::read_commissioning_file(fuzz::write_input("commissioning.yaml", data + 1, size - 1));
      if (!c.ok()) fuzz::expect_reason(c.status());
      break;
    }
  }
  return 0;
}

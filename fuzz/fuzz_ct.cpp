// CT readers (tracking/volume_io.hpp): a NIfTI-1/2 file (first byte even), or a DICOM slice
// written twice into a series folder (first byte odd), so the slice parser and the series
// checks both see it.
#include "fuzz_input.hpp"
#include "lftrack/tracking/volume_io.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  if (size < 1) return 0;
  if (data[0] % 2 == 0) {
    auto ct = tracking::read_nifti(fuzz::write_input("ct.nii", data + 1, size - 1));
    if (!ct.ok()) fuzz::expect_reason(ct.status());
    return 0;
  }
  const auto dir = fuzz::scratch() / "series";
  std::filesystem::create_directories(dir);
  for (const char* name : {"a.dcm", "b.dcm"})
    std::ofstream(dir / name, std::ios::binary | std::ios::trunc)
        .write(reinterpret_cast<const char*>(data + 1), std::streamsize(size - 1));
  auto ct = tracking::read_dicom_series(dir);
  if (!ct.ok()) fuzz::expect_reason(ct.status());
  return 0;
}

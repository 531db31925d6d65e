// DICOM RT objects a new patient is set up from (host/dicom_rt.hpp): an RT Plan (first byte even)
// or an RT Structure Set (first byte odd), read as `lftrack scene new` reads them.
#include "fuzz_input.hpp"
#include "lftrack/session/dicom_rt.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  if (size < 1) return 0;
  if (data[0] % 2 == 0) {
    auto plan = session::read_rt_plan(fuzz::write_input("plan.dcm", data + 1, size - 1), "");
    if (!plan.ok()) fuzz::expect_reason(plan.status());
    return 0;
  }
  auto set = session::read_rt_structure_set(fuzz::write_input("structures.dcm", data + 1, size - 1));
  if (!set.ok()) fuzz::expect_reason(set.status());
  return 0;
}

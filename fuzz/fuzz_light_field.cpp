// Light-field files (tracking/light_field.hpp LightField::load): header, payload size and CRC,
// sample values; a loaded field is sampled at its corners and centre.
#include "fuzz_input.hpp"
#include "lftrack/tracking/light_field.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace lftrack;
  auto field = tracking::LightField::load(fuzz::write_input("A.lf", data, size));
  if (!field.ok()) {
    fuzz::expect_reason(field.status());
    return 0;
  }
  const auto& s = (*field)->geometry().size;
  volatile float sum = (*field)->sample(0, 0, 0, 0) + (*field)->sample(s[0] - 1, s[1] - 1, s[2] - 1, s[3] - 1) +
                       (*field)->sample(s[0] / 2, s[1] / 2, s[2] / 2, s[3] / 2);
  (void)sum;
  return 0;
}

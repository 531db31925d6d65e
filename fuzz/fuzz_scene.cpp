// Scene YAML (host/scene.hpp parse_scene): every section, device keys included. Parsing only;
// the CT a scene names is not loaded.
#include "fuzz_input.hpp"
#include "lftrack/session/scene.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  auto scene = lftrack::session::parse_scene(text, "fuzz.yaml", lftrack::fuzz::scratch());
  if (!scene.ok()) lftrack::fuzz::expect_reason(scene.status());
  return 0;
}

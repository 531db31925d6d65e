#include "metaimage_reader.hpp"

#include <fstream>
#include <map>
#include <sstream>

namespace lftrack::test {

Result<tracking::CtVolume> read_metaimage_for_test(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) return not_found(file.string());
  std::map<std::string, std::string> header;
  std::string line;
  while (std::getline(in, line)) {
    const auto eq = line.find('=');
    if (eq == std::string::npos) continue;
    std::string key = line.substr(0, eq), value = line.substr(eq + 1);
    key.erase(key.find_last_not_of(' ') + 1);
    value.erase(0, value.find_first_not_of(' '));
    header[key] = value;
    if (key == "ElementDataFile") break;
  }
  if (header["ElementDataFile"] != "LOCAL" || header["CompressedData"] == "True") {
    return unsupported("test reader handles only uncompressed LOCAL data");
  }
  tracking::CtVolume v;
  std::istringstream(header["DimSize"]) >> v.geometry.size.x() >> v.geometry.size.y() >> v.geometry.size.z();
  std::istringstream(header["ElementSpacing"]) >> v.geometry.spacing_mm.x() >> v.geometry.spacing_mm.y() >>
      v.geometry.spacing_mm.z();
  std::istringstream(header["Offset"]) >> v.geometry.origin_mm.x() >> v.geometry.origin_mm.y() >>
      v.geometry.origin_mm.z();
  std::istringstream tm(header["TransformMatrix"]);
  for (int axis = 0; axis < 3; ++axis)
    for (int c = 0; c < 3; ++c) tm >> v.geometry.direction(c, axis);
  const auto n = static_cast<std::size_t>(v.geometry.voxel_count());
  v.values.resize(n);
  if (header["ElementType"] == "MET_FLOAT") {
    in.read(reinterpret_cast<char*>(v.values.data()), static_cast<std::streamsize>(n * 4));
  } else if (header["ElementType"] == "MET_SHORT") {
    std::vector<std::int16_t> raw(n);
    in.read(reinterpret_cast<char*>(raw.data()), static_cast<std::streamsize>(n * 2));
    for (std::size_t i = 0; i < n; ++i) v.values[i] = raw[i];
  } else {
    return unsupported("element type " + header["ElementType"]);
  }
  if (!in) return corrupt_data("truncated");
  return v;
}

}  // namespace lftrack::test

#pragma once
// A minimal MetaImage (.mha, uncompressed, MET_FLOAT or MET_SHORT) reader for reading peers'
// output in tests. Not product code: lftrack itself only writes MetaImage.

#include <filesystem>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::test {

Result<tracking::CtVolume> read_metaimage_for_test(const std::filesystem::path& file);

}  // namespace lftrack::test

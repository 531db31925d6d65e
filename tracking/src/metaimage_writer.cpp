// MetaImage (.mha) writer: a text header and raw float32 voxels in one file. Written by hand
// because it is a dozen lines and pulling in ITK for it would dwarf the rest of lftrack.

#include <fstream>

#include "lftrack/tracking/volume_io.hpp"

namespace lftrack::tracking {

template <class Unit>
Status write_metaimage(const ScalarVolume<Unit>& volume, const std::filesystem::path& file) {
  const VolumeGeometry& g = volume.geometry;
  if (volume.values.size() != static_cast<std::size_t>(g.voxel_count())) {
    return invalid_argument("volume holds " + std::to_string(volume.values.size()) +
                            " values, geometry says " + std::to_string(g.voxel_count()));
  }
  std::ofstream out(file, std::ios::binary);
  if (!out) return io_error(file.string() + ": cannot open for writing");
  out.precision(17);
  out << "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
      << "CompressedData = False\n";
  // MetaImage's TransformMatrix is row-major with the axis vectors as rows.
  out << "TransformMatrix =";
  for (int axis = 0; axis < 3; ++axis)
    for (int c = 0; c < 3; ++c) out << ' ' << g.direction(c, axis);
  out << "\nOffset = " << g.origin_mm.x() << ' ' << g.origin_mm.y() << ' ' << g.origin_mm.z()
      << "\nAnatomicalOrientation = RAI\n"
      << "ElementSpacing = " << g.spacing_mm.x() << ' ' << g.spacing_mm.y() << ' ' << g.spacing_mm.z()
      << "\nDimSize = " << g.size.x() << ' ' << g.size.y() << ' ' << g.size.z()
      << "\nElementType = MET_FLOAT\nElementDataFile = LOCAL\n";
  out.write(reinterpret_cast<const char*>(volume.values.data()),
            static_cast<std::streamsize>(volume.values.size() * sizeof(float)));
  if (!out) return io_error(file.string() + ": write failed");
  return {};
}

template Status write_metaimage(const CtVolume&, const std::filesystem::path&);
template Status write_metaimage(const MuVolume&, const std::filesystem::path&);

}  // namespace lftrack::tracking

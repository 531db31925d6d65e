#pragma once
// Reading CT volumes from disk into the CT frame (patient LPS, mm), and writing them for peers.
//
// Every reader either returns a complete, validated volume or a Status whose message names the
// file and the problem. No reader returns a partial volume.

#include <filesystem>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::tracking {

// A folder holding one DICOM CT series, one slice per file. Slices are ordered by their position
// along the slice normal (not by file name or InstanceNumber); RescaleSlope/Intercept give HU.
// Rejects: mixed series, mixed sizes, orientations or pixel spacings, duplicated, missing or
// unevenly spaced slices, tilted stacks, non-CT modality, multi-frame objects, and pixel data the
// library cannot decode.
Result<CtVolume> read_dicom_series(const std::filesystem::path& folder);

// A NIfTI-1 or NIfTI-2 file (.nii or .nii.gz). Orientation from the sform if its code is set,
// else the qform, else pixdim alone (with a warning); NIfTI's RAS world is turned into LPS.
// Values are taken as HU after scl_slope/scl_inter.
Result<CtVolume> read_nifti(const std::filesystem::path& file);

// Dispatches on what `path` is: a folder -> DICOM series; *.nii / *.nii.gz -> NIfTI.
Result<CtVolume> read_ct(const std::filesystem::path& path);

// Writes a MetaImage (.mha, float32, LPS with direction) for peers such as plastimatch.
template <class Unit>
Status write_metaimage(const ScalarVolume<Unit>& volume, const std::filesystem::path& file);

}  // namespace lftrack::tracking

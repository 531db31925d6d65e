#pragma once
// Reading CT volumes from disk into the CT frame (patient LPS, mm), and writing them for peers.
//
// Every reader either returns a complete, validated volume or a Status whose message names the
// file and the problem. No reader returns a partial volume.

#include <filesystem>

#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"

namespace lftrack::tracking {

// CT numbers a reader accepts: finite and within [kLowestPlausibleHu, kHighestPlausibleHu]. Air
// is -1000 HU; scanners pad outside the field of view with values down to about -34000 (raw
// -32768 with intercept -1024); dense metal in extended-range CT reaches about +30000. Anything
// beyond is a broken rescale (a slope of 1e38) or a damaged file, never anatomy, and is refused
// with the slice and pixel (DICOM) or voxel (NIfTI) named.
inline constexpr double kLowestPlausibleHu = -40000;
inline constexpr double kHighestPlausibleHu = 100000;
// A rescale slope is refused outside [kMinRescaleSlope, kMaxRescaleSlope] (DICOM; NIfTI's
// scl_slope 0 means no scaling), an intercept beyond +-kMaxRescaleIntercept.
inline constexpr double kMinRescaleSlope = 1e-3;
inline constexpr double kMaxRescaleSlope = 1000;
inline constexpr double kMaxRescaleIntercept = 100000;

// A folder holding one DICOM CT series, one slice per file. Slices are ordered by their position
// along the slice normal (not by file name or InstanceNumber); RescaleSlope/Intercept give HU.
// Rejects: mixed series, mixed sizes, orientations or pixel spacings, duplicated, missing or
// unevenly spaced slices, tilted stacks, non-CT modality, multi-frame objects, pixel data the
// library cannot decode, a missing, non-numeric or out-of-range rescale slope or intercept
// (above), stored values beyond
// BitsStored, and CT numbers outside the plausible range.
Result<CtVolume> read_dicom_series(const std::filesystem::path& folder);

// A NIfTI-1 or NIfTI-2 file (.nii or .nii.gz). Orientation from the sform if its code is set,
// else the qform; a file with neither is refused (its orientation, left from right included, is
// unknown). NIfTI's RAS world is turned into LPS. Values are taken as HU after
// scl_slope/scl_inter (slope 0: no scaling, as the standard says; a negative or non-finite slope
// or intercept is refused); NaN, infinite or implausible values are refused with the voxel named.
// A .nii.gz is read to the end of its gzip stream, so a damaged stream (CRC) is refused even
// where the volume ends before it.
Result<CtVolume> read_nifti(const std::filesystem::path& file);

// Dispatches on what `path` is: a folder -> DICOM series; *.nii / *.nii.gz -> NIfTI.
Result<CtVolume> read_ct(const std::filesystem::path& path);

// Writes a MetaImage (.mha, float32, LPS with direction) for peers such as plastimatch.
template <class Unit>
Status write_metaimage(const ScalarVolume<Unit>& volume, const std::filesystem::path& file);

}  // namespace lftrack::tracking

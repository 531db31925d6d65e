#pragma once
// plastimatch ("plastimatch drr") as an independent reference DRR generator.
//
// Geometry mapping from an XrayView expressed in the CT frame (the frame of the volume file):
//   --nrm  = the detector normal, pointing towards the source (plastimatch: target -> camera)
//   --sad  = any distance d along it; plastimatch puts the camera at isocentre + d * nrm, so
//   -o     = source - d * nrm is the "isocentre" that makes the camera our source
//   --sid  = source-to-detector-plane distance
//   --vup  = -row_axis (towards row 0, the top row)
//   -r     = "cols rows", -z = "cols*pitch_col rows*pitch_row" mm, -c = "col row" of the
//            principal point (foot of the source's perpendicular) in pixel coordinates.
//            plastimatch's help says "row col" for these three, but it uses the first number
//            along the image's width (columns) and the second along its height; the pairing
//            is pinned by the tests in tests/studies/plastimatch_peer_test.cpp.
// plastimatch's column direction is vup x nrm, which is our col_axis for an orthonormal
// right-handed detector (col_axis x row_axis = -nrm); views with the other handedness are
// refused. Its PFM output stores row 0 first (not bottom-up as PFM specifies), and its values
// are line integrals in cm (mu[1/mm] * mm / 10): the reader here undoes both.
//
// Known difference: plastimatch clips rays to the box spanned by the outermost voxel centres,
// lftrack to the voxels' full extent (half a voxel further on every side). The two agree exactly
// where the volume's boundary voxels are air, which is the usual case for a CT; a body cut off
// at the first or last slice makes plastimatch's line integral shorter by half a slice there.

#include <filesystem>
#include <string>
#include <vector>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::studies {

// True if `plastimatch` is on PATH and runs.
bool plastimatch_available();

// The argument list (argv[0] = "plastimatch") that renders `view_ct` from `volume_mha`, a
// MetaImage of attenuation values (1/mm; no HU conversion), into `output_prefix`.
Result<std::vector<std::string>> plastimatch_drr_arguments(const tracking::XrayView& view_ct,
                                                           const std::filesystem::path& volume_mha,
                                                           const std::string& output_prefix);

struct PeerDrr {
  tracking::Image<float> line_integrals;  // mu * mm, row 0 at the top, as our renderers give
  double reported_render_s = 0;           // plastimatch's own "Total time" (no volume loading)
  double wall_s = 0;                      // the whole process, volume loading included
};

// Runs plastimatch in `work_dir` and reads its result back.
// `threads` > 0 limits plastimatch's OpenMP threads (OMP_NUM_THREADS).
Result<PeerDrr> run_plastimatch_drr(const tracking::XrayView& view_ct,
                                    const std::filesystem::path& volume_mha,
                                    const std::filesystem::path& work_dir, int threads = 0);

// Runs argv (argv[0] looked up on PATH) with `extra_env` ("NAME=value") added, captures stdout and stderr into `output`, and returns
// the exit status as a Status.
Status run_process(const std::vector<std::string>& argv, std::string* output,
                   const std::vector<std::string>& extra_env = {});

}  // namespace lftrack::studies

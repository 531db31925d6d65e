#pragma once
// Registration of a prepared scene's frames: the scene's renderer (light fields loaded, or built
// and cached when missing), the registration set-up from its views and ROI windows,
// preprocessing, the fiducial term, and TRE in the scene's box. (Synthetic frames of a scene:
// lftrack/sim_devices/scene_sim_frames.hpp.)

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/calib/triangulation.hpp"
#include "lftrack/loop/view_agreement.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/registration.hpp"
#include "lftrack/tracking/target_error.hpp"

namespace lftrack::session {

// The renderer `name` for the scene ("lightfield": the fields in `light_field_dir` (empty: the
// scene's default folder); a missing or stale file is rebuilt, saved, and said so).
Result<std::shared_ptr<const tracking::DrrRenderer>> make_scene_renderer(
    const PreparedScene& scene, const std::string& name, const std::filesystem::path& light_field_dir,
    tracking::ThreadPool* pool);

// A Registration over the scene's ROI windows with the scene's (or the given) measure. With
// `detector_binning` b > 1 every image level, the originals included, is also offered binned b
// times more (a plan whose passes' bins are multiplied by b then registers coarser images).
Result<std::unique_ptr<tracking::Registration>> make_scene_registration(
    const PreparedScene& scene, std::shared_ptr<const tracking::DrrRenderer> renderer,
    const RegistrationSpec& spec, tracking::ThreadPool* pool, int detector_binning = 1);

// The verdict's view check for the scene (view_agreement.hpp): each view's registration alone, as
// make_scene_registration() sets it up, with `plan` (the scene's tracking plan).
Result<std::unique_ptr<loop::ViewAgreement>> make_scene_view_agreement(
    const PreparedScene& scene, std::shared_ptr<const tracking::DrrRenderer> renderer,
    const RegistrationSpec& spec, const tracking::RegistrationPlan& plan, tracking::ThreadPool* pool);

// One frame per detector, preprocessed to the ROI windows.
struct SceneFrames {
  std::vector<tracking::Image<float>> line_integral;
  std::vector<tracking::Image<unsigned char>> valid;
  std::vector<tracking::ImageView<const float>> frames() const;
  std::vector<tracking::ImageView<const unsigned char>> masks() const;
};

// Raw frames (whole detectors) -> preprocessed ROI windows, each detector's with its own
// correction, or all with one.
Result<SceneFrames> preprocess_scene_frames(const PreparedScene& scene,
                                            const std::vector<tracking::Image<std::uint16_t>>& raw,
                                            const std::vector<tracking::DetectorCorrection>& corrections);
Result<SceneFrames> preprocess_scene_frames(const PreparedScene& scene,
                                            const std::vector<tracking::Image<std::uint16_t>>& raw,
                                            const tracking::DetectorCorrection& correction);

// Per detector, how raw counts become line integrals, as the loop and `lftrack register` correct
// them: the scene's detector calibration file where it names one (refused if it does not load or
// is for another size); otherwise, for frames the simulator made (`simulated`) or replayed and
// simulated detectors, the simulator's detector model. A device detector's frames without a
// calibration are refused.
Result<std::vector<tracking::DetectorCorrection>> scene_detector_corrections(const PreparedScene& scene,
                                                                             bool simulated);

// Finds the scene's first fiducial in every frame near where `start` projects it, triangulates
// the first two views, and returns the hybrid term (paper 2) with its triangulation gap.
struct LocatedFiducial {
  tracking::FiducialTerm term;
  double gap_mm = 0;
  std::vector<Eigen::Vector2d> pixels;  // detector (col, row) per view
};
Result<LocatedFiducial> locate_fiducial(const PreparedScene& scene, const SceneFrames& frames,
                                        const tracking::Pose& start_T_room_from_ct, double gamma_per_mm,
                                        double search_radius_mm = 25);

// A pose given as the delta (tx ty tz [mm], rotation vector [deg]) from the nominal pose about
// the registration origin, as typed on command lines.
Result<tracking::Pose> pose_from_nominal_delta(const PreparedScene& scene, const std::vector<double>& delta);
// The same 6 numbers of a pose.
std::vector<double> nominal_delta_of(const PreparedScene& scene, const tracking::Pose& T_room_from_ct);

// The pose gold moved along `direction` (a delta 6-vector) by the scale at which its mean TRE
// against gold is `target_mm` (bisection; TRE grows with the scale).
tracking::Pose pose_at_tre(const PreparedScene& scene, const tracking::Pose& gold_T_room_from_ct,
                           const tracking::Vector6d& direction, double target_mm);

// TRE over the scene's box (a cube of tracking.tre_box_mm at the registration origin).
tracking::Tre scene_tre(const PreparedScene& scene, const tracking::Pose& T_room_from_ct,
                        const tracking::Pose& gold_T_room_from_ct);

}  // namespace lftrack::session

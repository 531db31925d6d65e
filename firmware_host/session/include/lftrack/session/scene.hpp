#pragma once
// A scene declares exactly what exists in one treatment set-up (DESIGN.md, "Scene files"):
// the CT and its ROI, the registration origin, the nominal pose, the detectors and the pose
// envelope. Only what a scene names is built.
//
// Loading is two steps: load_scene() parses and validates the YAML (fails with file:line:col and
// a reason); prepare_scene() then reads the CT and resolves everything that depends on it.

#include <Eigen/Core>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/drivers/actuator_dynamics.hpp"
#include "lftrack/drivers/can_robot.hpp"
#include "lftrack/drivers/modbus_couch.hpp"
#include "lftrack/loop/loop_spec.hpp"
#include "lftrack/loop/safety_gate.hpp"
#include "lftrack/sim_spec/breathing_surrogate_spec.hpp"
#include "lftrack/sim_spec/patient_motion_spec.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/light_field.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::tracking {
class ThreadPool;
}

namespace lftrack::session {

inline constexpr const char* kBuiltinPhantom = "builtin:phantom";
inline constexpr const char* kBuiltinPhantomClinical = "builtin:phantom-clinical";

struct CtSpec {
  std::string path;  // "builtin:phantom", or a DICOM folder / NIfTI file (absolute)
  std::uint64_t phantom_seed = 1;
  double mu_water_per_mm = tracking::kDefaultMuWaterPerMm;
  bool is_builtin_phantom() const { return path == kBuiltinPhantom; }
};

// roi.mask: the similarity measures look only at the target's neighbourhood in each view (the
// target's contours from an RT Structure Set of this CT, projected at the nominal pose and grown
// by margin_mm on the detector, scaled to the isocentre), not at the whole ROI window.
struct RoiMaskSpec {
  std::string rtstruct;  // the structure set, resolved against the scene's folder
  std::string target;    // a structure's name
  double margin_mm = 10;
};

struct RoiSpec {
  std::optional<Eigen::Vector3d> centre_ct_mm;  // unset: the phantom's target vertebra
  Eigen::Vector3d size_mm{64, 64, 40};
  std::optional<RoiMaskSpec> mask;
};

// detectors[i].frames: where a detector's frames come from, with the device's settings
// (docs/scenes.md, "Devices"). Every detector of a scene takes its frames from one kind: a pair
// comes from one source.
//   sim     the simulator renders them (lftrack sim, lftrack run on a simulated room)
//   v4l2    a Video4Linux2 device: `device` (best a /dev/v4l/by-path or by-id link), `buffers`,
//           an external trigger as a control id and value (0: free-running)
//   gige    a GigE Vision camera through Aravis: `camera` (device id, serial or IP address),
//           `buffers`, `packet_timeout_ms`, `id` (the device id it must answer with),
//           `exposure_clock` (device: the camera's timestamp, mapped by latches; arrival: the
//           frame's arrival on the host)
//   replay  an archived sequence folder (`sequence`; the same for every detector), which `run`
//           tracks and reports (nothing sent, no beam; a modbus or can actuator is refused at
//           load: archived frames cannot move a patient); `lftrack replay --sequence` needs none
struct DetectorFramesSpec {
  std::string kind = "sim";
  std::string device;  // v4l2: device path; gige: the camera
  int buffers = 4;
  std::uint32_t trigger_control_id = 0;  // v4l2
  std::int32_t trigger_value = 1;        // v4l2
  double packet_timeout_ms = 20;         // gige
  bool exposure_by_arrival = false;      // gige `exposure_clock: arrival` (default device)
  std::string sequence;                  // replay (absolute, or empty)
  // gige `id`: the device id (serial number) the camera must answer with; the start-up checks
  // refuse another. Empty: a served twin must answer as served_twin_id(name), another camera
  // is reported unchecked.
  std::string id;
};

struct DetectorSpec {
  tracking::XrayView view;  // room frame
  DetectorFramesSpec frames;
  int bits = 12;  // detector bit depth
  // detectors[i].calibration: a detector calibration file (`lftrack calibrate detector`;
  // absolute, or empty). Frames from devices are corrected with it; simulated frames use the
  // simulator's detector model. `calibration: simulator` says so for a device too (the device
  // is the simulator's twin, e.g. `lftrack serve detectors`): the start-up checks warn where the
  // device answered as the served twin of this detector, and refuse it on any other device.
  std::string calibration_file;
  bool simulator_calibration = false;
};

using PoseEnvelope = tracking::PoseEnvelope;  // +-translation_mm, +-rotation_deg per axis

// Metal fiducial markers (e.g. implanted steel tacks), CT frame. With `insert` the simulator
// places them as steel spheres into the CT (clipped at the CT's top HU value, as a scanner
// would) and into the anatomy that synthetic frames are rendered from.
struct FiducialSpec {
  std::vector<Eigen::Vector3d> positions_ct_mm;
  double radius_mm = 1.0;
  bool insert = false;
};

// tracking: how frames are registered.
struct RegistrationSpec {
  std::string similarity = "mi";
  int histogram_bins = 64;
  std::string plan = "papers";  // registration_plan_names()
  double gamma_per_mm = 0.05;   // hybrid measure's weight of the fiducial distance (paper 2)
  double tre_box_mm = 40;       // edge of the TRE cube at the registration origin
  // tracking.single_view: a scene with one detector registers only when it says so; depth along
  // that view's central ray is then unobservable (registration_verdict.hpp).
  bool single_view = false;
};

// sim: synthetic detector frames.
struct SimFrameSpec {
  // sim.exposure: how the simulated detectors are exposed. "aec" (default), as an automatic
  // exposure control does: one dose for the scene, set so that the ROI of the view that attenuates
  // most reads `aec_level` of the detector's full scale at the nominal pose (the open field beyond
  // the patient then saturates, as on a real panel). "fixed": photons_per_pixel in the open field.
  std::string exposure = "aec";
  double aec_level = 0.1;
  // The detector's conversion: this many photons per pixel read 85 % of its full scale (the open
  // field's level under `fixed`, which is then the dose).
  double photons_per_pixel = 10000;
  double detector_blur_px = 0.5;
  // What renders the simulated loop's frames: "siddon" (exact, about 30 ms per view of a 512 x 512
  // detector's ROI on one core) or "lightfield" (a separate field of `light_field` resolution,
  // built from the anatomy with its markers, under 1 ms per view; for real-time runs on few cores).
  std::string renderer = "siddon";
  tracking::LightFieldSpec light_field;
  std::uint64_t seed = 1;  // noise of the simulated loop's frames
  // sim.physics: what the frames carry beyond the planning CT's ideal DRR (a preset name, or a
  // mapping: `preset` and per-part overrides; docs/scenes.md "Imaging physics").
  sim_spec::XrayPhysicsSpec physics;
  std::string physics_name = "ideal";  // the preset the physics started from ("custom" once changed)
  // sim.couch_link: a served couch's room link (`lftrack serve couch|robot --room FILE`; absolute
  // or empty). Simulated frames then show the patient where that couch has moved them, so
  // `lftrack run` can drive a couch in another process from simulated detectors.
  std::string couch_link;
};

// Where a couch is mounted in the room: the rotation vector of its axes (room from couch) and
// its rotation centre (room frame; unset: the registration origin).
struct CouchMountingSpec {
  Eigen::Vector3d rotation_rad = Eigen::Vector3d::Zero();
  std::optional<Eigen::Vector3d> centre_room_mm;
};

// actuator: what moves the patient. "none" tracks and reports; "virtual" is the simulator's
// couch. Every type that moves has its dynamics (latency, speeds, travel): what the host
// assumes of it (drivers/actuator_dynamics.hpp).
//   mounting:     (sim) how the virtual couch is really mounted; unset: the ideal couch
//   calibration:  a couch calibration file (`lftrack calibrate couch`); the loop converts its
//                 corrections through it. Unset: the couch's axes are assumed to be the room's,
//                 rotating about the registration origin.
//   type:         none, virtual, modbus (a couch: tcp {host, port} or rtu {device, baud, parity,
//                 data_bits, stop_bits}; unit_id; response_timeout_ms), can (a robot: an
//                 `interface` such as can0, or a `bridge` socket path to a CAN bridge process
//                 such as `lftrack serve robot`; node_id; heartbeat_timeout_ms)
struct ActuatorSpec {
  std::string type = "none";
  drivers::ActuatorDynamics dynamics;  // modbus, can, virtual (the simulator's couch moves so)
  drivers::ModbusCouchOptions modbus;  // modbus
  drivers::CanRobotOptions can;        // can (can.bridge_path set: through a bridge)
  std::optional<CouchMountingSpec> mounting;
  std::string calibration_file;                  // absolute, or empty
  std::optional<CouchMountingSpec> calibration;  // read from calibration_file at load
};

// motion: the simulated patient (sim only): where they lie at the start (set-up error, delta from
// the nominal pose) and how they move from there.
struct MotionSpec {
  tracking::Vector6d setup_error = tracking::Vector6d::Zero();  // mm, rad
  sim_spec::PatientMotionSpec motion;
};

// The registration verdict's checks beyond its floors (registration_verdict.hpp), from safety's
// keys. Measured on the shipped scenes' commissioning cases (BENCHMARKS.md, "One verdict").
struct VerdictChecksSpec {
  // safety.envelope_edge_mm / _deg: results this close to the envelope's limits are refused;
  // unset, the outer kEnvelopeEdgeFraction of the envelope's translation_mm (0.5 mm of 10 mm:
  // commissioning's good cases reach 0.9 of it). The translation band refused 20 wrong results
  // the default floors accepted across six scenes and no right one; a rotation band refused
  // right results the clinical presets bias outwards.
  static constexpr double kEnvelopeEdgeFraction = 0.05;
  double envelope_edge_mm = 0.5;
  double envelope_edge_deg = 0;
  // safety.max_view_shift_mm: the most a view registered alone from the result may move the
  // target across it; 0: not checked.
  double max_view_shift_mm = 1.0;
  // safety.view_check_every: the view check runs at every alignment and on every Nth tracking
  // cycle (0: alignments only): two single-view registrations cost about one registration.
  int view_check_every = 10;
};

// surrogate: the breathing surrogate that tracking.imaging `model` follows between X-ray pairs
// (imaging_on_demand.hpp). Its watch's limits (rate_hz, stale_ms, jump_mm, freeze_s) are the loop's
// (LoopSpec::imaging.surrogate).
struct SurrogateSpec {
  // "" (none), "sim" (the simulated patient's chest marker: lftrack sim only) or "igtl" (an optical
  // tracker's positions over OpenIGTLink).
  std::string source;
  // sim: the marker's travel, lead, drift and noise; its period is motion.breathing's, its seed
  // sim.seed's. With igtl in lftrack sim, the marker the tracker's twin serves (sim/tracker_twin.hpp).
  sim_spec::BreathingSurrogateSpec sim;
  // igtl: the tracker's OpenIGTLink server, and the device name whose TRANSFORM or POSITION
  // messages carry the marker ("" any); the marker's displacement along `axis` (room frame, unit).
  std::string igtl_host = "127.0.0.1";
  int igtl_port = 18944;
  std::string igtl_device;
  Eigen::Vector3d igtl_axis = Eigen::Vector3d::UnitZ();
};

// tracking.imaging.technique: each view's exposure per pair, for the imaging dose (scene_imaging_dose.hpp).
struct ImagingTechniqueSpec {
  double kvp = 120;
  double mas = 2.0;
};

struct Scene {
  std::string source;  // the scene file, or "builtin:phantom"
  // Where sections checked after parsing were written ("ct", "roi"): "FILE:LINE:COLUMN", so an
  // error found once the CT is loaded still names the scene's line. where("ct") falls back to
  // the source.
  std::map<std::string, std::string> lines;
  std::string where(const std::string& section) const {
    const auto it = lines.find(section);
    return it != lines.end() ? it->second : source;
  }
  std::string name;
  std::string room_file;  // `room:`, resolved: the room's views, detectors and devices came from it ("" none)
  CtSpec ct;
  RoiSpec roi;
  std::optional<Eigen::Vector3d> registration_origin_ct_mm;  // unset: ROI centre (phantom: body centre)
  std::optional<tracking::Pose> nominal_T_room_from_ct;      // unset: origin onto the isocentre
  std::vector<DetectorSpec> detectors;
  PoseEnvelope envelope;
  std::string renderer = "siddon";
  double octree_pivot = 0;               // tracking.octree_pivot: the octree renderer's P in [0, 1]
  tracking::LightFieldSpec light_field;  // tracking.light_field: resolution, storage, codebook, margin
  RegistrationSpec registration;         // tracking: similarity, plan, ...
  // Which plans the scene does not name, and why they are what they are (scene_default_plans.hpp:
  // the robust plans unless the frames are ideal).
  struct DefaultedPlans {
    bool plan = false, align = false, track = false;  // tracking.plan, loop.align_plan, loop.track_plan
    std::string because;                              // empty when the scene names all three
  } defaulted_plans;
  FiducialSpec fiducials;
  SimFrameSpec sim;
  loop::LoopSpec loop;
  loop::SafetyLimits safety;
  // Whether the scene names safety.min_similarity (in its tracking.similarity's units); without
  // it the registration verdict takes the measure's default floor (registration_verdict.hpp).
  bool min_similarity_given = false;
  // safety.commissioning: the scene's commissioning file (commissioning_file.hpp; absolute), whose
  // floors the verdict takes; empty: the measure's default floors, the scene not commissioned.
  std::string commissioning_file;
  VerdictChecksSpec verdict_checks;  // safety's keys for the verdict's own checks
  // safety.require_daily_qa: `lftrack run` refuses to start unless today's daily QA of the room
  // passed (lftrack qa daily); false: it warns.
  bool require_daily_qa = false;
  ActuatorSpec actuator;
  MotionSpec motion;
  SurrogateSpec surrogate;
  ImagingTechniqueSpec technique;  // tracking.imaging.technique
};

// Parses a scene from YAML text; `source_name` is used in messages ("file.yaml:12:5: ...") and
// `base_dir` resolves relative CT paths.
Result<Scene> parse_scene(const std::string& yaml_text, const std::string& source_name,
                          const std::filesystem::path& base_dir);
// Loads "builtin:phantom" or a scene file.
Result<Scene> load_scene(const std::string& file_or_builtin);

// A detector name, which becomes part of file names (its light field, its archived frames, its
// calibration): 1 to 64 letters, digits, '_', '-' or '.', not starting with '.'. The one rule of
// scenes and `calibrate detector --detector`.
bool is_detector_name(const std::string& name);
// The YAML text of a built-in scene, or nothing.
std::optional<std::string> builtin_scene_text(const std::string& name);

// The simulated detectors' exposure, the same for every frame of a scene and for every detector
// (an AEC sets one technique for the pair, through the view that attenuates most).
struct SimExposure {
  double photons_per_pixel = 10000;   // in the open field, per pixel and frame
  double open_field_fraction = 0.85;  // the open field's counts / full scale; above 1 it saturates
  // What the AEC measured: each view's ROI mean at the nominal pose (the primary, without noise)
  // as a fraction of full scale at this exposure; empty under `fixed`.
  std::vector<double> roi_mean_of_full_scale;
};

// A scene with its CT read and everything that depends on the CT resolved.
struct PreparedScene {
  Scene scene;
  std::shared_ptr<const tracking::CtVolume> ct;
  std::shared_ptr<const tracking::MuVolume> mu;
  // The anatomy synthetic frames are rendered from: `mu`, with steel markers where the scene
  // inserts fiducials (the CT shows them clipped).
  std::shared_ptr<const tracking::MuVolume> world_mu;
  Eigen::Vector3d registration_origin_ct_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d roi_centre_ct_mm = Eigen::Vector3d::Zero();
  // Nothing named the ROI centre (a CT given with --ct to a scene without roi.centre_mm): it is
  // the volume's centre, and so is the registration origin unless the scene names that.
  bool roi_centre_is_volume_centre = false;
  tracking::Pose nominal_T_room_from_ct = tracking::Pose::Identity();
  std::vector<tracking::PixelWindow> roi_windows;  // per detector: the ROI's projection
  // Per detector, with roi.mask: where in its ROI window the measures look (1), the window's
  // size (roi_mask.hpp); empty without roi.mask.
  std::vector<tracking::Image<unsigned char>> roi_masks;
  SimExposure exposure;  // the simulated detectors' dose (sim.exposure), set once for the scene

  Eigen::Vector3d registration_origin_room_mm() const {
    return nominal_T_room_from_ct * registration_origin_ct_mm;
  }
  // Index of the detector called `name`, or -1.
  int detector_index(const std::string& name) const;
  // What a light field for detector `index` must cover.
  tracking::LightFieldPlanInput light_field_plan(int index) const;
};

// Light-field files (light_field_cache.cpp). A field depends on the attenuation volume it
// samples, its plan (the view, ROI window, nominal pose, registration origin, envelope,
// resolution, margin, integration and slice step) and its storage, and its file is named after
// all of them: DIR/<view>-<key>.lf, the key 12 hex digits of their hash. Fields of scenes or
// settings that differ never share a file: one folder (--lf-dir) keeps the fields of any number
// of scenes, a field is never replaced by another's, and a stale field is left where it is (its
// successor is written beside it). A file named <view>.lf, as lftrack named fields before, is
// used where it is the field asked for.

// The default folder of a scene's fields: out/lightfields/<scene file stem>
// (out/lightfields/builtin-phantom for the built-in scene), relative to the working folder.
std::filesystem::path default_light_field_dir(const Scene& scene);
// The file of each view's field of `spec` (null: the scene's tracking.light_field) over `mu`
// (null: the scene's CT) in `dir`, in the scene's order of detectors.
std::vector<std::filesystem::path> light_field_files(const PreparedScene& scene,
                                                     const std::filesystem::path& dir,
                                                     const tracking::MuVolume* mu = nullptr,
                                                     const tracking::LightFieldSpec* spec = nullptr);
// Builds every view's field as `spec` says, on `pool`, with a progress bar per view on stderr,
// from `mu` (null: the scene's CT).
Result<std::vector<std::shared_ptr<const tracking::LightField>>> build_light_fields(
    const PreparedScene& scene, const tracking::LightFieldSpec& spec, tracking::ThreadPool* pool,
    const tracking::MuVolume* mu = nullptr);
// Loads every view's field of `spec` (null: the scene's tracking.light_field) over `mu` (null:
// the scene's CT) from `dir`. A field not there is refused (not found), naming every setting in
// which the newest other field of that view in `dir` differs; a file that fails its checks is
// refused with the reason.
Result<std::vector<std::shared_ptr<const tracking::LightField>>> load_light_fields(
    const PreparedScene& scene, const std::filesystem::path& dir, const tracking::MuVolume* mu = nullptr,
    const tracking::LightFieldSpec* spec = nullptr);
// What load_or_build_light_fields did, per view.
struct LightFieldCacheReport {
  std::vector<std::filesystem::path> files;
  std::vector<bool> built;  // built now; else loaded (up to date)
  Status saved;             // the first save that failed (that field is used from memory)
};
// The fields of `spec` over `mu` from `dir`; those missing or unusable are built (as float, then
// converted), saved beside any other and said so. A failed save is a warning (and in `report`).
Result<std::vector<std::shared_ptr<const tracking::LightField>>> load_or_build_light_fields(
    const PreparedScene& scene, const tracking::MuVolume& mu, const tracking::LightFieldSpec& spec,
    const std::filesystem::path& dir, tracking::ThreadPool* pool, LightFieldCacheReport* report = nullptr);

// Reads the CT (or generates the phantom), converts it to attenuation, and resolves the ROI,
// the registration origin, the nominal pose and each detector's ROI window. `ct_override`
// replaces the scene's CT path when non-empty.
Result<PreparedScene> prepare_scene(const Scene& scene, const std::string& ct_override,
                                    tracking::ThreadPool* pool);

}  // namespace lftrack::session

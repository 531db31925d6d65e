#pragma once
// Light fields (attenuation fields) for fast DRRs (PAPERS.md, paper 1; DESIGN.md, "Light fields").
//
// One field per X-ray view, in the CT frame. A ray is named by its crossings of two parallel
// planes, both perpendicular to the view's central ray at the nominal pose (source S towards the
// ROI centre C, unit axis n):
//   (u, v): the plane through S,   point S + u e1 + v e2
//   (s, t): the plane through C,   point C + s e1 + t e2
// with e1, e2 unit vectors perpendicular to n: e1 along the detector's row axis (the way the row
// index grows), e2 along its column axis, so that t, the samples' innermost axis, runs along a
// detector row. A sample is the line integral of mu along the whole line through both points,
// through the entire volume (the effective image plane lies beyond the CT), so a DRR pixel whose
// ray runs from its source through the patient to the detector reads the same value.
//
// Samples sit on a regular grid: axis a has size[a] samples at lo[a] + i * spacing(a),
// i = 0..size[a]-1. Rendering interpolates quadrilinearly between the 16 samples around a ray;
// a ray outside the grid on any axis is out of the field and is masked, never clamped.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "lftrack/tracking/image.hpp"
#include "lftrack/tracking/pose.hpp"
#include "lftrack/tracking/status.hpp"
#include "lftrack/tracking/volume.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::tracking {

class ThreadPool;

enum class LightFieldStorage : std::uint32_t {
  kFloat32 = 0,  // 4 bytes a sample
  kFixed16 = 1,  // 2 bytes a sample: value = code * scale, scale = max value / 65535
  kVq = 2,       // one codeword index per 2x2x2x2 tile of samples + a codebook of 16-float codewords
};
const char* to_string(LightFieldStorage storage);

// The pose envelope a field is built for: delta = (t, omega) about the registration origin,
// each component of t within +-translation_mm and of omega within +-rotation_deg.
struct PoseEnvelope {
  double translation_mm = 10;
  double rotation_deg = 5;
};

// Everything that fixes which rays a field holds.
struct LightFieldGeometry {
  std::string view_name;
  Eigen::Vector3d source_ct_mm = Eigen::Vector3d::Zero();      // S, nominal source in the CT frame
  Eigen::Vector3d roi_centre_ct_mm = Eigen::Vector3d::Zero();  // C
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();             // n = (C - S) / |C - S|
  Eigen::Vector3d e1 = Eigen::Vector3d::UnitX();
  Eigen::Vector3d e2 = Eigen::Vector3d::UnitY();
  std::array<int, 4> size{32, 32, 256, 256};  // u, v, s, t
  std::array<double, 4> lo{};                 // mm
  std::array<double, 4> hi{};                 // mm

  double spacing(int a) const { return size[a] > 1 ? (hi[a] - lo[a]) / (size[a] - 1) : 1.0; }
  std::int64_t sample_count() const { return std::int64_t{size[0]} * size[1] * size[2] * size[3]; }
  // The (u, v, s, t) of the line through points a and b (CT frame); nothing if the line is
  // (nearly) parallel to the planes.
  std::optional<Eigen::Vector4d> coordinates(const Eigen::Vector3d& a_ct, const Eigen::Vector3d& b_ct) const;
  // The two plane points of sample (u, v, s, t) in mm.
  void ray(const Eigen::Vector4d& uvst, Eigen::Vector3d* on_uv, Eigen::Vector3d* on_st) const;
  Status validate() const;
};

// How a float field's samples are integrated.
enum class LightFieldIntegration : std::uint32_t {
  // Depth slices of the voxels' box model, each resampled once and shifted for every source
  // sample (tracking/src/light_field_slices.hpp): about 5x faster than the walk on the lumbar CT,
  // slightly less faithful (BENCHMARKS.md, issue 24).
  kSlices = 0,
  // The exact Siddon walk of every ray through the voxels (the papers' precompute; the default).
  kSiddon = 1,
};
const char* to_string(LightFieldIntegration integration);

struct LightFieldSpec {
  std::array<int, 4> resolution{32, 32, 256, 256};
  double margin_fraction = 0.02;  // each axis' extent grows by this fraction on both sides
  LightFieldIntegration integration = LightFieldIntegration::kSiddon;
  double slice_step_mm = 0;  // kSlices: the depth step; 0 takes the CT's finest voxel spacing
  // kSiddon: above -1000, each ray is walked only between the first and the last block of 8^3
  // voxels it meets that holds a voxel at or above this CT number (HU, on mu =
  // kDefaultMuWaterPerMm (1 + HU / 1000) whatever water the volume was made with: a few tens of
  // HU either way): the air around the body is left out. -900 builds
  // the lumbar CT's fields in 0.8 of the time; the DRRs then lack the CT noise of that air (a
  // near-constant few hundredths of each line integral), which costs 0.002-0.004 mm of mean TRE
  // on frames rendered from the whole CT (BENCHMARKS.md, issue 56). -1000 (the default) walks
  // the whole grid.
  double skip_air_below_hu = -1000;
  LightFieldStorage storage = LightFieldStorage::kFloat32;
  int vq_codebook_size = 4096;    // 2 .. 65536
  int vq_training_tiles = 65536;  // tiles sampled to train the codebook
  std::uint64_t vq_seed = 1;
};

// The frame of a field: where it sits and what it must cover.
struct LightFieldPlanInput {
  XrayView view_room;      // the detector, room frame
  PixelWindow roi_window;  // the detector pixels the field must serve
  Pose nominal_T_room_from_ct = Pose::Identity();
  Eigen::Vector3d registration_origin_room_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d roi_centre_ct_mm = Eigen::Vector3d::Zero();
  PoseEnvelope envelope;
};

// Plans a field's geometry: the planes from the nominal pose, and extents covering the rays of
// every ROI pixel at every pose of the envelope (its 3^6 corner, edge and centre poses), grown
// by the spec's margin. Nothing outside that is sampled or stored. The (u, v) extents are then
// widened (by under one spacing) so that the nominal source is a sample: rays of the nominal
// pose need no (u, v) interpolation.
Result<LightFieldGeometry> plan_light_field(const LightFieldPlanInput& input, const LightFieldSpec& spec);

// A field with its samples, in memory or memory-mapped from a file. Immutable after building.
class LightField {
 public:
  struct Header {
    LightFieldGeometry geometry;
    LightFieldStorage storage = LightFieldStorage::kFloat32;
    int codebook_size = 0;   // VQ only
    double fixed_scale = 0;  // fixed16 only: value = code * fixed_scale
    Pose nominal_T_room_from_ct = Pose::Identity();
    Eigen::Vector3d registration_origin_room_mm = Eigen::Vector3d::Zero();
    PoseEnvelope envelope;
    std::uint64_t ct_hash = 0;    // of the attenuation volume it was built from
    std::uint64_t plan_hash = 0;  // of the plan input and spec it was built for
    // The settings it was built with beyond its geometry, so that a stale field can name what
    // differs (light_field_differences). Files written before they were recorded have none:
    // `settings_recorded` false.
    bool settings_recorded = false;
    std::uint64_t detector_hash = 0;  // detector_geometry_hash of the view it serves
    PixelWindow roi_window;           // the detector pixels it serves
    double margin_fraction = 0;
    LightFieldIntegration integration = LightFieldIntegration::kSiddon;
    double slice_step_mm = 0;   // as the spec gave it (0: the volume's finest spacing)
    int vq_training_tiles = 0;  // VQ only
    std::uint64_t vq_seed = 0;  // VQ only
  };

  ~LightField();
  LightField(const LightField&) = delete;
  LightField& operator=(const LightField&) = delete;

  const Header& header() const { return header_; }
  const LightFieldGeometry& geometry() const { return header_.geometry; }
  // Bytes of sample data (codebook and indices for VQ).
  std::size_t payload_bytes() const { return payload_bytes_; }
  // The stored value of sample (iu, iv, is, it), decoded to mu * mm.
  float sample(int iu, int iv, int is, int it) const;

  // Storage views for the renderer's kernels.
  const float* float_samples() const { return f32_; }
  const std::uint16_t* fixed_samples() const { return q16_; }
  const float* codebook() const { return codebook_; }
  const std::uint16_t* tile_codes() const { return codes_; }

  // Builds a float field from `mu` (whole lines through the volume), integrated as the spec
  // says, on every thread of `pool`. Slices refused by the geometry (the volume within a tenth
  // of the way from the source to the ROI; light_field_slices.hpp) fall back to the exact walk.
  // `progress` (may be empty) is called with the fraction done, from any worker thread, at most
  // a few times a second.
  static Result<std::shared_ptr<const LightField>> build(const MuVolume& mu, const LightFieldPlanInput& input,
                                                         const LightFieldSpec& spec, ThreadPool* pool,
                                                         const std::function<void(double)>& progress = {});
  // The same samples in another storage mode (VQ trains its codebook here).
  static Result<std::shared_ptr<const LightField>> convert(const LightField& source,
                                                           const LightFieldSpec& spec, ThreadPool* pool);

  // The field averaged over blocks of `factor` x `factor` (s, t) samples (a power of two from 2
  // to 64, fewer than the source's samples less one on each axis), as float, for views whose
  // pixels each span about that many samples: its sample j of s (and t) sits at sample
  // j * factor of the source and holds the trapezoid-weighted mean of the source's samples
  // within factor / 2 of it (the source's edge samples repeated beyond its edges), so a coarse
  // pixel renders rays averaged over about its footprint rather than the one ray through its
  // centre, and reads 1 / factor^2 of the samples. Its last sample reaches the source's last one
  // or up to factor - 1 samples past it; the renderer masks rays past the source's extent, so
  // both mask the same pixels. Its plan hash is 0 (it is not the field its plan describes).
  static Result<std::shared_ptr<const LightField>> downsampled_st(const LightField& source, int factor,
                                                                  ThreadPool* pool);

  // Writes a versioned, checksummed file.
  Status save(const std::filesystem::path& file) const;
  // The header of a file, read alone (1024 bytes) and checked (magic, version, header checksum,
  // geometry); the samples are not read.
  static Result<Header> read_header(const std::filesystem::path& file);
  // Memory-maps a file and checks its version, size and checksums; then, if given, that it was
  // built for this CT and this plan. Each refusal says which check failed.
  static Result<std::shared_ptr<const LightField>> load(const std::filesystem::path& file,
                                                        std::optional<std::uint64_t> expected_ct_hash = {},
                                                        std::optional<std::uint64_t> expected_plan_hash = {});

 private:
  LightField() = default;
  void point_at(const unsigned char* payload);

  Header header_;
  std::vector<unsigned char> owned_;  // in-memory payload
  void* mapping_ = nullptr;           // or a read-only mapping of the whole file
  std::size_t mapping_bytes_ = 0;
  std::size_t payload_bytes_ = 0;
  const float* f32_ = nullptr;
  const std::uint16_t* q16_ = nullptr;
  const float* codebook_ = nullptr;
  const std::uint16_t* codes_ = nullptr;
};

// The depth step a field integrated by slices takes: `step_mm` (LightFieldSpec::slice_step_mm)
// if positive and finite, else the volume's finest voxel spacing.
double light_field_slice_step_mm(const MuVolume& mu, double step_mm);

// Identity of an attenuation volume (geometry and every voxel) for light-field files.
std::uint64_t volume_hash(const MuVolume& mu);
// Identity of a plan input and spec (view, window, pose, origin, ROI, envelope, resolution,
// margin and integration, with the slices' step; not the storage mode, which a file states on its
// own; fields walked by Siddon keep the hash they had before slices existed) and of the planning convention
// (a file planned by an older lftrack is stale) for light-field files.
std::uint64_t plan_hash(const LightFieldPlanInput& input, const LightFieldSpec& spec);
// Identity of a detector's geometry: name, source, first pixel, axes, pitch and size.
std::uint64_t detector_geometry_hash(const XrayView& view);

// What differs between the field `header` describes and a field of `input` and `spec` over a
// volume of hash `ct_hash`, one entry per setting, e.g. "integration (slices in the file, siddon
// now)". A file that does not record its settings (written before they were recorded) whose plan
// hash differs for no reason it records says so. Empty: the header describes that field.
std::vector<std::string> light_field_differences(const LightField::Header& header, std::uint64_t ct_hash,
                                                 const LightFieldPlanInput& input, const LightFieldSpec& spec);

}  // namespace lftrack::tracking

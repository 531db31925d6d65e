#pragma once
// The scene parser's YAML helpers (private to firmware_host/session/src): every value read through them
// is checked, and every error is located at file:line:col.

#include <yaml-cpp/yaml.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "lftrack/session/scene.hpp"

namespace lftrack::session {

namespace fs = std::filesystem;
using Eigen::Vector3d;

// `text` as a YAML double-quoted scalar (JSON's string syntax is one): what a user or a file wrote
// can hold ':', '#', quotes or a line break, and none of it may turn into a key of a file lftrack
// writes. Bytes that are not UTF-8 are written as U+FFFD.
inline std::string yaml_quoted(const std::string& text) {
  return nlohmann::json(text).dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

// The text of a YAML file a person wrote (a scene, a calibration): a regular file of at most
// kMaxYamlFileBytes, read whole. A FIFO, a device (/dev/zero), a folder or a larger file is
// refused with `what` and the path, never read without end (issue 50 probe: /dev/zero as a scene
// took 16 GB, a FIFO blocked for ever).
inline constexpr std::size_t kMaxYamlFileBytes = std::size_t{1} << 20;
Result<std::string> read_yaml_text(const std::string& file, const std::string& what);

class SceneParser {
 public:
  SceneParser(std::string source, fs::path base_dir)
      : source_(std::move(source)), base_dir_(std::move(base_dir)) {}

  Status error_at(const YAML::Mark& mark, const std::string& message) const {
    std::ostringstream s;
    s << source_;
    if (!mark.is_null()) s << ':' << mark.line + 1 << ':' << mark.column + 1;
    s << ": " << message;
    return invalid_argument(s.str());
  }
  // An error at `node`, named by the file it was written in: the scene, or its room file.
  Status error(const YAML::Node& node, const std::string& message) const {
    if (from_room(node)) return SceneParser(room_source_, base_dir_).error_at(node.Mark(), message);
    return error_at(node.Mark(), message);
  }
  // The folder a file named at `node` is relative to: the room file's for what the room wrote,
  // else the scene's.
  fs::path folder_of(const YAML::Node& node) const {
    return from_room(node) ? fs::path(room_source_).parent_path() : base_dir_;
  }
  // "FILE:LINE:COLUMN" of a node (FILE alone where it has no mark).
  std::string where(const YAML::Node& node) const {
    std::ostringstream s;
    s << (from_room(node) ? room_source_ : source_);
    if (!node.Mark().is_null()) s << ':' << node.Mark().line + 1 << ':' << node.Mark().column + 1;
    return s.str();
  }

  // Rejects keys of `map` that are not in `allowed` (typos must not pass silently).
  Status check_keys(const YAML::Node& map, const std::string& what,
                    const std::set<std::string>& allowed) const {
    if (!map.IsMap()) return error(map, what + " must be a mapping");
    std::set<std::string> seen;
    for (const auto& kv : map) {
      // A complex key ("? [a, b]: 1") is no name; as<std::string>() would throw (found by fuzz_calibration_files).
      if (!kv.first.IsScalar()) return error(kv.first, "a key in " + what + " must be a plain name");
      const std::string key = kv.first.Scalar();
      // YAML keeps the first of two equal keys: a limit written twice must not pass unseen.
      if (!seen.insert(key).second) return error(kv.first, "'" + key + "' appears twice in " + what);
      if (!allowed.count(key)) {
        std::string known;
        for (const auto& k : allowed) known += (known.empty() ? "" : ", ") + k;
        return error(kv.first, "unknown key '" + key + "' in " + what + " (allowed: " + known + ")");
      }
    }
    return {};
  }

  Status number(const YAML::Node& n, const std::string& what, double* out) const {
    if (!n.IsScalar()) return error(n, what + " must be a number");
    try {
      *out = n.as<double>();
    } catch (const YAML::Exception&) {
      return error(n, what + " must be a number, got '" + n.Scalar() + "'");
    }
    if (!std::isfinite(*out)) return error(n, what + " must be finite");
    return {};
  }

  Status positive(const YAML::Node& n, const std::string& what, double* out) const {
    LFTRACK_RETURN_IF_ERROR(number(n, what, out));
    if (!(*out > 0)) return error(n, what + " must be positive, got " + n.Scalar());
    return {};
  }

  // A positive number at most `most` (a limit beyond which the value is a typo, never a setting;
  // `why` says so in the error).
  Status positive_at_most(const YAML::Node& n, const std::string& what, double most, const std::string& why,
                          double* out) const {
    LFTRACK_RETURN_IF_ERROR(positive(n, what, out));
    if (*out > most) {
      std::ostringstream m;
      m << what << " must be at most " << most << " (" << why << "), got " << n.Scalar();
      return error(n, m.str());
    }
    return {};
  }

  Status integer(const YAML::Node& n, const std::string& what, long lo, long hi, long* out) const {
    if (!n.IsScalar()) return error(n, what + " must be an integer");
    try {
      *out = n.as<long>();
    } catch (const YAML::Exception&) {
      return error(n, what + " must be an integer, got '" + n.Scalar() + "'");
    }
    if (*out < lo || *out > hi) {
      return error(
          n, what + " must be in " + std::to_string(lo) + ".." + std::to_string(hi) + ", got " + n.Scalar());
    }
    return {};
  }

  // true or false, written so (not yes/no/on: a scene says what it means).
  Status boolean(const YAML::Node& n, const std::string& what, bool* out) const {
    if (!n.IsScalar() || (n.Scalar() != "true" && n.Scalar() != "false"))
      return error(n, what + " must be true or false");
    *out = n.Scalar() == "true";
    return {};
  }

  Status text(const YAML::Node& n, const std::string& what, std::string* out) const {
    if (!n.IsScalar() || n.Scalar().empty()) return error(n, what + " must be a non-empty string");
    *out = n.Scalar();
    return {};
  }

  Status vec3(const YAML::Node& n, const std::string& what, Vector3d* out) const {
    if (!n.IsSequence() || n.size() != 3) return error(n, what + " must be a list of 3 numbers [x, y, z]");
    for (int a = 0; a < 3; ++a) LFTRACK_RETURN_IF_ERROR(number(n[a], what, &(*out)[a]));
    return {};
  }

  Status unit_vec3(const YAML::Node& n, const std::string& what, Vector3d* out) const {
    LFTRACK_RETURN_IF_ERROR(vec3(n, what, out));
    if (!(out->norm() > 1e-9)) return error(n, what + " must not be the zero vector");
    out->normalize();
    return {};
  }

  // The value under `key` of `map`, or an error located at the map if it is absent.
  Status need(const YAML::Node& map, const std::string& key, const std::string& what, YAML::Node* out) const {
    const YAML::Node n = map[key];
    if (!n) return error(map, what + " needs '" + key + "'");
    out->reset(n);  // rebind; operator= would write into the referenced node
    return {};
  }

  Status parse_ct(const YAML::Node& n, CtSpec* ct) const;
  Status parse_roi(const YAML::Node& n, bool builtin, RoiSpec* roi) const;
  Status parse_pose(const YAML::Node& n, tracking::Pose* pose) const;
  Status parse_light_field(const YAML::Node& n, const std::string& what,
                           tracking::LightFieldSpec* spec) const;
  Status parse_detector(const YAML::Node& n, int index, DetectorSpec* d) const;
  Status one_of(const YAML::Node& n, const std::string& what, const std::vector<std::string>& known,
                std::string* out) const;
  Status parse_registration(const YAML::Node& t, RegistrationSpec* r) const;
  // The plans the scene does not name, from what its frames are (scene_default_plans.hpp).
  static void choose_unnamed_plans(const YAML::Node& root, Scene* scene);
  Status parse_fiducials(const YAML::Node& n, FiducialSpec* f) const;
  Result<Scene> parse(const std::string& yaml_text);
  // The scene's `room: FILE` (scene_room.cpp): the room file's sections (detectors, tracking, sim,
  // loop, safety limits, actuator) taken into `root`. What one file sets is taken whole; mappings
  // in both merge key by key, at every depth; a value set in both files is refused (a room never
  // overrides a patient's value unseen, nor the reverse). Errors in what came from the room name
  // the room file and its line.
  Status merge_room(YAML::Node& root, Scene* scene);
  Status merge_room_entry(YAML::Node& here, const YAML::Node& key, const YAML::Node& value, const std::string& within);
  // The host-loop sections (scene_loop_parser.cpp).
  Status parse_sim(const YAML::Node& n, SimFrameSpec* sim) const;
  Status parse_physics(const YAML::Node& n, SimFrameSpec* sim) const;
  Status parse_loop(const YAML::Node& n, loop::LoopSpec* loop) const;
  Status parse_safety(const YAML::Node& n, loop::SafetyLimits* limits) const;
  // safety's keys for the verdict's own checks, within the scene's envelope (parsed before).
  Status parse_verdict_checks(const YAML::Node& n, const PoseEnvelope& envelope, VerdictChecksSpec* checks) const;
  Status parse_actuator(const YAML::Node& n, ActuatorSpec* actuator) const;
  Status parse_motion(const YAML::Node& n, MotionSpec* motion) const;
  // Imaging on demand (scene_imaging_parser.cpp): tracking.imaging, and the surrogate section.
  Status number_in(const YAML::Node& n, const std::string& what, double lo, double hi, const std::string& why,
                   double* out) const;
  Status parse_imaging(const YAML::Node& n, loop::ImagingSpec* imaging, ImagingTechniqueSpec* technique,
                       bool* min_span_given) const;
  Status parse_surrogate(const YAML::Node& n, SurrogateSpec* surrogate, loop::SurrogateLimits* limits) const;
  Status parse_imaging_sections(const YAML::Node& root, Scene* scene) const;
  Status check_motion(const YAML::Node& n, const std::string& what, const tracking::Vector6d& v, double mm,
                      double deg) const;
  // The devices (scene_device_parser.cpp).
  Status parse_frames(const YAML::Node& n, const std::string& what, DetectorFramesSpec* frames) const;
  Status parse_detector_calibration(const YAML::Node& n, const std::string& what, std::string* file) const;
  Status parse_modbus(const YAML::Node& n, drivers::ModbusCouchOptions* modbus) const;
  Status parse_can(const YAML::Node& n, drivers::CanRobotOptions* can) const;
  Status check_devices(const YAML::Node& root, const Scene& scene) const;
  Status vec6(const YAML::Node& n, const std::string& what, const char* translation_key,
              const char* rotation_key, tracking::Vector6d* out) const;

 private:
  // Whether `node` is one the room file wrote (a walk of its sections: small files, and only on
  // an error).
  bool from_room(const YAML::Node& node) const;

  std::string source_;
  fs::path base_dir_;
  std::string room_source_;             // the room file as the scene names it, resolved
  std::vector<YAML::Node> room_nodes_;  // the room file's sections, as merged
};

}  // namespace lftrack::session

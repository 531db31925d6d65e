// Scene YAML -> Scene, with every error located at file:line:col (yaml-cpp marks, 1-based here).

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iomanip>
#include <set>

#include <sstream>

#include "lftrack/loop/registration_verdict.hpp"
#include "lftrack/session/scene.hpp"
#include "lftrack/session/scene_default_plans.hpp"
#include "lftrack/tracking/registration.hpp"
#include "lftrack/tracking/similarity.hpp"
#include "scene_yaml.hpp"

namespace lftrack::session {

using loop::similarity_expectation;

Status SceneParser::parse_ct(const YAML::Node& n, CtSpec* ct) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "ct", {"path", "seed", "mu_water_per_mm"}));
  YAML::Node path;
  LFTRACK_RETURN_IF_ERROR(need(n, "path", "ct", &path));
  LFTRACK_RETURN_IF_ERROR(text(path, "ct.path", &ct->path));
  if (!ct->is_builtin_phantom()) {
    if (ct->path.rfind("builtin:", 0) == 0)
      return error(path, "unknown built-in CT '" + ct->path + "' (known: builtin:phantom, builtin:phantom-clinical)");
    const fs::path p(ct->path);
    ct->path = (p.is_absolute() ? p : base_dir_ / p).lexically_normal().string();
  }
  if (n["seed"]) {
    long seed = 0;
    LFTRACK_RETURN_IF_ERROR(integer(n["seed"], "ct.seed", 0, 2147483647L, &seed));
    if (!ct->is_builtin_phantom()) return error(n["seed"], "ct.seed applies only to builtin:phantom");
    ct->phantom_seed = static_cast<std::uint64_t>(seed);
  }
  if (n["mu_water_per_mm"]) {
    LFTRACK_RETURN_IF_ERROR(positive(n["mu_water_per_mm"], "ct.mu_water_per_mm", &ct->mu_water_per_mm));
    if (ct->mu_water_per_mm > 1.0)
      return error(n["mu_water_per_mm"], "ct.mu_water_per_mm is in 1/mm; water is about 0.02");
  }
  return {};
}

Status SceneParser::parse_roi(const YAML::Node& n, bool builtin, RoiSpec* roi) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "roi", {"centre_mm", "size_mm", "mask"}));
  if (const YAML::Node m = n["mask"]) {
    LFTRACK_RETURN_IF_ERROR(check_keys(m, "roi.mask", {"rtstruct", "target", "margin_mm"}));
    RoiMaskSpec mask;
    YAML::Node node;
    LFTRACK_RETURN_IF_ERROR(need(m, "rtstruct", "roi.mask", &node));
    LFTRACK_RETURN_IF_ERROR(text(node, "roi.mask.rtstruct", &mask.rtstruct));
    const fs::path file(mask.rtstruct);
    mask.rtstruct = (file.is_absolute() ? file : base_dir_ / file).lexically_normal().string();
    LFTRACK_RETURN_IF_ERROR(need(m, "target", "roi.mask", &node));
    LFTRACK_RETURN_IF_ERROR(text(node, "roi.mask.target", &mask.target));
    if (m["margin_mm"]) {
      LFTRACK_RETURN_IF_ERROR(number(m["margin_mm"], "roi.mask.margin_mm", &mask.margin_mm));
      if (!(mask.margin_mm >= 0 && mask.margin_mm <= 50))
        return error(m["margin_mm"], "roi.mask.margin_mm is the margin around the target's projection, in [0, 50] mm");
    }
    if (builtin) return error(m, "roi.mask needs a CT read from a DICOM series (its structure set's CT)");
    roi->mask = mask;
  }
  if (n["centre_mm"]) {
    Vector3d c;
    LFTRACK_RETURN_IF_ERROR(vec3(n["centre_mm"], "roi.centre_mm", &c));
    roi->centre_ct_mm = c;
  } else if (!builtin) {
    return error(n, "roi needs 'centre_mm' (only builtin:phantom has a default target)");
  }
  if (n["size_mm"]) {
    LFTRACK_RETURN_IF_ERROR(vec3(n["size_mm"], "roi.size_mm", &roi->size_mm));
    if (!(roi->size_mm.minCoeff() > 0)) return error(n["size_mm"], "roi.size_mm must be positive");
  }
  return {};
}

Status SceneParser::parse_pose(const YAML::Node& n, tracking::Pose* pose) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "nominal_pose", {"translation_mm", "rotation_deg"}));
  Vector3d t = Vector3d::Zero(), r = Vector3d::Zero();
  if (n["translation_mm"])
    LFTRACK_RETURN_IF_ERROR(vec3(n["translation_mm"], "nominal_pose.translation_mm", &t));
  if (n["rotation_deg"])
    LFTRACK_RETURN_IF_ERROR(vec3(n["rotation_deg"], "nominal_pose.rotation_deg [roll, pitch, yaw]", &r));
  *pose = tracking::Pose::Identity();
  pose->linear() = tracking::rotation_from_euler(
      {tracking::deg_to_rad(r.x()), tracking::deg_to_rad(r.y()), tracking::deg_to_rad(r.z())});
  pose->translation() = t;
  return {};
}

Result<Scene> SceneParser::parse(const std::string& yaml_text) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::ParserException& e) {
    return error_at(e.mark, "YAML syntax error: " + e.msg);
  }
  if (!root || root.IsNull()) return error_at(YAML::Mark::null_mark(), "the scene is empty");
  LFTRACK_RETURN_IF_ERROR(check_keys(
      root, "the scene",
      {"version", "name", "room", "ct", "roi", "registration_origin_mm", "nominal_pose", "detectors",
       "envelope", "tracking", "fiducials", "sim", "loop", "safety", "actuator", "motion", "surrogate"}));
  Scene scene;
  scene.source = source_;
  if (root["room"]) LFTRACK_RETURN_IF_ERROR(merge_room(root, &scene));
  YAML::Node node;
  long version = 0;
  LFTRACK_RETURN_IF_ERROR(need(root, "version", "the scene", &node));
  LFTRACK_RETURN_IF_ERROR(integer(node, "version", 1, 1, &version));
  if (root["name"]) LFTRACK_RETURN_IF_ERROR(text(root["name"], "name", &scene.name));
  if (!root["ct"] && root["detectors"] && !root["room"])
    return error(root, "the scene needs 'ct': this looks like a room file, which a patient's scene names under "
                       "`room:` (docs/scenes.md, \"Room files\")");
  LFTRACK_RETURN_IF_ERROR(need(root, "ct", "the scene", &node));
  LFTRACK_RETURN_IF_ERROR(parse_ct(node, &scene.ct));
  scene.lines["ct"] = where(node);
  if (root["roi"]) {
    LFTRACK_RETURN_IF_ERROR(parse_roi(root["roi"], scene.ct.is_builtin_phantom(), &scene.roi));
    scene.lines["roi"] = where(root["roi"]);
  } else if (!scene.ct.is_builtin_phantom()) {
    return error(root, "the scene needs 'roi' (centre_mm, size_mm) for a CT read from a file");
  }
  if (root["registration_origin_mm"]) {
    Vector3d c;
    LFTRACK_RETURN_IF_ERROR(vec3(root["registration_origin_mm"], "registration_origin_mm", &c));
    scene.registration_origin_ct_mm = c;
  }
  if (root["nominal_pose"]) {
    tracking::Pose pose;
    LFTRACK_RETURN_IF_ERROR(parse_pose(root["nominal_pose"], &pose));
    scene.nominal_T_room_from_ct = pose;
  }
  YAML::Node detectors;
  if (!root["detectors"] && !scene.room_file.empty())
    return error(root, "the scene needs 'detectors', and neither it nor its room file " + scene.room_file + " gives them");
  LFTRACK_RETURN_IF_ERROR(need(root, "detectors", "the scene", &detectors));
  if (!detectors.IsSequence() || detectors.size() == 0 || detectors.size() > 4) {
    return error(detectors, "detectors must be a list of 1 to 4 detectors");
  }
  std::set<std::string> names;
  for (std::size_t i = 0; i < detectors.size(); ++i) {
    DetectorSpec d;
    LFTRACK_RETURN_IF_ERROR(parse_detector(detectors[i], int(i), &d));
    if (!names.insert(d.view.name).second)
      return error(detectors[i], "duplicate detector name '" + d.view.name + "'");
    scene.detectors.push_back(d);
  }
  if (root["envelope"]) {
    const YAML::Node e = root["envelope"];
    LFTRACK_RETURN_IF_ERROR(check_keys(e, "envelope", {"translation_mm", "rotation_deg"}));
    if (e["translation_mm"])
      LFTRACK_RETURN_IF_ERROR(positive_at_most(e["translation_mm"], "envelope.translation_mm", 50,
                                               "light fields cover the poses the envelope names; beyond 50 mm "
                                               "the patient is set up again",
                                               &scene.envelope.translation_mm));
    if (e["rotation_deg"])
      LFTRACK_RETURN_IF_ERROR(
          positive(e["rotation_deg"], "envelope.rotation_deg", &scene.envelope.rotation_deg));
    if (scene.envelope.rotation_deg > 45)
      return error(e["rotation_deg"], "envelope.rotation_deg must be at most 45");
  }
  if (root["tracking"]) {
    const YAML::Node t = root["tracking"];
    LFTRACK_RETURN_IF_ERROR(
        check_keys(t, "tracking",
                   {"renderer", "octree_pivot", "light_field", "similarity", "histogram_bins", "plan",
                    "gamma_per_mm", "tre_box_mm", "single_view", "imaging"}));
    LFTRACK_RETURN_IF_ERROR(parse_registration(t, &scene.registration));
    if (t["light_field"])
      LFTRACK_RETURN_IF_ERROR(
          parse_light_field(t["light_field"], "tracking.light_field", &scene.light_field));
    if (t["renderer"]) {
      LFTRACK_RETURN_IF_ERROR(text(t["renderer"], "tracking.renderer", &scene.renderer));
      const auto known = tracking::renderer_names();
      if (std::find(known.begin(), known.end(), scene.renderer) == known.end()) {
        std::string list;
        for (const auto& k : known) list += (list.empty() ? "" : ", ") + k;
        return error(t["renderer"], "unknown renderer '" + scene.renderer + "' (known: " + list + ")");
      }
    }
    if (t["octree_pivot"]) {
      LFTRACK_RETURN_IF_ERROR(number(t["octree_pivot"], "tracking.octree_pivot", &scene.octree_pivot));
      if (!(scene.octree_pivot >= 0 && scene.octree_pivot <= 1))
        return error(t["octree_pivot"],
                     "tracking.octree_pivot must be in [0, 1], got " + t["octree_pivot"].Scalar());
    }
  }
  if (root["fiducials"]) LFTRACK_RETURN_IF_ERROR(parse_fiducials(root["fiducials"], &scene.fiducials));
  if (root["sim"]) LFTRACK_RETURN_IF_ERROR(parse_sim(root["sim"], &scene.sim));
  if (root["loop"]) LFTRACK_RETURN_IF_ERROR(parse_loop(root["loop"], &scene.loop));
  if (root["safety"]) {
    LFTRACK_RETURN_IF_ERROR(parse_safety(root["safety"], &scene.safety));
    scene.min_similarity_given = static_cast<bool>(root["safety"]["min_similarity"]);
    LFTRACK_RETURN_IF_ERROR(parse_verdict_checks(root["safety"], scene.envelope, &scene.verdict_checks));
    if (const YAML::Node q = root["safety"]["require_daily_qa"])
      LFTRACK_RETURN_IF_ERROR(boolean(q, "safety.require_daily_qa", &scene.require_daily_qa));
    if (const YAML::Node c = root["safety"]["commissioning"]) {
      std::string file;
      LFTRACK_RETURN_IF_ERROR(text(c, "safety.commissioning", &file));
      if (file.empty()) return error(c, "safety.commissioning: an empty file name");
      if (scene.min_similarity_given)
        return error(root["safety"]["min_similarity"],
                     "safety.min_similarity and safety.commissioning both set the floor; a commissioned scene takes "
                     "its floors from its commissioning file");
      const fs::path path(file);
      scene.commissioning_file = (path.is_absolute() ? path : base_dir_ / path).lexically_normal().string();
    }
    // A floor at or below what unrelated images score turns the similarity check off.
    const auto expected = similarity_expectation(scene.registration.similarity);
    if (scene.min_similarity_given && expected.ok() && scene.safety.min_similarity <= expected->no_information) {
      std::ostringstream why;
      why << "safety.min_similarity " << scene.safety.min_similarity << " does not exceed what unrelated images score with "
          << scene.registration.similarity << " (" << expected->no_information
          << "): the floor would pass frames that match nothing (the measure's default is " << expected->min_similarity
          << ")";
      return error(root["safety"]["min_similarity"], why.str());
    }
  }
  if (root["actuator"]) LFTRACK_RETURN_IF_ERROR(parse_actuator(root["actuator"], &scene.actuator));
  LFTRACK_RETURN_IF_ERROR(check_devices(root, scene));
  if (root["motion"]) LFTRACK_RETURN_IF_ERROR(parse_motion(root["motion"], &scene.motion));
  LFTRACK_RETURN_IF_ERROR(parse_imaging_sections(root, &scene));
  if (!(root["safety"] && root["safety"]["envelope_edge_mm"]))
    scene.verdict_checks.envelope_edge_mm = VerdictChecksSpec::kEnvelopeEdgeFraction * scene.envelope.translation_mm;
  choose_unnamed_plans(root, &scene);
  return scene;
}

Status SceneParser::one_of(const YAML::Node& n, const std::string& what,
                           const std::vector<std::string>& known, std::string* out) const {
  LFTRACK_RETURN_IF_ERROR(text(n, what, out));
  if (std::find(known.begin(), known.end(), *out) != known.end()) return {};
  std::string list;
  for (const auto& k : known) list += (list.empty() ? "" : ", ") + k;
  return error(n, "unknown " + what + " '" + *out + "' (known: " + list + ")");
}

void SceneParser::choose_unnamed_plans(const YAML::Node& root, Scene* scene) {
  const auto named = [&](const char* section, const char* key) {
    return root[section] && root[section].IsMap() && root[section][key];
  };
  scene->defaulted_plans.plan = !named("tracking", "plan");
  scene->defaulted_plans.align = !named("loop", "align_plan");
  scene->defaulted_plans.track = !named("loop", "track_plan");
  apply_default_plans(default_plans(*scene), scene);
}

Status SceneParser::parse_registration(const YAML::Node& t, RegistrationSpec* r) const {
  if (t["similarity"])
    LFTRACK_RETURN_IF_ERROR(
        one_of(t["similarity"], "tracking.similarity", tracking::similarity_names(), &r->similarity));
  if (t["plan"])
    LFTRACK_RETURN_IF_ERROR(
        one_of(t["plan"], "tracking.plan", tracking::registration_plan_names(), &r->plan));
  if (t["histogram_bins"]) {
    long bins = 0;
    LFTRACK_RETURN_IF_ERROR(integer(t["histogram_bins"], "tracking.histogram_bins", 4, 1024, &bins));
    r->histogram_bins = static_cast<int>(bins);
  }
  if (t["gamma_per_mm"]) {
    LFTRACK_RETURN_IF_ERROR(number(t["gamma_per_mm"], "tracking.gamma_per_mm", &r->gamma_per_mm));
    if (r->gamma_per_mm < 0) return error(t["gamma_per_mm"], "tracking.gamma_per_mm must be >= 0");
  }
  if (t["tre_box_mm"])
    LFTRACK_RETURN_IF_ERROR(positive(t["tre_box_mm"], "tracking.tre_box_mm", &r->tre_box_mm));
  if (t["single_view"]) {
    if (!t["single_view"].IsScalar() ||
        (t["single_view"].Scalar() != "true" && t["single_view"].Scalar() != "false"))
      return error(t["single_view"], "tracking.single_view must be true or false");
    r->single_view = t["single_view"].Scalar() == "true";
  }
  return {};
}

Status SceneParser::parse_fiducials(const YAML::Node& n, FiducialSpec* f) const {
  LFTRACK_RETURN_IF_ERROR(check_keys(n, "fiducials", {"positions_mm", "radius_mm", "insert"}));
  YAML::Node list;
  LFTRACK_RETURN_IF_ERROR(need(n, "positions_mm", "fiducials", &list));
  if (!list.IsSequence() || list.size() == 0 || list.size() > 16)
    return error(list, "fiducials.positions_mm must be a list of 1 to 16 points [x, y, z]");
  for (std::size_t i = 0; i < list.size(); ++i) {
    Vector3d p;
    LFTRACK_RETURN_IF_ERROR(vec3(list[i], "fiducials.positions_mm", &p));
    f->positions_ct_mm.push_back(p);
  }
  if (n["radius_mm"]) {
    LFTRACK_RETURN_IF_ERROR(positive(n["radius_mm"], "fiducials.radius_mm", &f->radius_mm));
    if (f->radius_mm > 10) return error(n["radius_mm"], "fiducials.radius_mm must be at most 10");
  }
  if (n["insert"]) {
    if (!n["insert"].IsScalar() || (n["insert"].Scalar() != "true" && n["insert"].Scalar() != "false"))
      return error(n["insert"], "fiducials.insert must be true or false");
    f->insert = n["insert"].Scalar() == "true";
  }
  return {};
}

Result<Scene> parse_scene(const std::string& yaml_text, const std::string& source_name,
                          const std::filesystem::path& base_dir) {
  SceneParser parser(source_name, base_dir);
  try {
    return parser.parse(yaml_text);
  } catch (const YAML::Exception& e) {  // shapes the checks above did not foresee, e.g. a list as a key
    return parser.error_at(e.mark, "unexpected YAML structure: " + e.msg);
  }
}

bool is_detector_name(const std::string& name) {
  return !name.empty() && name.size() <= 64 && name.front() != '.' &&
         std::all_of(name.begin(), name.end(),
                     [](unsigned char c) { return std::isalnum(c) || c == '_' || c == '-' || c == '.'; });
}

Result<std::string> read_yaml_text(const std::string& file, const std::string& what) {
  // O_NONBLOCK: opening a FIFO with no writer does not wait; fstat then refuses it.
  const int fd = ::open(file.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) return not_found("cannot open " + what + " '" + file + "': " + std::strerror(errno));
  struct stat st {};
  const bool regular = ::fstat(fd, &st) == 0 && S_ISREG(st.st_mode);
  if (!regular || std::uint64_t(st.st_size) > kMaxYamlFileBytes) {
    ::close(fd);
    return invalid_argument(file + ": " +
                            (regular ? "larger than the " + std::to_string(kMaxYamlFileBytes >> 20) + " MiB a " + what +
                                           " may be"
                                     : "not a regular file (a " + what + " is a YAML file)"));
  }
  std::string text(std::size_t(st.st_size), '\0');
  std::size_t have = 0;
  while (have < text.size()) {
    const ssize_t n = ::read(fd, text.data() + have, text.size() - have);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    have += std::size_t(n);
  }
  ::close(fd);
  text.resize(have);  // a file that shrank while read: what was there
  return text;
}

Result<Scene> load_scene(const std::string& file_or_builtin) {
  if (auto text = builtin_scene_text(file_or_builtin)) {
    return parse_scene(*text, file_or_builtin, std::filesystem::current_path());
  }
  if (file_or_builtin.rfind("builtin:", 0) == 0) {
    return not_found("unknown built-in scene '" + file_or_builtin + "' (known: builtin:phantom, builtin:phantom-clinical)");
  }
  auto text = read_yaml_text(file_or_builtin, "scene file");
  if (!text.ok()) return text.status();
  const fs::path base = fs::absolute(fs::path(file_or_builtin)).parent_path();
  return parse_scene(*text, file_or_builtin, base);
}

}  // namespace lftrack::session

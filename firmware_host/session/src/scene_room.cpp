// A scene's room file: the room's views, detectors, devices and imaging kept apart from the
// patient, so that a new patient is a CT, a plan and a room (docs/scenes.md, "Room files").

#include <functional>

#include "scene_yaml.hpp"

namespace lftrack::session {

namespace {

// What a room file may hold: the room (views, detectors, couch or robot, the loop's host, the
// simulated twin's imaging) and the site's registration and safety settings. The patient (CT,
// ROI, origin, envelope, fiducials, motion) and its commissioning stay in the scene.
const std::set<std::string> kRoomSections = {"detectors", "tracking", "sim", "loop", "safety", "actuator"};
// What a room file may hold at most: a room of four detectors and every device is some hundreds of
// values, ten levels deep.
constexpr std::size_t kMaxRoomNodes = 20000;
constexpr int kMaxRoomDepth = 32;

}  // namespace

bool SceneParser::from_room(const YAML::Node& node) const {
  if (room_nodes_.empty() || !node.IsDefined()) return false;
  // Bounded: a room file that passed merge_room has at most kMaxRoomNodes nodes, no deeper than
  // kMaxRoomDepth (aliases may make a graph of it; the walk stops at the bounds).
  std::size_t visited = 0;
  const std::function<bool(const YAML::Node&, int)> holds = [&](const YAML::Node& n, int depth) {
    if (++visited > kMaxRoomNodes || depth > kMaxRoomDepth) return false;
    if (n.is(node)) return true;
    if (n.IsSequence()) {
      for (const YAML::Node& item : n)
        if (holds(item, depth + 1)) return true;
    } else if (n.IsMap()) {
      for (const auto& kv : n)
        if (kv.first.is(node) || holds(kv.second, depth + 1)) return true;
    }
    return false;
  };
  for (const YAML::Node& section : room_nodes_)
    if (holds(section, 0)) return true;
  return false;
}

Status SceneParser::merge_room_entry(YAML::Node& here, const YAML::Node& key, const YAML::Node& value,
                                     const std::string& within) {
  if (!key.IsScalar()) return error(key, "a key in " + (within.empty() ? "a room file" : within) + " must be a plain name");
  const std::string name = within.empty() ? key.Scalar() : within + "." + key.Scalar();
  const YAML::Node& lookup = here;  // const: a lookup that must not add the key
  const YAML::Node mine = lookup[key.Scalar()];
  if (!mine) {
    here.force_insert(key, value);  // the room's own nodes: their errors name the room file
    return {};
  }
  if (!mine.IsMap() || !value.IsMap())
    return error(mine, name + " is set both here and in the room file " + where(value) + ": give it in one of them");
  YAML::Node into = mine;
  for (const auto& entry : value) LFTRACK_RETURN_IF_ERROR(merge_room_entry(into, entry.first, entry.second, name));
  return {};
}

Status SceneParser::merge_room(YAML::Node& root, Scene* scene) {
  const YAML::Node room_key = root["room"];
  std::string file;
  LFTRACK_RETURN_IF_ERROR(text(room_key, "room", &file));
  const fs::path path(file);
  const std::string resolved = (path.is_absolute() ? path : base_dir_ / path).lexically_normal().string();
  auto room_text = read_yaml_text(resolved, "room file");
  if (!room_text.ok()) return error(room_key, "room: " + room_text.status().message());
  const SceneParser room_parser(resolved, base_dir_);
  YAML::Node room;
  try {
    room = YAML::Load(*room_text);
  } catch (const YAML::ParserException& e) {
    return room_parser.error_at(e.mark, "YAML syntax error: " + e.msg);
  }
  if (!room || room.IsNull()) return error(room_key, "room: the room file '" + resolved + "' is empty");
  std::set<std::string> allowed = kRoomSections;
  allowed.insert({"version", "name"});
  if (Status s = room_parser.check_keys(room, "a room file", allowed); !s.ok()) {
    if (room.IsMap() && (room["ct"] || room["room"]))
      return invalid_argument(s.message() + " (a room file holds the room, never a patient nor another room)");
    return s;
  }
  YAML::Node node;
  long version = 0;
  LFTRACK_RETURN_IF_ERROR(room_parser.need(room, "version", "a room file", &node));
  LFTRACK_RETURN_IF_ERROR(room_parser.integer(node, "version", 1, 1, &version));
  if (const YAML::Node safety = room["safety"]; safety && safety.IsMap() && safety["commissioning"])
    return room_parser.error(safety["commissioning"],
                             "safety.commissioning belongs to the patient's scene: a room file is shared by "
                             "every patient, and each is commissioned on its own CT");

  // A key written twice anywhere in the room file (YAML keeps the first) is the room's own error.
  std::size_t nodes = 0;
  const std::function<Status(const YAML::Node&, const std::string&, int)> no_repeats =
      [&](const YAML::Node& n, const std::string& within, int depth) -> Status {
    if (++nodes > kMaxRoomNodes || depth > kMaxRoomDepth)
      return room_parser.error(n, "the room file is larger or deeper than a room is (at most " +
                                      std::to_string(kMaxRoomNodes) + " values, " + std::to_string(kMaxRoomDepth) +
                                      " levels; an alias may repeat a part of it without end)");
    if (n.IsSequence()) {
      for (std::size_t i = 0; i < n.size(); ++i)
        LFTRACK_RETURN_IF_ERROR(no_repeats(n[i], within + "[" + std::to_string(i) + "]", depth + 1));
    } else if (n.IsMap()) {
      std::set<std::string> seen;
      for (const auto& kv : n) {
        if (!kv.first.IsScalar()) return room_parser.error(kv.first, "a key in " + within + " must be a plain name");
        if (!seen.insert(kv.first.Scalar()).second)
          return room_parser.error(kv.first, "'" + kv.first.Scalar() + "' appears twice in " + within);
        LFTRACK_RETURN_IF_ERROR(
            no_repeats(kv.second, within.empty() ? kv.first.Scalar() : within + "." + kv.first.Scalar(), depth + 1));
      }
    }
    return {};
  };
  LFTRACK_RETURN_IF_ERROR(no_repeats(room, "", 0));
  room_source_ = resolved;
  for (const auto& kv : room) {
    if (!kRoomSections.count(kv.first.Scalar())) continue;
    room_nodes_.push_back(kv.second);
    LFTRACK_RETURN_IF_ERROR(merge_room_entry(root, kv.first, kv.second, ""));
  }
  scene->room_file = resolved;
  return {};
}

}  // namespace lftrack::session

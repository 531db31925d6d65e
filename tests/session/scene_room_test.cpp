// A scene's room file (scene_room.cpp): the room's sections merged into the patient's scene, a
// value set in both refused, errors named by the file that wrote them.

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "lftrack/session/scene.hpp"
#include "test_data.hpp"

namespace lftrack::session {
namespace {

namespace fs = std::filesystem;

const char* kRoom = R"(version: 1
name: test room
detectors:
  - name: A
    rows: 64
    cols: 64
    pitch_mm: 0.4
    isocentric:
      source_direction: [0, -1, 0]
      up: [0, 0, 1]
      source_to_isocentre_mm: 1000
      source_to_detector_mm: 1500
tracking:
  similarity: ncc
  single_view: true
sim:
  photons_per_pixel: 5000
  physics:
    preset: clinical
safety:
  max_step_mm: 1.5
)";

const char* kPatient = R"(version: 1
room: rooms/room.yaml
ct: {path: ct_folder}
roi: {centre_mm: [0, 0, 0], size_mm: [40, 40, 40]}
tracking:
  gamma_per_mm: 0.05
sim:
  physics:
    anatomy:
      breathing_mm: 4
safety:
  max_total_mm: 8
)";

class SceneRoom : public ::testing::Test {
 protected:
  void SetUp() override {
    fs::create_directories(dir_.path() / "rooms");
    write("rooms/room.yaml", kRoom);
  }
  void write(const std::string& name, const std::string& text) { std::ofstream(dir_.path() / name) << text; }
  Result<Scene> load(const std::string& text) {
    write("patient.yaml", text);
    return load_scene((dir_.path() / "patient.yaml").string());
  }
  test::TempDir dir_;
};

TEST_F(SceneRoom, TheRoomsSectionsAndThePatientsMergeAtEveryDepth) {
  auto scene = load(kPatient);
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->room_file, (dir_.path() / "rooms/room.yaml").lexically_normal().string());
  ASSERT_EQ(scene->detectors.size(), 1u);
  EXPECT_EQ(scene->detectors[0].view.rows, 64);
  EXPECT_EQ(scene->registration.similarity, "ncc");                     // the room's
  EXPECT_DOUBLE_EQ(scene->registration.gamma_per_mm, 0.05);               // the patient's, in the same section
  EXPECT_DOUBLE_EQ(scene->sim.photons_per_pixel, 5000);                   // the room's
  EXPECT_DOUBLE_EQ(scene->safety.max_step_mm, 1.5);                       // the room's
  EXPECT_DOUBLE_EQ(scene->safety.max_total_mm, 8);                        // the patient's
  EXPECT_EQ(scene->ct.path, (dir_.path() / "ct_folder").string());       // relative to the scene, not the room
}

TEST_F(SceneRoom, AValueSetInBothFilesIsRefusedNamingBoth) {
  std::string text = kPatient;
  text.replace(text.find("  max_total_mm: 8"), 16, "  max_step_mm: 3");
  auto scene = load(text);
  ASSERT_FALSE(scene.ok());
  const std::string m = scene.status().message();
  EXPECT_NE(m.find("patient.yaml:"), std::string::npos) << m;
  EXPECT_NE(m.find("safety.max_step_mm is set both here and in the room file"), std::string::npos) << m;
  EXPECT_NE(m.find("room.yaml:"), std::string::npos) << m;
  // A list in both (the detectors) is as refused as a number.
  text = std::string(kPatient) + "detectors:\n  - {name: B, rows: 8, cols: 8, pitch_mm: 1, isocentric: "
                                 "{source_direction: [0, -1, 0], up: [0, 0, 1], source_to_isocentre_mm: 1000, "
                                 "source_to_detector_mm: 1500}}\n";
  scene = load(text);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("detectors is set both here and in the room file"), std::string::npos)
      << scene.status().message();
}

TEST_F(SceneRoom, AnErrorInTheRoomNamesTheRoomFileAndItsLine) {
  std::string room = kRoom;
  room.replace(room.find("max_step_mm: 1.5"), 16, "max_step_mm: -1");
  write("rooms/room.yaml", room);
  auto scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  const std::string m = scene.status().message();
  EXPECT_EQ(m.rfind((dir_.path() / "rooms/room.yaml").lexically_normal().string() + ":21:", 0), 0u) << m;
  // An unknown key the room put into a section the patient also has: the room's line.
  room = kRoom;
  room.replace(room.find("  max_step_mm: 1.5"), 18, "  max_stepmm: 1.5");
  write("rooms/room.yaml", room);
  scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("room.yaml:21:3: unknown key 'max_stepmm'"), std::string::npos)
      << scene.status().message();
}

TEST_F(SceneRoom, AKeyTwiceInTheRoomIsTheRoomsOwnErrorAndARoomWithoutDetectorsIsNamed) {
  std::string room = kRoom;
  room.replace(room.find("  max_step_mm: 1.5"), 18, "  max_step_mm: 1.5\n  max_step_mm: 2");
  write("rooms/room.yaml", room);
  auto scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("room.yaml:22:3: 'max_step_mm' appears twice in safety"), std::string::npos)
      << scene.status().message();
  write("rooms/room.yaml", "version: 1\nsafety: {max_step_mm: 1}\n");
  scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("neither it nor its room file"), std::string::npos) << scene.status().message();
}

TEST_F(SceneRoom, AFileTheRoomNamesIsRelativeToTheRoomFile) {
  std::string room = kRoom;
  room.replace(room.find("  - name: A\n"), 12, "  - name: A\n    frames: {type: replay, sequence: archive}\n");
  write("rooms/room.yaml", room);
  auto scene = load(kPatient);
  ASSERT_TRUE(scene.ok()) << scene.status().message();
  EXPECT_EQ(scene->detectors[0].frames.sequence, (dir_.path() / "rooms/archive").string());
}

TEST_F(SceneRoom, ARoomThatRepeatsItselfWithoutEndIsRefused) {
  // An alias inside its own anchor, and ten levels of aliases each ten times the last.
  write("rooms/room.yaml", "version: 1\nsim: &a [*a]\n");
  auto scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("larger or deeper than a room is"), std::string::npos) << scene.status().message();
  std::string laughs = "version: 1\nsafety:\n  l0: &l0 [1]\n";
  for (int i = 1; i <= 10; ++i) {
    laughs += "  l" + std::to_string(i) + ": &l" + std::to_string(i) + " [";
    for (int k = 0; k < 10; ++k) laughs += std::string(k ? ", " : "") + "*l" + std::to_string(i - 1);
    laughs += "]\n";
  }
  write("rooms/room.yaml", laughs);
  scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("larger or deeper than a room is"), std::string::npos) << scene.status().message();
}

TEST_F(SceneRoom, ARoomFileHoldsOnlyTheRoom) {
  // A patient in the room file, a room in a room, a commissioning shared by every patient.
  for (const std::string& extra :
       {std::string("ct: {path: x}\n"), std::string("room: other.yaml\n"), std::string("roi: {size_mm: [1, 1, 1]}\n")}) {
    write("rooms/room.yaml", std::string(kRoom) + extra);
    auto scene = load(kPatient);
    ASSERT_FALSE(scene.ok()) << extra;
    EXPECT_NE(scene.status().message().find("unknown key"), std::string::npos) << scene.status().message();
  }
  std::string room = kRoom;
  room.replace(room.find("  max_step_mm: 1.5"), 18, "  commissioning: c.yaml");
  write("rooms/room.yaml", room);
  auto scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("safety.commissioning belongs to the patient's scene"), std::string::npos)
      << scene.status().message();
}

TEST_F(SceneRoom, AMissingEmptyOrBrokenRoomFileIsRefusedAtTheScenesLine) {
  std::string text = kPatient;
  text.replace(text.find("rooms/room.yaml"), 15, "rooms/none.yaml");
  auto scene = load(text);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("patient.yaml:2:7: room: cannot open room file"), std::string::npos)
      << scene.status().message();
  write("rooms/room.yaml", "");
  scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("is empty"), std::string::npos) << scene.status().message();
  write("rooms/room.yaml", "version: 1\ndetectors: [\n");
  scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("room.yaml:"), std::string::npos) << scene.status().message();
  EXPECT_NE(scene.status().message().find("YAML syntax error"), std::string::npos) << scene.status().message();
  write("rooms/room.yaml", "detectors: []\n");  // no version
  scene = load(kPatient);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("a room file needs 'version'"), std::string::npos) << scene.status().message();
  // A folder or a device as the room: refused, never read without end.
  text = kPatient;
  text.replace(text.find("rooms/room.yaml"), 15, "/dev/zero");
  scene = load(text);
  ASSERT_FALSE(scene.ok());
  EXPECT_NE(scene.status().message().find("not a regular file"), std::string::npos) << scene.status().message();
}

TEST(SceneRoomShipped, EveryRoomFileLoadsWithAPatientAndTheShippedScenesUseThem) {
  const fs::path scenes = fs::path(LFTRACK_SOURCE_DIR) / "scenes";
  for (const char* room : {"oblique-pair.yaml", "oblique-pair-clinical.yaml"}) {
    const std::string text = std::string("version: 1\nroom: ") + (scenes / "room" / room).string() +
                             "\nct: {path: builtin:phantom}\n";
    auto scene = parse_scene(text, "patient.yaml", scenes);
    ASSERT_TRUE(scene.ok()) << room << ": " << scene.status().message();
    EXPECT_EQ(scene->detectors.size(), 2u) << room;
  }
  for (const char* name : {"lumbar-ct.yaml", "thoracic-ct.yaml", "lumbar-ct-clinical.yaml", "thoracic-ct-clinical.yaml"}) {
    auto scene = load_scene((scenes / name).string());
    ASSERT_TRUE(scene.ok()) << name << ": " << scene.status().message();
    EXPECT_FALSE(scene->room_file.empty()) << name;
  }
}

}  // namespace
}  // namespace lftrack::session

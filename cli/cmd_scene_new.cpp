// `lftrack scene new`: a new patient's scene from the CT, the treatment plan's isocentre, the
// structure set's target and a room file (issue 53); with a picture to confirm it before the
// first beam. The scene is written only when it loads as any scene does, and never over a file.

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <memory>

#include "cli_commands.hpp"
#include "lftrack/session/patient_setup.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/session/setup_picture.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/registration.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "lftrack/tracking/volume_io.hpp"

namespace lftrack::cli {

using session::compose_new_scene;
using session::make_scene_registration;
using session::NewSceneCt;
using session::NewSceneRequest;
using session::parse_scene;
using session::prepare_scene;
using session::printable;
using session::read_ct_dicom_identity;
using session::read_rt_structure_set;
using session::setup_picture;
using session::SetupMarks;
using session::structure_list;
namespace {

namespace fs = std::filesystem;

struct SceneNewOptions {
  std::string ct, room, out, rtplan, beam, rtstruct, target, name;
  std::vector<double> isocentre;
  double roi_margin_mm = 10;
  std::optional<double> roi_mask_margin_mm;
  bool list_structures = false;
  bool precompute = false;
  int threads = 0;
  std::string command_line;
};

// The scene's file: a new .yaml in a folder that exists, not the CT's DICOM folder (every file
// there is read as a slice); neither it nor its picture a file that is there.
Status check_scene_path(const fs::path& out, const fs::path& picture, const fs::path& ct) {
  if (out.extension() != ".yaml") return invalid_argument(out.string() + ": a scene is a .yaml file");
  std::error_code ec;
  for (const fs::path& file : {out, picture})
    if (fs::exists(fs::symlink_status(file, ec)))
      return failed_precondition(file.string() + ": already there; a scene and its picture are never written over "
                                                 "(choose another name, or remove it first)");
  const fs::path folder = out.parent_path().empty() ? fs::path(".") : out.parent_path();
  if (!fs::is_directory(folder, ec)) return invalid_argument(out.string() + ": no folder " + folder.string());
  if (fs::is_directory(ct, ec) && fs::equivalent(folder, ct, ec))
    return invalid_argument(out.string() + ": in the CT's DICOM folder, where every file is read as a slice; write "
                                           "the scene beside it");
  return {};
}

// `bytes` in a new file beside `beside` that no other run can have named.
Result<fs::path> write_temporary(const fs::path& beside, const std::string& bytes) {
  std::string name = ((beside.parent_path().empty() ? fs::path(".") : beside.parent_path()) / ".lftrack-scene-new-XXXXXX").string();
  const int fd = ::mkstemp(name.data());
  if (fd < 0) return io_error(beside.string() + ": cannot write in its folder: " + std::strerror(errno));
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    done += std::size_t(n);
  }
  const bool written = done == bytes.size() && ::fsync(fd) == 0;
  const std::string why = std::strerror(errno);
  if (::close(fd) != 0 || !written) {
    ::unlink(name.c_str());
    return io_error(beside.string() + ": write failed: " + why);
  }
  const mode_t mask = ::umask(0);  // mkstemp made it 0600: the mode any new file would have
  ::umask(mask);
  ::chmod(name.c_str(), 0666 & ~mask);
  return fs::path(name);
}

// Gives `temporary` the name `file` unless a file has it (link(): atomic, never over a file).
Status claim(const fs::path& temporary, const fs::path& file) {
  const int rc = ::link(temporary.c_str(), file.c_str());
  const int error = errno;
  ::unlink(temporary.c_str());
  if (rc == 0) return {};
  return error == EEXIST ? failed_precondition(file.string() + ": already there (another run wrote it); a scene and "
                                                               "its picture are never written over")
                         : io_error(file.string() + ": cannot create: " + std::strerror(error));
}

// An argument as a shell takes it back: as it is when it is plain, else in single quotes.
std::string shell_quoted(const std::string& arg) {
  const bool plain = !arg.empty() && std::all_of(arg.begin(), arg.end(), [](unsigned char c) {
    return std::isalnum(c) || std::strchr("_-./,=:+@%", c) != nullptr;
  });
  if (plain) return arg;
  std::string out = "'";
  for (char c : arg) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

Status list_structures(const SceneNewOptions& o) {
  auto set = read_rt_structure_set(o.rtstruct);
  if (!set.ok()) return set.status();
  std::printf("%s: structure set '%s', %zu structures\n%s", o.rtstruct.c_str(), set->label.c_str(),
              set->structures.size(), structure_list(*set).c_str());
  return {};
}

Status run(const SceneNewOptions& o) {
  if (o.list_structures) return list_structures(o);
  const fs::path out(o.out);
  const fs::path picture_file = out.parent_path() / (out.stem().string() + "-setup.png");
  LFTRACK_RETURN_IF_ERROR(check_scene_path(out, picture_file, o.ct));

  NewSceneRequest request;
  request.ct = o.ct;
  request.room = o.room;
  request.output = out;
  request.rtplan = o.rtplan;
  request.beam = o.beam;
  request.rtstruct = o.rtstruct;
  request.target = o.target;
  if (!o.isocentre.empty()) request.isocentre_ct_mm = Eigen::Vector3d(o.isocentre[0], o.isocentre[1], o.isocentre[2]);
  request.roi_margin_mm = o.roi_margin_mm;
  request.roi_mask_margin_mm = o.roi_mask_margin_mm;
  request.name = o.name;
  request.command_line = o.command_line;

  auto ct = tracking::read_ct(o.ct);
  if (!ct.ok()) return ct.status();
  NewSceneCt scene_ct;
  scene_ct.volume = &*ct;
  std::error_code ec;
  if (fs::is_directory(o.ct, ec)) {
    auto identity = read_ct_dicom_identity(o.ct);
    if (!identity.ok()) return identity.status();
    scene_ct.identity = *identity;
  }
  auto setup = compose_new_scene(request, scene_ct);
  if (!setup.ok()) return setup.status();

  // The scene must load and prepare as any scene does before it is written.
  const fs::path folder = fs::absolute(out).parent_path();
  auto scene = parse_scene(setup->yaml, out.string() + " (not written)", folder);
  if (!scene.ok()) return Status(scene.status().code(), "the new scene does not load: " + scene.status().message());
  tracking::ThreadPool pool(o.threads);
  auto prepared = prepare_scene(*scene, "", &pool);
  if (!prepared.ok()) return prepared.status();

  // roi.mask: the room's plans must be able to register what it keeps (every binned level).
  if (!prepared->roi_masks.empty()) {
    tracking::RendererOptions options;
    options.pool = &pool;
    auto renderer = tracking::make_renderer("siddon", prepared->mu, options);
    if (!renderer.ok()) return renderer.status();
    auto registration = make_scene_registration(*prepared, std::move(renderer).value(), prepared->scene.registration, &pool);
    if (!registration.ok()) return Status(registration.status().code(), "roi.mask: " + registration.status().message());
    for (const auto& [key, name] : {std::pair<const char*, std::string>{"loop.align_plan", prepared->scene.loop.align_plan},
                                    {"loop.track_plan", prepared->scene.loop.track_plan}}) {
      auto plan = tracking::registration_plan(name);
      if (!plan.ok()) continue;  // the scene's own check names it
      if (auto prepared_plan = (*registration)->prepare_plan(*plan); !prepared_plan.ok())
        return Status(prepared_plan.status().code(), std::string("roi.mask: the room's ") + key + " '" + name +
                                                         "' cannot register what the mask keeps: " +
                                                         prepared_plan.status().message() +
                                                         " (a wider --roi-mask-mm, or no mask)");
    }
  }
  SetupMarks marks;
  marks.isocentre_ct_mm = setup->isocentre_ct_mm;
  marks.roi_centre_ct_mm = setup->roi_centre_ct_mm;
  marks.roi_size_mm = setup->roi_size_mm;
  marks.target_polygons = setup->target_polygons;
  marks.target = setup->target ? &*setup->target : nullptr;
  auto picture = setup_picture(*prepared, marks, &pool);
  if (!picture.ok()) return picture.status();
  // Both files are written under names no other run can have, then take their own names, the
  // scene first: a run that finds the scene taken writes nothing, and the picture beside a scene
  // is always that scene's.
  auto picture_tmp = write_temporary(out, "");
  if (!picture_tmp.ok()) return picture_tmp.status();
  if (Status s = tracking::write_rgb_png(*picture_tmp, *picture); !s.ok()) {
    ::unlink(picture_tmp->c_str());
    return s;
  }
  auto scene_tmp = write_temporary(out, setup->yaml);
  if (!scene_tmp.ok()) {
    ::unlink(picture_tmp->c_str());
    return scene_tmp.status();
  }
  if (Status s = claim(*scene_tmp, out); !s.ok()) {
    ::unlink(picture_tmp->c_str());
    return s;
  }
  if (Status s = claim(*picture_tmp, picture_file); !s.ok()) {
    ::unlink(out.c_str());
    return s;
  }

  const Eigen::Vector3d& iso = setup->isocentre_ct_mm;
  std::printf("scene       %s\n", out.c_str());
  std::printf("isocentre   (%.2f, %.2f, %.2f) mm (CT frame), from %s\n", iso.x(), iso.y(), iso.z(),
              printable(setup->isocentre_from).c_str());
  std::printf("patient     %s\n", setup->patient_position.c_str());
  std::printf("roi         centre (%.1f, %.1f, %.1f) mm, size (%.1f, %.1f, %.1f) mm", setup->roi_centre_ct_mm.x(),
              setup->roi_centre_ct_mm.y(), setup->roi_centre_ct_mm.z(), setup->roi_size_mm.x(), setup->roi_size_mm.y(),
              setup->roi_size_mm.z());
  if (setup->target)
    std::printf(", about target '%s' (%.1f cc)", printable(setup->target_name).c_str(), setup->target->volume_cc());
  std::printf("\npicture     %s (top: each view's DRR; bottom: axial, coronal, sagittal; green the isocentre, "
              "yellow the ROI, red the target, cyan roi.mask's edge)\n",
              picture_file.c_str());
  for (const std::string& w : setup->warnings) spdlog::warn("{}", w);
  if (o.precompute) {
    if (Status s = precompute_light_fields(*prepared, "", &pool); !s.ok())
      return Status(s.code(), "the scene and its picture are written; its light fields are not (lftrack precompute "
                              "--scene " + out.string() + " builds them): " + s.message());
  }
  std::printf("next        look at the picture, then:\n");
  if (!o.precompute) std::printf("              build/bin/lftrack precompute --scene %s\n", out.c_str());
  std::printf("              build/bin/lftrack commission --scene %s   (the verdict's floors)\n", out.c_str());
  std::printf("              build/bin/lftrack register --scene %s --sim\n", out.c_str());
  std::printf("              build/bin/lftrack sim --scene %s\n", out.c_str());
  return {};
}

}  // namespace

Command add_scene_new_command(CLI::App* parent, int argc, char** argv) {
  auto* app = parent->add_subcommand(
      "new", "A new patient's scene from the CT, the plan's isocentre, the target's contours and a room file");
  auto o = std::make_shared<SceneNewOptions>();
  // The command as a user types it, for the scene's header: the program by its name.
  for (int i = 0; i < argc; ++i)
    o->command_line += std::string(i ? " " : "") + (i == 0 ? fs::path(argv[0]).filename().string() : shell_quoted(argv[i]));
  app->add_option("--ct", o->ct, "The planning CT: a DICOM series' folder or a NIfTI file")->check(not_empty());
  app->add_option("--room", o->room, "The room file: views, detectors, couch, imaging (scenes/room/*.yaml)")
      ->check(not_empty());
  app->add_option("-o,--out", o->out, "The scene to write (.yaml; never over a file); its picture goes beside it")
      ->check(not_empty());
  auto* plan = app->add_option("--rtplan", o->rtplan, "DICOM RT Plan: its isocentre, patient position, tolerances")
                   ->check(not_empty());
  app->add_option("--beam", o->beam, "The plan's beam whose isocentre to take (number or name; default: all beams, "
                                     "which must share one)")
      ->needs(plan)
      ->check(not_empty());
  auto* rtstruct =
      app->add_option("--rtstruct", o->rtstruct, "DICOM RT Structure Set: the target's contours")->check(not_empty());
  app->add_option("--target", o->target, "The target's structure name (--list-structures lists them)")
      ->needs(rtstruct)
      ->check(not_empty());
  app->add_flag("--list-structures", o->list_structures, "List the structure set's structures and exit")
      ->needs(rtstruct);
  app->add_option("--isocentre", o->isocentre, "The isocentre X,Y,Z in mm, CT frame (a CT without a plan)")
      ->expected(3)
      ->delimiter(',')
      ->check(finite_in(-10000, 10000))
      ->excludes(plan);
  app->add_option("--roi-margin-mm", o->roi_margin_mm, "Margin around the target's box, each side (default 10)")
      ->check(finite_in(0, 100))
      ->needs(rtstruct);
  app->add_option("--roi-mask-mm", o->roi_mask_margin_mm,
                  "Register only the target and this margin around it in each view (roi.mask; default: the whole ROI)")
      ->check(finite_in(0, 50))
      ->needs(rtstruct);
  app->add_option("--name", o->name, "The scene's name (default: the file's)")->check(not_empty());
  app->add_flag("--precompute", o->precompute, "Build the light fields at once");
  app->add_option("--threads", o->threads, "Threads (0: all cores)")->check(CLI::Range(0, 1024));
  // --ct, --room and -o are needed unless the structures are only listed: a usage error (exit 2).
  app->callback([o] {
    if (o->list_structures) return;
    const std::pair<bool, const char*> needed[] = {{!o->ct.empty(), "--ct"}, {!o->room.empty(), "--room"}, {!o->out.empty(), "-o"}};
    for (const auto& [given, name] : needed)
      if (!given) throw CLI::RequiredError(std::string(name) + " (unless --rtstruct FILE --list-structures)");
  });
  return [o] { return run(*o); };
}

}  // namespace lftrack::cli

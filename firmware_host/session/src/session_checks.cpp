// A loop session's options and scene judged before anything is made (session_parts.hpp,
// check_session_options in loop_session.hpp): refusals, and warnings the scene's author should read.

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>

#include "lftrack/loop/motion_predictor.hpp"
#include "lftrack/session/scene_devices.hpp"
#include "lftrack/watch/operator_token.hpp"
#include "session_parts.hpp"

namespace lftrack::session {

using loop::check_archive_directory;
using loop::check_auto_resume_s;
using loop::check_journal_path;
using loop::ControlSocket;
using loop::loop_period_ns;
using loop::LoopSettings;
using loop::LoopSpec;
using loop::MotionPredictor;
using loop::prediction_lookahead_s;

using watch::check_monitor_origins;
using watch::ListenAddress;
using watch::open_listening_socket;
using watch::TokenFile;
namespace {

// The journal, the archive and the control socket are three different places: a socket opened
// over the journal (or the other way round) would lose the record.
Status check_distinct_paths(const LoopSessionOptions& o) {
  namespace fs = std::filesystem;
  const auto same = [](const fs::path& a, const fs::path& b) {
    return !a.empty() && !b.empty() && fs::weakly_canonical(a) == fs::weakly_canonical(b);
  };
  const auto inside = [](const fs::path& file, const fs::path& dir) {
    if (file.empty() || dir.empty()) return false;
    const fs::path f = fs::weakly_canonical(file), d = fs::weakly_canonical(dir);
    const auto mismatch = std::mismatch(d.begin(), d.end(), f.begin(), f.end());
    return mismatch.first == d.end();
  };
  if (same(o.control_socket, o.journal))
    return invalid_argument("--control and --journal name the same file " + o.journal.string());
  if (inside(o.control_socket, o.archive) || inside(o.journal, o.archive))
    return invalid_argument("the journal and the control socket cannot be inside the frame archive " +
                            o.archive.string());
  if (inside(o.journal, o.replay_sequence) || inside(o.archive, o.replay_sequence))
    return invalid_argument("the journal and the archive cannot be inside the replayed sequence " +
                            o.replay_sequence.string());
  return {};
}

}  // namespace

// A prediction window too short for its order is not an error (the predictor drops to a line, or
// to the newest estimate, MotionPredictor::kMaxNoiseGain), but the scene's author should know.
void warn_if_prediction_window_short(const LoopSettings& s) {
  const LoopSpec& l = s.loop;
  if (l.prediction_cycles < 2) return;
  const double lookahead_s = prediction_lookahead_s(s);
  const MotionPredictor::FullWindow w = MotionPredictor::full_window(
      l.prediction_cycles, l.prediction_order, 1e-9 * double(loop_period_ns(s)), lookahead_s);
  if (w.order_used >= l.prediction_order) return;
  const std::string used = w.order_used == 1 ? fmt::format("a line (noise gain {:.2f})", w.gain_used)
                                             : std::string("the newest estimate alone");
  const std::string advice = "a longer prediction_cycles or a lower prediction_order says so";
  if (!std::isfinite(w.gain_configured)) {
    spdlog::warn(
        "loop: prediction_order {} needs at least {} prediction_cycles ({} given): the loop predicts with "
        "{}; {}",
        l.prediction_order, l.prediction_order + 2, l.prediction_cycles, used, advice);
    return;
  }
  spdlog::warn(
      "loop: prediction_order {} over prediction_cycles {} ({} ms apart, {:.3f} s ahead) would multiply the "
      "registration's noise by {:.2f}, more than {}: the loop predicts with {}; {}",
      l.prediction_order, l.prediction_cycles, l.period_ms, lookahead_s, w.gain_configured,
      MotionPredictor::kMaxNoiseGain, used, advice);
}

// An actuator whose largest allowed move (safety.max_total_mm at the speed the scene gives it,
// after its latency) takes longer than the beam may wait: such a move would end in a HOLD
// "patient not in place" before the couch arrives. Every type that moves has these dynamics
// (drivers::ActuatorDynamics): the virtual couch moves so; a device is assumed to.
void warn_if_beam_wait_short(const Scene& scene) {
  if (scene.actuator.type == "none") return;
  const drivers::ActuatorDynamics& couch = scene.actuator.dynamics;
  const double largest_move_s = scene.safety.max_total_mm / couch.max_speed_mm_s + couch.latency_s;
  if (largest_move_s < scene.safety.max_beam_withheld_s) return;
  spdlog::warn(
      "safety: the couch's largest allowed move ({} mm at {} mm/s after {} s) takes {:.1f} s, not less than "
      "safety.max_beam_withheld_s ({} s): a move that large ends in a HOLD \"patient not in place\" before "
      "it "
      "is made; a longer max_beam_withheld_s or a smaller max_total_mm says so",
      scene.safety.max_total_mm, couch.max_speed_mm_s, couch.latency_s, largest_move_s,
      scene.safety.max_beam_withheld_s);
}

// A watcher's port that is taken now is refused before minutes of preparation (a later bind
// can still fail; the server says so then).
static Status check_watcher_ports(const LoopSessionOptions& o) {
  if (o.monitor && o.igtl && o.monitor->listen.port != 0 && o.monitor->listen.port == o.igtl->listen.port)
    return invalid_argument("--monitor and --igtl name the same port " + std::to_string(o.igtl->listen.port));
  if (o.monitor) LFTRACK_RETURN_IF_ERROR(check_monitor_origins(*o.monitor));
  for (const ListenAddress* at :
       {o.monitor ? &o.monitor->listen : nullptr, o.igtl ? &o.igtl->listen : nullptr}) {
    if (at == nullptr || at->port == 0) continue;
    int port = 0;
    auto fd = open_listening_socket(*at, &port);
    if (!fd.ok())
      return fd.status().with_context(o.monitor && at == &o.monitor->listen ? "--monitor" : "--igtl");
    ::close(*fd);
  }
  return {};
}

Status check_session_options(const LoopSessionOptions& o) {
  if (o.auto_resume_s) LFTRACK_RETURN_IF_ERROR(check_auto_resume_s(*o.auto_resume_s));
  LFTRACK_RETURN_IF_ERROR(check_watcher_ports(o));
  LFTRACK_RETURN_IF_ERROR(check_distinct_paths(o));
  if (!o.control_socket.empty()) LFTRACK_RETURN_IF_ERROR(ControlSocket::check_path(o.control_socket));
  if (!o.journal.empty() && !o.journal_options.add_suffix)
    LFTRACK_RETURN_IF_ERROR(check_journal_path(o.journal, o.journal_options.overwrite));
  if (!o.archive.empty()) LFTRACK_RETURN_IF_ERROR(check_archive_directory(o.archive, o.overwrite_archive));
  // What would otherwise be found only after the CT load and minutes of light-field building
  // (issue 50 probe): a light-field folder that is a file, a sequence that is not there, a token
  // file that is another's.
  std::error_code ec;
  if (!o.light_field_dir.empty() && std::filesystem::exists(o.light_field_dir, ec) &&
      !std::filesystem::is_directory(o.light_field_dir, ec))
    return failed_precondition("--lf-dir " + o.light_field_dir.string() + ": not a folder");
  if (!o.replay_sequence.empty() && !std::filesystem::is_directory(o.replay_sequence, ec))
    return not_found(o.replay_sequence.string() + ": no such sequence directory");
  if (o.monitor && !o.monitor->token_file.empty())
    LFTRACK_RETURN_IF_ERROR(TokenFile::check(o.monitor->token_file).with_context("--monitor-token-file"));
  return {};
}

// The real devices a session opens (the scene's V4L2 or GigE detectors, Modbus couch or CAN robot
// under kScene), in words; empty when every device is simulated or replayed.
static std::string real_devices(const PreparedScene& p, const LoopSessionOptions& o) {
  if (o.devices != SessionDevices::kScene) return {};
  std::string devices;
  if (o.replay_sequence.empty() && !p.scene.detectors.empty() &&
      frames_from_device(p.scene.detectors[0].frames))
    devices = "detectors " + describe_frames(p.scene.detectors[0].frames) +
              (p.scene.detectors.size() > 1 ? ", ..." : "");
  if (actuator_is_device(p.scene))
    devices += (devices.empty() ? "" : "; ") + describe_actuator(p.scene.actuator);
  return devices;
}

// In the room a HOLD ends only by a person's decision: a session on real devices takes no
// unattended operator (auto_resume_s, or an unattended input among the hooks), whoever asks.
Status check_attended(const PreparedScene& p, const LoopSessionOptions& o) {
  const std::string devices = real_devices(p, o);
  if (devices.empty()) return {};
  std::string unattended;
  if (o.auto_resume_s)
    unattended = fmt::format("an automatic resume {} s into each HOLD", *o.auto_resume_s);
  else if (o.hooks.operator_input != nullptr && o.hooks.operator_input->unattended())
    unattended = "a scripted operator";
  if (unattended.empty()) return {};
  return failed_precondition(
      "the room's devices (" + devices + ") take no unattended operator (" + unattended +
      "): a HOLD there ends only by a person's decision (the terminal, the control socket or "
      "the monitor page)");
}

}  // namespace lftrack::session

// `lftrack serve detectors --scene FILE`: the scene's simulated detectors as GigE Vision cameras
// of their own process (sim/gige_fake_detector.hpp), whose frames are the simulator's X-rays of
// the simulated patient (16-bit mono), where the served couch has moved them (--room: its room
// link). `lftrack run` reads them through the real GigE driver.
//
// One camera per detector, each on an IPv4 address of its own (GigE Vision's control port is
// fixed; sim/gige_fake_detector.hpp): --address per detector, by default 127.0.0.1, 127.0.0.2 and
// so on. Each camera's trigger renders the pair at that moment (the second camera's trigger
// within 5 ms shares it). The frames' truth (the residual of the simulated patient) is
// summarised at the end.

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstring>
#include <cstdio>
#include <mutex>
#include <nlohmann/json.hpp>

#include "lftrack/session/scene_devices.hpp"
#include "lftrack/session/scene_registration.hpp"
#include "lftrack/sim/gige_fake_detector.hpp"
#include "lftrack/sim/v4l2_loopback_writer.hpp"
#include "lftrack/sim_devices/room_simulator.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"
#include "lftrack/sim_devices/sim_frame_source.hpp"
#include "lftrack/tracking/thread_pool.hpp"
#include "serve_common.hpp"

namespace lftrack::cli {

using sim_devices::SimFrameSource;

using session::load_scene;
using session::prepare_scene;
using session::PreparedScene;
using session::Scene;
using session::served_twin_id;
using session::SimFrameSourceOptions;
using sim_devices::make_scene_patient;
using sim_devices::make_sim_frame_renderer;
using sim_devices::scene_room_spec;
using sim_devices::sim_frame_margin_px;
namespace {

using namespace serve;

// The simulated room and its detectors, rendering a pair whenever a camera asks, at that moment.
class DetectorRoom {
 public:
  static Result<std::unique_ptr<DetectorRoom>> start(const PreparedScene& p, const ServeOptions& o,
                                                     tracking::ThreadPool* pool) {
    std::unique_ptr<DetectorRoom> r(new DetectorRoom(p));
    auto patient = make_scene_patient(p, o.lf_dir, pool);  // realistic physics (null: ideal frames)
    if (!patient.ok()) return patient.status();
    if (!*patient) {
      auto renderer = make_sim_frame_renderer(p, o.lf_dir, pool);
      if (!renderer.ok()) return renderer.status();
      r->renderer_ = *renderer;
    }
    sim::SimulatedRoomSpec room = scene_room_spec(p);  // the couch mounted as the scene says
    if (!o.room.empty()) {
      auto link = sim::RoomLinkReader::open(o.room);
      if (!link.ok()) return link.status();
      room.couch_link = std::move(link).value();
    } else {
      spdlog::warn("no --room: the patient is not moved by any couch (the frames show the set-up error and motion)");
    }
    r->room_ = std::make_unique<sim::SimulatedRoom>(room);
    SimFrameSourceOptions frames;
    frames.wait_for_frames = false;
    frames.detectors.margin_px = sim_frame_margin_px(p);
    r->frames_ = std::make_unique<SimFrameSource>(p, r->renderer_, r->room_.get(), frames, *patient);
    LFTRACK_RETURN_IF_ERROR(r->frames_->open(&r->pair_));
    return r;
  }
  ~DetectorRoom() {
    if (frames_) frames_->close();
  }

  // The pair exposed now, rendered once per exposure: a camera that asks gets the newest pair if
  // it has not had it yet and it is under 40 ms old (the other camera's trigger of the same
  // exposure), else a new pair. Copies detector `index`'s pixels (rows x cols) into `out` under
  // the lock: each camera asks from its own thread, and a pair rendered for one must never be
  // rewritten while the other copies it (a half-rendered frame once reached the loop, which held
  // on a 9 mm step). False, with nothing copied, if rendering failed or the size differs.
  bool copy_frame(std::size_t index, std::uint16_t* out, int rows, int cols) {
    std::lock_guard lock(mutex_);
    const tracking::Image<std::uint16_t>* f = frame_locked(index);
    if (f == nullptr || f->rows() != rows || f->cols() != cols) return false;
    std::memcpy(out, &f->at(0, 0), std::size_t(rows) * std::size_t(cols) * sizeof(std::uint16_t));
    return true;
  }

 private:
  const tracking::Image<std::uint16_t>* frame_locked(std::size_t index) {
    const std::int64_t now = monotonic_ns();
    if (taken_.size() <= index) taken_.resize(index + 1, -1);
    if (!have_ || taken_[index] >= pair_number_ || now - exposed_ns_ > 40'000'000) {
      ++pair_number_;
      if (exposures_ == 0) start_ns_ = now;  // the settle time counts from the first exposure
      frames_->request_exposure(now);
      have_ = frames_->acquire(&pair_, std::chrono::steady_clock::now() + std::chrono::seconds(2)) ==
              drivers::DeviceStatus::kOk;
      render_ms_.push_back(1e-6 * double(monotonic_ns() - now));
      exposed_ns_ = now;
      if (have_ && 1e-9 * double(now - start_ns_) >= settle_s_) residuals_.push_back(room_->residual_mm());
      ++exposures_;
    }
    taken_[index] = pair_number_;
    return have_ && index < pair_.frames.size() ? &pair_.frames[index].pixels : nullptr;
  }

 public:
  void set_settle(double s) { settle_s_ = s; }
  nlohmann::json truth() {
    std::lock_guard lock(mutex_);
    nlohmann::json j = {{"exposures", exposures_}, {"residual_frames", residuals_.size()}};
    if (!render_ms_.empty()) {
      std::vector<double> v = render_ms_;
      std::sort(v.begin(), v.end());
      j["render_ms"] = {{"p50", v[v.size() / 2]}, {"p99", v[std::min(v.size() - 1, std::size_t(0.99 * double(v.size())))]},
                        {"max", v.back()}};
    }
    if (!residuals_.empty()) {
      std::vector<double> v = residuals_;
      std::sort(v.begin(), v.end());
      double sum = 0;
      for (double x : v) sum += x;
      j["residual_mean_mm"] = sum / double(v.size());
      j["residual_p95_mm"] = v[std::min(v.size() - 1, std::size_t(0.95 * double(v.size())))];
      j["residual_max_mm"] = v.back();
    }
    return j;
  }

 private:
  explicit DetectorRoom(const PreparedScene& p) : scene_(p) {}
  static std::int64_t monotonic_ns() {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
  }
  const PreparedScene& scene_;
  std::shared_ptr<const tracking::DrrRenderer> renderer_;
  std::unique_ptr<sim::SimulatedRoom> room_;
  std::unique_ptr<SimFrameSource> frames_;
  drivers::FramePair pair_;
  std::mutex mutex_;
  bool have_ = false;
  std::int64_t exposed_ns_ = 0, start_ns_ = 0, exposures_ = 0, pair_number_ = 0;
  std::vector<std::int64_t> taken_;  // per detector: the last pair it was given
  double settle_s_ = 2;
  std::vector<double> residuals_;
  std::vector<double> render_ms_;  // trigger to the pair rendered
};

// The faults each kind of detector server takes (--fault, `fault KIND` on the control socket).
std::map<std::string, int> loopback_fault_kinds() { return {{"stop", 0}, {"start", 1}}; }
std::map<std::string, int> gige_fault_kinds() { return {{"stop", 0}, {"start", 1}, {"power-cycle", 2}}; }

// --v4l2loopback: the pair written into loopback devices every period (free-running), for
// `run` to read through the kernel's V4L2 capture path.
Status serve_v4l2_loopback(const Scene& scene, const ServeOptions& o, DetectorRoom* r) {
  std::vector<std::unique_ptr<sim::V4l2LoopbackWriter>> writers;
  for (std::size_t i = 0; i < o.loopback.size(); ++i) {
    writers.push_back(std::make_unique<sim::V4l2LoopbackWriter>());
    LFTRACK_RETURN_IF_ERROR(writers.back()->open(o.loopback[i], scene.detectors[i].view.rows, scene.detectors[i].view.cols));
  }
  std::string listening;
  for (const std::string& d : o.loopback) listening += (listening.empty() ? "" : ", ") + d;
  const auto announce = [&] {
    std::printf("lftrack serve detectors: v4l2loopback %s%s%s\n", listening.c_str(),
                o.room.empty() ? "" : "; room link ", o.room.c_str());
  };
  std::vector<tracking::Image<std::uint16_t>> copies;
  for (std::size_t i = 0; i < writers.size(); ++i)
    copies.emplace_back(scene.detectors[i].view.rows, scene.detectors[i].view.cols);
  std::atomic<bool> paused{false}, done{false};
  std::thread writer([&] {
    const auto period = std::chrono::microseconds(std::int64_t(scene.loop.period_ms * 1000));
    auto next = std::chrono::steady_clock::now();
    while (!done.load()) {
      next += period;
      if (!paused.load())
        for (std::size_t i = 0; i < writers.size(); ++i) {
          tracking::Image<std::uint16_t>& f = copies[i];
          if (r->copy_frame(i, &f.at(0, 0), f.rows(), f.cols()))
            if (Status s = writers[i]->write(&f.at(0, 0)); !s.ok()) spdlog::warn("{}", s.message());
        }
      std::this_thread::sleep_until(next);
    }
  });
  const std::map<std::string, int> kinds = loopback_fault_kinds();
  const Status served = serve_until_stopped(
      o, kinds,
      [&](const Fault& f) {
        paused.store(f.kind == "stop");
        return true;
      },
      [&] {
        return "frames written: " + std::to_string(writers[0]->frames()) +
               (paused.load() ? " (stopped)" : "");
      },
      announce);
  done.store(true);
  writer.join();
  LFTRACK_RETURN_IF_ERROR(served);
  nlohmann::json j = r->truth();
  j["device"] = "detectors";
  j["frames_written"] = writers[0]->frames();
  if (o.json)
    std::printf("%s\n", j.dump().c_str());
  else
    std::printf("served: %s\n", j.dump().c_str());
  return {};
}

Status serve_detectors(const ServeOptions& o) {
  if (auto checked = check_serve_options(o, o.loopback.empty() ? gige_fault_kinds() : loopback_fault_kinds());
      !checked.ok())
    return checked.status();
  LFTRACK_RETURN_IF_ERROR(check_seconds(o.settle_s, "--settle", 3600));
  auto scene = load_scene(o.scene.scene);
  if (!scene.ok()) return scene.status();
  const std::size_t views = scene->detectors.size();
  // By default loopback addresses, one per detector (127.0.0.1, 127.0.0.2, ...: the loopback
  // device answers the whole of 127.0.0.0/8): the cameras are reachable from this host only.
  std::vector<std::string> addresses = o.addresses;
  for (std::size_t k = 0; o.addresses.empty() && k < views; ++k)
    addresses.push_back("127.0.0." + std::to_string(k + 1));
  if (addresses.size() != views)
    return invalid_argument("give one --address per detector (" + std::to_string(views) + ")");
  if (!o.loopback.empty() && o.loopback.size() != views)
    return invalid_argument("give one --v4l2loopback device per detector (" + std::to_string(views) + ")");
  // Each twin's id is what the start-up checks tell the detectors apart by: two alike would let
  // swapped cameras pass.
  for (std::size_t a = 0; a < views; ++a)
    for (std::size_t b = a + 1; b < views; ++b)
      if (served_twin_id(scene->detectors[a].view.name) == served_twin_id(scene->detectors[b].view.name))
        return invalid_argument("detectors '" + scene->detectors[a].view.name + "' and '" +
                                scene->detectors[b].view.name + "' would be served with one device id (" +
                                served_twin_id(scene->detectors[a].view.name) +
                                "), so a swap could not be told apart: rename one");
  tracking::ThreadPool pool(o.scene.threads);
  auto prepared = prepare_scene(*scene, o.scene.ct, &pool);
  if (!prepared.ok()) return prepared.status();
  auto room = DetectorRoom::start(*prepared, o, &pool);
  if (!room.ok()) return room.status();
  (*room)->set_settle(o.settle_s);
  DetectorRoom* r = room->get();
  if (!o.loopback.empty()) return serve_v4l2_loopback(*scene, o, r);
  std::vector<std::unique_ptr<sim::GigeFakeDetector>> cameras;
  std::string listening;
  for (std::size_t k = 0; k < addresses.size(); ++k) {
    sim::GigeFakeDetectorOptions c;
    c.interface = addresses[k];
    c.serial = served_twin_id(scene->detectors[k].view.name);  // what the start-up checks expect of a twin
    c.rows = scene->detectors[k].view.rows;
    c.cols = scene->detectors[k].view.cols;
    auto render = [r, k](std::uint64_t, std::uint16_t* pixels, int rows, int cols) {
      if (!r->copy_frame(k, pixels, rows, cols))
        std::memset(pixels, 0, std::size_t(rows) * std::size_t(cols) * 2);  // an unexposed frame
    };
    cameras.push_back(std::make_unique<sim::GigeFakeDetector>(c, render));
    if (Status s = cameras.back()->start(); !s.ok()) return s;
    listening += (k ? ", " : "") + cameras.back()->address() + " (" + std::to_string(c.cols) + " x " +
                 std::to_string(c.rows) + ")";
  }
  const auto announce = [&] {
    std::printf("lftrack serve detectors: gige %s%s%s\n", listening.c_str(),
                o.room.empty() ? "" : "; room link ", o.room.c_str());
  };
  const std::map<std::string, int> kinds = gige_fault_kinds();
  const auto describe = [&] {
    std::string s = "frames served:";
    for (const auto& c : cameras) s += " " + std::to_string(c->frames_served()) + (c->running() ? "" : " (stopped)");
    return s;
  };
  LFTRACK_RETURN_IF_ERROR(serve_until_stopped(
      o, kinds,
      [&](const Fault& f) {
        for (auto& c : cameras) {
          if (f.kind != "start") c->stop();
          if (f.kind == "power-cycle") std::this_thread::sleep_for(std::chrono::milliseconds(100 * f.count));
          if (f.kind != "stop" && !c->start().ok()) return false;
        }
        return true;
      },
      describe, announce));
  nlohmann::json j = r->truth();
  j["device"] = "detectors";
  std::uint64_t served = 0;
  for (const auto& c : cameras) served += c->frames_served();
  j["frames_served"] = served;
  cameras.clear();
  if (o.json)
    std::printf("%s\n", j.dump().c_str());
  else
    std::printf("served: %s\n", j.dump().c_str());
  return {};
}

}  // namespace

Command add_serve_detectors_command(CLI::App* parent) {
  auto o = std::make_shared<ServeOptions>();
  CLI::App* app = parent->add_subcommand(
      "detectors", "The scene's simulated detectors as GigE Vision cameras, as their own process");
  add_common(app, o.get(),
             {"Scene whose detectors are served: their geometry and frames, the simulated patient and its motion",
              "Read where the served couch or robot has moved the patient from this room link file (theirs: serve "
              "couch|robot --room); without it the patient stays where the scene's motion puts them",
              kind_list(gige_fault_kinds()) + " (with --v4l2loopback: " + kind_list(loopback_fault_kinds()) + ")"});
  app->add_option(
      "--address", o->addresses,
      "IPv4 address (or interface) of each detector's camera, one per detector (default: 127.0.0.1, "
      "127.0.0.2, ...: this host only)");
  app->add_option("--v4l2loopback", o->loopback,
                  "Instead of GigE: write each detector's frames into this v4l2loopback device (one per detector), "
                  "every period, for `run` to read through V4L2");
  app->add_option("--lf-dir", o->lf_dir,
                  "Light-field folder of the frames' fields, when the scene's sim.renderer is lightfield (in "
                  "DIR/sim-frames; default out/lightfields/<scene>)");
  app->add_option("--settle", o->settle_s, "Summarise the residual of frames after this many seconds")
      ->check(finite_in(0, 3600))
      ->capture_default_str();
  app->add_option("--threads", o->scene.threads, "Worker threads rendering the frames (0: all cores)")
      ->check(CLI::Range(0, 256));
  CLI::Option* scene = app->get_option("--scene");
  scene->required();
  return [o] { return serve_detectors(*o); };
}

}  // namespace lftrack::cli

#include "lftrack/sim_devices/sim_frame_source.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"

#include "lftrack/loop/realtime_setup.hpp"

#include <time.h>
#include <algorithm>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <thread>

#include "lftrack/session/scene_registration.hpp"

namespace lftrack::sim_devices {

using session::PreparedScene;
using session::SimFrameSourceOptions;

using loop::lower_current_thread_priority;

using drivers::DeviceStatus;

SimFrameSource::SimFrameSource(const PreparedScene& scene,
                               std::shared_ptr<const tracking::DrrRenderer> renderer,
                               sim::SimulatedRoom* room, const SimFrameSourceOptions& options,
                               std::shared_ptr<const SimulatedPatient> patient)
    : scene_(scene),
      renderer_(std::move(renderer)),
      patient_(std::move(patient)),
      room_(room),
      options_(options),
      model_(scene_detector_model(scene)) {}

SimFrameSource::~SimFrameSource() {
  close();
}

Status SimFrameSource::open(drivers::FramePair* pair) {
  if ((!renderer_ && !patient_) || room_ == nullptr)
    return invalid_argument("sim frames: no renderer or room");
  if (thread_.joinable()) return failed_precondition("sim frames: already open");
  const std::size_t views = scene_.scene.detectors.size();
  pair->frames.assign(views, {});
  auto detectors = SimDetectors::create(scene_, renderer_, patient_, model_, options_.detectors);
  if (!detectors.ok()) return detectors.status().with_context("sim frames");
  detectors_ = std::move(detectors).value();
  rendered_ = detectors_->make_frames();
  for (std::size_t i = 0; i < views; ++i) {
    const auto& view = scene_.scene.detectors[i].view;
    pair->frames[i].pixels = tracking::Image<std::uint16_t>(view.rows, view.cols, 0);
  }
  stopping_ = false;
  has_pending_ = has_rendered_ = rendering_ = false;
  thread_ = std::thread([this] { render_loop(); });
  return {};
}

void SimFrameSource::close() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void SimFrameSource::request_exposure(std::int64_t exposure_time_ns) {
  room_->advance_to_ns(exposure_time_ns);
  Job job;
  job.exposure_ns = exposure_time_ns;
  job.pose_at_exposure = room_->spec().couch_link != nullptr && !options_.wait_for_frames;
  if (!job.pose_at_exposure) job.pose = room_->true_T_room_from_ct();
  {
    std::lock_guard lock(mutex_);
    job.index = next_index_++;
    pending_ = job;
    has_pending_ = true;
  }
  wake_.notify_one();
}

void SimFrameSource::render_loop() {
  // The simulated detectors stand for hardware running beside the host: they render while the
  // cycle sleeps and never preempt it.
  lower_current_thread_priority();
  for (;;) {
    Job job;
    {
      std::unique_lock lock(mutex_);
      wake_.wait(lock, [&] { return stopping_ || has_pending_; });
      if (stopping_) return;
      job = pending_;
      has_pending_ = false;
      rendering_ = true;
    }
    if (job.pose_at_exposure) {
      const timespec at{static_cast<time_t>(job.exposure_ns / 1'000'000'000),
                        static_cast<long>(job.exposure_ns % 1'000'000'000)};
      while (::clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &at, nullptr) == EINTR) {
      }
      // Where the served couch was at the exposure, not when this low-priority thread woke: on a
      // loaded host that can be tens of milliseconds later, after the couch has moved on while the
      // loop's read-back at the cycle's start saw it before the move.
      job.pose = room_->true_T_room_from_ct_at_exposure(job.exposure_ns);
    }
    Status status = detectors_->expose(
        job.pose, scene_.scene.sim.seed * 1000003ull + std::uint64_t(job.index) * 7919ull, &rendered_);
    {
      std::lock_guard lock(mutex_);
      rendering_ = false;
      has_rendered_ = true;
      rendered_job_ = job;
      render_status_ = std::move(status);
    }
    done_.notify_all();
  }
}

DeviceStatus SimFrameSource::acquire(drivers::FramePair* pair, drivers::Deadline deadline) {
  if (pair->frames.size() != rendered_.size()) return DeviceStatus::kFault;
  std::unique_lock lock(mutex_);
  const std::int64_t wanted = next_index_ - 1;
  if (wanted < 0) return DeviceStatus::kTimeout;  // nothing was requested
  if (wanted >= options_.drop_from && wanted < options_.drop_to) return DeviceStatus::kTimeout;
  if (wanted >= options_.stall_from && wanted < options_.stall_to && !options_.wait_for_frames) {
    lock.unlock();  // fault injection: the host stalls (the renderer keeps going)
    std::this_thread::sleep_for(std::chrono::microseconds(static_cast<long long>(options_.stall_ms * 1000)));
    lock.lock();
    deadline += std::chrono::microseconds(static_cast<long long>(options_.stall_ms * 1000));
  }
  auto ready = [&] { return !rendering_ && !has_pending_ && has_rendered_ && rendered_job_.index == wanted; };
  if (options_.wait_for_frames) {
    done_.wait(lock, ready);
  } else if (!done_.wait_until(lock, deadline, ready)) {
    return DeviceStatus::kTimeout;
  }
  if (!render_status_.ok()) return DeviceStatus::kFault;
  for (std::size_t v = 0; v < rendered_.size(); ++v) {
    drivers::Frame& frame = pair->frames[v];
    const tracking::PixelWindow w =
        detectors_->whole_detector() ? tracking::PixelWindow::full(frame.pixels.rows(), frame.pixels.cols())
                                     : detectors_->window(v);
    for (int r = w.row0; r < w.row0 + w.rows; ++r)
      std::memcpy(&frame.pixels.at(r, w.col0), &rendered_[v].at(r, w.col0),
                  sizeof(std::uint16_t) * std::size_t(w.cols));
    frame.sequence = static_cast<std::uint32_t>(wanted);
    frame.timestamp_ns = rendered_job_.exposure_ns +
                         (v == 1 ? static_cast<std::int64_t>(std::llround(options_.skew_ms * 1e6)) : 0);
  }
  return DeviceStatus::kOk;
}

}  // namespace lftrack::sim_devices

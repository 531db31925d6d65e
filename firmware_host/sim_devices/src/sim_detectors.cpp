#include "lftrack/sim_devices/sim_detectors.hpp"
#include "lftrack/sim_devices/scene_sim_frames.hpp"

#include "lftrack/session/scene_registration.hpp"

namespace lftrack::sim_devices {

using session::PreparedScene;
using session::SimDetectorsOptions;

Result<SimDetectors> SimDetectors::create(const PreparedScene& p,
                                          std::shared_ptr<const tracking::DrrRenderer> ideal,
                                          std::shared_ptr<const SimulatedPatient> patient,
                                          const sim::DetectorModel& model, const SimDetectorsOptions& o) {
  if (!ideal && !patient) return invalid_argument("sim detectors: no renderer and no patient");
  SimDetectors d;
  d.scene_ = &p;
  d.ideal_ = std::move(ideal);
  d.patient_ = std::move(patient);
  // Ideal frames' surround: Siddon over a coarse copy of the anatomy the frame renderer renders
  // (a light field made for the ROI covers nothing outside it).
  if (o.whole_detector && !d.patient_) {
    if (!p.world_mu)
      return invalid_argument("sim detectors: the scene has no anatomy to render outside the ROI");
    auto siddon = tracking::make_renderer(
        "siddon", std::make_shared<const tracking::MuVolume>(sim::surround_volume(*p.world_mu)));
    if (!siddon.ok()) return siddon.status().with_context("sim detectors, outside the ROI");
    d.surround_ideal_ = std::move(siddon).value();
  }
  if (o.whole_detector && d.patient_) {
    const sim::PatientRenderers surround = d.patient_->surround_renderers();
    if (surround.attenuation == nullptr && surround.water == nullptr)
      return invalid_argument("sim detectors: the patient was made without its surround renderers");
  }
  const sim_spec::XrayPhysicsSpec physics = d.patient_ ? p.scene.sim.physics : sim_spec::XrayPhysicsSpec{};
  for (std::size_t i = 0; i < p.scene.detectors.size(); ++i) {
    const auto& view = p.scene.detectors[i].view;
    const tracking::PixelWindow window = sim_frame_window(p, int(i), o.margin_px);
    const double pitch_mm = 0.5 * (view.pitch_col_mm + view.pitch_row_mm);
    if (d.patient_) {  // realistic physics: the detector's own fixed pattern, lag kept between frames
      auto s = sim::FrameSynthesizer::create(window, model, physics, view.rows, view.cols, pitch_mm, i + 1);
      if (!s.ok()) return s.status().with_context("sim detectors, detector " + view.name);
      d.synthesizers_.push_back(std::move(s).value());
    } else {
      d.synthesizers_.push_back(std::make_unique<sim::FrameSynthesizer>(window, model));
    }
    if (o.whole_detector) {
      auto s =
          sim::SurroundSynthesizer::create(window, model, physics, view.rows, view.cols, pitch_mm, i + 1);
      if (!s.ok())
        return s.status().with_context("sim detectors, detector " + view.name + " outside the ROI");
      d.surrounds_.push_back(std::move(s).value());
    }
  }
  return d;
}

Status SimDetectors::expose(const tracking::Pose& pose, std::uint64_t seed,
                            std::vector<tracking::Image<std::uint16_t>>* frames) {
  if (frames->size() != synthesizers_.size()) return invalid_argument("sim detectors: one frame per view");
  sim::PatientRenderers surround;
  if (patient_) {
    surround = patient_->surround_renderers();
  } else {
    surround.attenuation = surround_ideal_.get();
  }
  for (std::size_t v = 0; v < synthesizers_.size(); ++v) {
    const tracking::XrayView& view = scene_->scene.detectors[v].view;
    tracking::ImageView<std::uint16_t> frame = (*frames)[v].view();
    const std::uint64_t view_seed = seed + v;
    LFTRACK_RETURN_IF_ERROR(
        patient_ ? synthesizers_[v]->synthesize(patient_->renderers(), pose, view, view_seed, frame)
                 : synthesizers_[v]->synthesize(*ideal_, pose, view, view_seed, frame));
    if (v < surrounds_.size())
      LFTRACK_RETURN_IF_ERROR(
          surrounds_[v]->synthesize(surround, pose, view, view_seed ^ 0x5a5a5a5a5a5a5a5aull, frame));
  }
  return {};
}

std::vector<tracking::Image<std::uint16_t>> SimDetectors::make_frames() const {
  std::vector<tracking::Image<std::uint16_t>> frames;
  for (const auto& d : scene_->scene.detectors) frames.emplace_back(d.view.rows, d.view.cols, 0);
  return frames;
}

std::int64_t SimDetectors::written_pixels() const {
  std::int64_t n = 0;
  for (std::size_t v = 0; v < synthesizers_.size(); ++v) {
    const auto& view = scene_->scene.detectors[v].view;
    n += whole_detector() ? std::int64_t(view.rows) * view.cols
                          : std::int64_t(window(v).rows) * window(v).cols;
  }
  return n;
}

void SimDetectors::forget_previous_frames() {
  for (auto& s : synthesizers_) s->forget_previous_frame();
}

Result<SceneSimDetectors> make_scene_sim_detectors(const PreparedScene& p, tracking::ThreadPool* pool) {
  const sim_spec::XrayPhysicsSpec& physics = p.scene.sim.physics;
  std::shared_ptr<const SimulatedPatient> patient;
  std::shared_ptr<const tracking::DrrRenderer> exact;
  if (!physics.ideal()) {
    auto made = make_simulated_patient(p, physics, scene_anatomy_seed(p), pool, pool, nullptr, true);
    if (!made.ok()) return made.status();
    patient = std::make_shared<const SimulatedPatient>(std::move(made).value());
  } else {
    tracking::RendererOptions exact_options;
    exact_options.pool = pool;
    auto siddon = tracking::make_renderer("siddon", p.world_mu, exact_options);
    if (!siddon.ok()) return siddon.status();
    exact = std::move(siddon).value();
  }
  const sim::DetectorModel model = scene_detector_model(p);
  auto detectors = SimDetectors::create(p, exact, patient, model);
  if (!detectors.ok()) return detectors.status();
  SceneSimDetectors out{std::move(detectors).value(), std::nullopt};
  if (patient) out.correction = sim::detector_correction(model);
  return out;
}

}  // namespace lftrack::sim_devices

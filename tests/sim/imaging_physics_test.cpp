// The imaging physics of realistic synthetic frames, part by part (issue 21): attenuation
// tables, the spectrum and its hardening, the water/bone split, scatter, detector effects and
// the deformed anatomy.
#include <gtest/gtest.h>

#include <cmath>

#include "lftrack/sim/anatomy_deformation.hpp"
#include "lftrack/sim/detector_effects.hpp"
#include "lftrack/sim/material_decomposition.hpp"
#include "lftrack/sim/scatter_model.hpp"
#include "lftrack/sim/synthetic_frames.hpp"
#include "lftrack/sim/xray_spectrum.hpp"
#include "lftrack/sim_spec/xray_physics_spec.hpp"
#include "lftrack/tracking/drr_renderer.hpp"
#include "lftrack/tracking/xray_view.hpp"

namespace lftrack::sim {

using sim_spec::AnatomySpec;
using sim_spec::check_anatomy_spec;
using sim_spec::check_detector_effects;
using sim_spec::check_scatter_spec;
using sim_spec::clinical_anatomy;
using sim_spec::clinical_detector;
using sim_spec::DetectorEffectsSpec;
using sim_spec::physics_preset;
using sim_spec::ScatterSpec;
using sim_spec::SpectrumSpec;
using sim_spec::XrayPhysicsSpec;
namespace {

using namespace lftrack::tracking;

TEST(AttenuationTables, TabulatedValuesAndTheDefaultWaterMu) {
  EXPECT_DOUBLE_EQ(mass_attenuation_cm2_per_g(Material::kWater, 40), 0.2683);
  EXPECT_DOUBLE_EQ(mass_attenuation_cm2_per_g(Material::kCorticalBone, 40), 0.6655);
  EXPECT_DOUBLE_EQ(mass_attenuation_cm2_per_g(Material::kAluminium, 100), 0.1704);
  // The mono-energetic model's water mu (0.0193/mm) is water at about 70 keV.
  EXPECT_NEAR(mass_attenuation_cm2_per_g(Material::kWater, 70) / 10, kDefaultMuWaterPerMm, 0.0005);
  for (Material m : {Material::kWater, Material::kCorticalBone, Material::kAluminium})
    for (double e = 10; e < 150; e += 1)
      EXPECT_GT(mass_attenuation_cm2_per_g(m, e), mass_attenuation_cm2_per_g(m, e + 1));
  EXPECT_TRUE(std::isfinite(mass_attenuation_cm2_per_g(Material::kWater, NAN)));
}

TEST(Spectrum, FiltrationHardensTheBeamAndBadSettingsAreRefused) {
  SpectrumSpec spec;
  auto s = make_spectrum(spec);
  ASSERT_TRUE(s.ok()) << s.status().message();
  EXPECT_GT(s->mean_energy_kev(), 50);
  EXPECT_LT(s->mean_energy_kev(), 80);
  spec.filtration_mm_al = 6;
  EXPECT_GT(make_spectrum(spec)->mean_energy_kev(), s->mean_energy_kev());
  for (double kvp : {0.0, -1.0, double(NAN), double(INFINITY), 1e12, 39.0, 151.0}) {
    SpectrumSpec bad;
    bad.kvp = kvp;
    EXPECT_FALSE(make_spectrum(bad).ok()) << kvp;
  }
  SpectrumSpec bad;
  bad.filtration_mm_al = -1;
  EXPECT_FALSE(make_spectrum(bad).ok());
  bad = {};
  bad.bin_kev = 0;
  EXPECT_FALSE(make_spectrum(bad).ok());
}

TEST(Spectrum, EffectiveAttenuationFallsWithThicknessBeamHardening) {
  auto s = make_spectrum({});
  ASSERT_TRUE(s.ok());
  // Effective mu (per g/cm^2) of the next centimetre of water, at 1, 10 and 30 cm.
  auto effective = [&](double t) {
    return polyenergetic_log_attenuation(*s, t + 1, 0) - polyenergetic_log_attenuation(*s, t, 0);
  };
  EXPECT_GT(effective(1), effective(10));
  EXPECT_GT(effective(10), effective(30));
  EXPECT_NEAR(polyenergetic_log_attenuation(*s, 0, 0), 0, 1e-12);
  // Bone hardens the beam too, and attenuates more per gram than water.
  EXPECT_GT(polyenergetic_log_attenuation(*s, 0, 1), polyenergetic_log_attenuation(*s, 1, 0));
}

TEST(Spectrum, TableMatchesTheDirectSum) {
  auto s = make_spectrum({});
  auto table = PolyenergeticTable::create(*s);
  ASSERT_TRUE(table.ok());
  double worst = 0;
  for (double w = 0; w <= 60; w += 1.37)
    for (double b = 0; b <= 40; b += 0.93)
      worst = std::max(worst, std::abs(table->log_attenuation(float(w), float(b)) -
                                       polyenergetic_log_attenuation(*s, w, b)));
  EXPECT_LT(worst, 1e-3);
  EXPECT_NEAR(table->log_attenuation(NAN, -5), 0.f, 1e-6);
  EXPECT_TRUE(std::isfinite(table->log_attenuation(1e12f, 1e12f)));
}

TEST(MaterialDecomposition, ReproducesThePlanningCtsAttenuationAtItsEnergy) {
  const double e = 70;
  EXPECT_NEAR(cortical_bone_hu(e), 1550, 150);
  CtVolume ct;
  ct.geometry.size = {8, 1, 1};
  ct.values = {-1000, -500, 0, 200, 800, 1500, 2500, NAN};
  auto split = decompose_ct(ct, e);
  ASSERT_TRUE(split.ok()) << split.status().message();
  const double mu_w = mass_attenuation_cm2_per_g(Material::kWater, e);
  const double mu_b = mass_attenuation_cm2_per_g(Material::kCorticalBone, e);
  for (int i = 0; i < 7; ++i) {
    // Per mm: (mu/rho) [cm^2/g] x (rho / 10) [g/cm^2 per mm].
    const double mu = mu_w * split->water.values[std::size_t(i)] + mu_b * split->bone.values[std::size_t(i)];
    EXPECT_NEAR(mu, mu_w / 10 * (1 + ct.values[std::size_t(i)] / 1000), 1e-6) << ct.values[std::size_t(i)];
    EXPECT_GE(split->water.values[std::size_t(i)], 0);
    EXPECT_GE(split->bone.values[std::size_t(i)], 0);
  }
  EXPECT_EQ(split->bone.values[2], 0.f);   // water is water
  EXPECT_EQ(split->water.values[6], 0.f);  // dense bone has no water
  EXPECT_EQ(split->water.values[7], 0.f);  // NaN reads as air
  EXPECT_FALSE(decompose_ct(ct, 10).ok());
  EXPECT_FALSE(decompose_ct(ct, NAN).ok());
}

TEST(Scatter, UniformSlabRaisesTheSignalByTheStatedRatio) {
  ScatterSpec spec;
  spec.spr_per_cm = 0.05;
  spec.kernel_sigma_mm = 20;
  ASSERT_TRUE(check_scatter_spec(spec).ok());
  const int n = 200;
  Image<float> primary(n, n, 0.1f), thickness(n, n, 20.f), out(n, n);
  ScatterModel model(n, n, 0.4, spec);
  ASSERT_TRUE(model.add_scatter(primary.view(), thickness.view(), out.view()).ok());
  EXPECT_NEAR(out.at(n / 2, n / 2) / primary.at(n / 2, n / 2), 1 + 0.05 * 20, 1e-3);
  // The grid passes Ts of the scatter and Tp of the primary: the SPR falls by Ts / Tp.
  spec.grid = true;
  ScatterModel gridded(n, n, 0.4, spec);
  ASSERT_TRUE(gridded.add_scatter(primary.view(), thickness.view(), out.view()).ok());
  EXPECT_NEAR(out.at(n / 2, n / 2) / 0.1, 1 + 1.0 * 0.15 / 0.70, 1e-3);
  EXPECT_DOUBLE_EQ(gridded.photon_fraction(), 0.70);
  // Scatter is broad: a thick half and a thin half smear into each other across the edge.
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) thickness.at(r, c) = c < n / 2 ? 30.f : 0.f;
  ScatterModel plain(n, n, 0.4, ScatterSpec{});
  ASSERT_TRUE(plain.add_scatter(primary.view(), thickness.view(), out.view()).ok());
  EXPECT_GT(out.at(n / 2, n / 2 + 10), 0.1f * 1.05f);  // thin side, scatter from the thick side
  EXPECT_LT(out.at(n / 2, n / 2 - 10), 0.1f * (1 + 0.05f * 30));
  for (double bad : {-1.0, double(NAN), 2.0}) {
    ScatterSpec b;
    b.spr_per_cm = bad;
    EXPECT_FALSE(check_scatter_spec(b).ok());
  }
  ScatterSpec b;
  b.kernel_sigma_mm = 0;
  EXPECT_FALSE(check_scatter_spec(b).ok());
}

// A 40 mm cube of water-like attenuation in front of a small detector.
std::shared_ptr<const MuVolume> cube(float mu) {
  auto v = std::make_shared<MuVolume>();
  v->geometry.size = {40, 40, 40};
  v->geometry.origin_mm = {-19.5, -19.5, -19.5};
  v->values.assign(64000, mu);
  return v;
}
// A detector that adds nothing of its own: no noise, no blur, 16 bits.
DetectorModel exact_detector() {
  DetectorModel model;
  model.noise = false;
  model.blur_sigma_px = 0;
  model.bits = 16;
  return model;
}

XrayView small_view() {
  return *XrayView::isocentric("A", Eigen::Vector3d::Zero(), Eigen::Vector3d(0, -1, 0),
                               Eigen::Vector3d(0, 0, 1), 500, 700, 32, 32, 1.0);
}

TEST(PhysicsFrames, ScatterRaisesTheCountsBehindAThickObjectByTheStatedRatio) {
  auto renderer = std::move(make_renderer("siddon", cube(0.1f))).value();  // p = 4: 20.7 cm of water
  const DetectorModel model = exact_detector();
  const XrayView v = small_view();
  const PixelWindow window = PixelWindow::full(v.rows, v.cols);
  XrayPhysicsSpec physics;
  physics.scatter = ScatterSpec{};
  physics.scatter->kernel_sigma_mm = 4;
  auto with = FrameSynthesizer::create(window, model, physics, v.rows, v.cols, 1.0, 1);
  ASSERT_TRUE(with.ok()) << with.status().message();
  FrameSynthesizer without(window, model);
  Image<std::uint16_t> a(v.rows, v.cols), b(v.rows, v.cols);
  ASSERT_TRUE((*with)->synthesize(*renderer, Pose::Identity(), v, 1, a.view()).ok());
  ASSERT_TRUE(without.synthesize(*renderer, Pose::Identity(), v, 1, b.view()).ok());
  Image<float> p(1, 1);
  ASSERT_TRUE(renderer->render(Pose::Identity(), v, {16, 16, 1, 1}, p.view()).ok());
  const double thickness_cm = p.at(0, 0) / (10 * kDefaultMuWaterPerMm);
  EXPECT_NEAR(double(a.at(16, 16)) / b.at(16, 16), 1 + 0.05 * thickness_cm, 0.02);
}

TEST(PhysicsFrames, IdealPhysicsGivesTodaysFramesAndMaterialsAreRequiredWithASpectrum) {
  auto renderer = std::move(make_renderer("siddon", cube(0.02f))).value();
  DetectorModel model;
  const XrayView v = small_view();
  const PixelWindow window{2, 3, 25, 26};
  auto ideal = FrameSynthesizer::create(window, model, XrayPhysicsSpec{}, v.rows, v.cols, 1.0, 1);
  ASSERT_TRUE(ideal.ok());
  auto today = synthesize_frame(*renderer, Pose::Identity(), v, window, model, 7);
  Image<std::uint16_t> frame(v.rows, v.cols, 0);
  ASSERT_TRUE((*ideal)->synthesize(*renderer, Pose::Identity(), v, 7, frame.view()).ok());
  EXPECT_EQ(frame.pixels(), today->pixels());
  auto clinical = physics_preset("clinical");
  ASSERT_TRUE(clinical.ok());
  auto real = FrameSynthesizer::create(window, model, *clinical, v.rows, v.cols, 1.0, 1);
  ASSERT_TRUE(real.ok()) << real.status().message();
  EXPECT_TRUE((*real)->needs_materials());
  EXPECT_FALSE((*real)->synthesize(*renderer, Pose::Identity(), v, 7, frame.view()).ok());
  EXPECT_FALSE(physics_preset("realistic").ok());
  XrayPhysicsSpec bad;
  bad.detector = DetectorEffectsSpec{};
  bad.detector->lag_fraction = NAN;
  EXPECT_FALSE(FrameSynthesizer::create(window, model, bad, v.rows, v.cols, 1.0, 1).ok());
  EXPECT_FALSE(FrameSynthesizer::create({0, 0, 40, 40}, model, *clinical, v.rows, v.cols, 1.0, 1).ok());
}

TEST(PhysicsFrames, LagCarriesTheStatedShareOfThePreviousFrame) {
  auto dark = std::move(make_renderer("siddon", cube(0.05f))).value();
  auto light = std::move(make_renderer("siddon", cube(0.0f))).value();
  const DetectorModel model = exact_detector();
  const XrayView v = small_view();
  const PixelWindow window = PixelWindow::full(v.rows, v.cols);
  XrayPhysicsSpec physics;
  physics.detector = DetectorEffectsSpec{};
  physics.detector->lag_fraction = 0.1;
  auto s = FrameSynthesizer::create(window, model, physics, v.rows, v.cols, 1.0, 1);
  ASSERT_TRUE(s.ok());
  Image<std::uint16_t> first(v.rows, v.cols), second(v.rows, v.cols), fresh(v.rows, v.cols);
  ASSERT_TRUE((*s)->synthesize(*light, Pose::Identity(), v, 1, first.view()).ok());
  ASSERT_TRUE((*s)->synthesize(*dark, Pose::Identity(), v, 1, second.view()).ok());
  (*s)->forget_previous_frame();
  ASSERT_TRUE((*s)->synthesize(*dark, Pose::Identity(), v, 1, fresh.view()).ok());
  EXPECT_NEAR(second.at(16, 16), 0.9 * fresh.at(16, 16) + 0.1 * first.at(16, 16), 1.0);
  EXPECT_GT(second.at(16, 16), fresh.at(16, 16) + 50);
}

TEST(DetectorPattern, FixedPerPixelDefectsAtTheirRateAndTheHeelGradient) {
  DetectorEffectsSpec spec = clinical_detector();
  spec.defective_pixel_fraction = 0.01;
  DetectorPattern a(spec, 512, 512), b(spec, 512, 512);
  int stuck = 0;
  double sum = 0, sum2 = 0;
  for (int r = 0; r < 512; ++r)
    for (int c = 0; c < 512; ++c) {
      EXPECT_EQ(a.gain(r, c), b.gain(r, c));
      if (a.stuck_level(r, c) > 0) ++stuck;
      const double g = a.gain(r, c);
      sum += g;
      sum2 += g * g;
    }
  EXPECT_NEAR(stuck / (512.0 * 512.0), 0.01, 0.002);
  const double mean = sum / (512.0 * 512), rms = std::sqrt(sum2 / (512.0 * 512) - mean * mean);
  EXPECT_NEAR(mean, 1, 0.01);
  EXPECT_GT(rms, 0.003);  // smooth, pixel and the two lines' gains
  EXPECT_LT(rms, 0.05);
  EXPECT_NEAR(a.heel(511) - a.heel(0), spec.heel_gradient, 1e-3);
  spec.pattern_seed = 2;
  DetectorPattern other(spec, 512, 512);
  EXPECT_NE(other.gain(100, 100), a.gain(100, 100));
  DetectorEffectsSpec bad;
  bad.defective_lines = 9;
  EXPECT_FALSE(check_detector_effects(bad).ok());
  bad = {};
  bad.heel_gradient = INFINITY;
  EXPECT_FALSE(check_detector_effects(bad).ok());
}

TEST(AnatomyDeformation, TargetStaysRigidNeighboursMoveSoftTissueDeforms) {
  AnatomySpec spec = clinical_anatomy();
  spec.adjacent_translation_mm = 2;
  spec.adjacent_rotation_deg = 2;
  const Eigen::Vector3d centre(10, 100, 180);
  AnatomyDeformation d(spec, centre, 3);
  // Inside the target's box: nothing moves.
  for (double x : {-29.0, 0.0, 29.0})
    for (double z : {-14.9, 0.0, 14.9})
      EXPECT_EQ(d.displacement_mm(centre + Eigen::Vector3d(x, 10, z)).norm(), 0);
  // Just above the box moves little; a vertebra above (past the disc) moves rigidly.
  const double near = d.displacement_mm(centre + Eigen::Vector3d(0, 0, 15.5)).norm();
  const double above = d.displacement_mm(centre + Eigen::Vector3d(0, 0, 35)).norm();
  EXPECT_LT(near, 0.1);
  EXPECT_GT(above, 0.1);
  // Far away, the soft-tissue field has about its stated rms.
  double sum2 = 0;
  int n = 0;
  for (double x = -200; x <= 200; x += 23)
    for (double y = -200; y <= 200; y += 23)
      for (double z = 200; z <= 400; z += 23) {
        sum2 +=
            d.displacement_mm(centre + Eigen::Vector3d(x, y, z) + Eigen::Vector3d(0, 0, 100)).squaredNorm();
        ++n;
      }
  EXPECT_GT(std::sqrt(sum2 / n), 0.5 * spec.soft_tissue_mm);
  EXPECT_LT(std::sqrt(sum2 / n), 3.0 * spec.soft_tissue_mm);
  AnatomySpec bad;
  bad.soft_tissue_mm = NAN;
  EXPECT_FALSE(check_anatomy_spec(bad).ok());
  bad = {};
  bad.target_size_mm.x() = 0;
  EXPECT_FALSE(check_anatomy_spec(bad).ok());
}

TEST(AnatomyDeformation, DeformedCtKeepsTheTargetsVoxelsAndMovesTheRest) {
  CtVolume ct;
  ct.geometry.size = {60, 60, 60};
  ct.geometry.spacing_mm = {2, 2, 2};
  ct.geometry.origin_mm = {-59, -59, -59};
  ct.values.resize(std::size_t(ct.geometry.voxel_count()));
  for (int k = 0; k < 60; ++k)
    for (int j = 0; j < 60; ++j)
      for (int i = 0; i < 60; ++i)
        ct.at(i, j, k) = float(100 * std::sin(i * 0.3) + 50 * std::cos(j * 0.2 + k * 0.25));
  AnatomySpec spec;
  spec.soft_tissue_mm = 4;
  spec.ramp_mm = 10;
  spec.target_size_mm = {30, 30, 30};
  AnatomyDeformation d(spec, Eigen::Vector3d::Zero(), 11);
  auto moved = deform_ct(ct, d);
  ASSERT_TRUE(moved.ok()) << moved.status().message();
  int changed_far = 0;
  for (int k = 0; k < 60; ++k)
    for (int j = 0; j < 60; ++j)
      for (int i = 0; i < 60; ++i) {
        const Eigen::Vector3d x = ct.geometry.ct_from_index() * Eigen::Vector3d(i, j, k);
        if (d.in_target(x)) {
          ASSERT_EQ(moved->at(i, j, k), ct.at(i, j, k));
        }
        if (x.cwiseAbs().minCoeff() > 40 && std::abs(moved->at(i, j, k) - ct.at(i, j, k)) > 1) ++changed_far;
      }
  EXPECT_GT(changed_far, 100);
}

}  // namespace
}  // namespace lftrack::sim

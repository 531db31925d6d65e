// The scene's simulator sections as data (lftrack::sim_spec): the presets, the range checks the
// scene parser applies, and the one-line description, on their own (this suite links nothing else).
#include "lftrack/sim_spec/xray_physics_spec.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace lftrack::sim_spec {
namespace {

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

TEST(PhysicsPresets, IdealIsNothingClinicalIsEverythingAndOthersAreRefused) {
  auto ideal = physics_preset("ideal");
  ASSERT_TRUE(ideal.ok());
  EXPECT_TRUE(ideal->ideal());
  auto clinical = physics_preset("clinical");
  ASSERT_TRUE(clinical.ok());
  EXPECT_TRUE(clinical->spectrum && clinical->scatter && clinical->detector && clinical->anatomy);
  EXPECT_TRUE(check_physics(*clinical).ok());
  EXPECT_EQ(clinical->spectrum->spectrum.kvp, 120);
  EXPECT_TRUE(clinical->scatter->grid);
  const auto unknown = physics_preset("realistic");
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.status().message().find("(ideal, clinical)"), std::string::npos)
      << unknown.status().message();
  EXPECT_EQ(physics_preset_names(), (std::vector<std::string>{"ideal", "clinical"}));
}

TEST(PhysicsChecks, TheSpectrumsRangesAtTheirEdgesAndBeyond) {
  SpectrumSpec s;
  EXPECT_TRUE(check_spectrum_spec(s).ok());
  for (double kvp : {40.0, 150.0}) {
    s.kvp = kvp;
    EXPECT_TRUE(check_spectrum_spec(s).ok()) << kvp;
  }
  for (double kvp : {39.9, 150.1, 0.0, -1.0, kNan, kInf, 1e12}) {
    s.kvp = kvp;
    const Status st = check_spectrum_spec(s);
    EXPECT_FALSE(st.ok()) << kvp;
    EXPECT_NE(st.message().find("kvp must be in [40, 150]"), std::string::npos) << st.message();
  }
  s = SpectrumSpec{};
  for (double mm : {0.0, 20.0}) {
    s.filtration_mm_al = mm;
    EXPECT_TRUE(check_spectrum_spec(s).ok()) << mm;
  }
  for (double mm : {-0.1, 20.1, kNan}) {
    s.filtration_mm_al = mm;
    EXPECT_FALSE(check_spectrum_spec(s).ok()) << mm;
  }
  s = SpectrumSpec{};
  for (double bin : {0.01, 10.0}) {
    s.bin_kev = bin;
    EXPECT_TRUE(check_spectrum_spec(s).ok()) << bin;
  }
  for (double bin : {0.0, 1e-12, 0.0099, -1.0, 10.1, kNan}) {
    s.bin_kev = bin;
    EXPECT_FALSE(check_spectrum_spec(s).ok()) << bin;
  }
}

// check_physics checks every part that is on, and says which part failed.
TEST(PhysicsChecks, EachPartThatIsOnIsCheckedAndNamed) {
  XrayPhysicsSpec p = physics_preset("clinical").value();
  p.spectrum->ct_effective_kev = 200;
  EXPECT_NE(check_physics(p).message().find("spectrum: ct_effective_kev"), std::string::npos);
  p = physics_preset("clinical").value();
  p.scatter->spr_per_cm = kNan;
  EXPECT_NE(check_physics(p).message().find("scatter: spr_per_cm"), std::string::npos);
  p = physics_preset("clinical").value();
  p.detector->defective_lines = 9;
  EXPECT_NE(check_physics(p).message().find("detector: defective_lines"), std::string::npos);
  p = physics_preset("clinical").value();
  p.anatomy->target_size_mm.z() = kInf;
  EXPECT_NE(check_physics(p).message().find("anatomy: target_size_mm"), std::string::npos);
  p.anatomy.reset();  // a part that is off is not checked
  EXPECT_TRUE(check_physics(p).ok()) << check_physics(p).message();
}

TEST(PhysicsDescription, SaysIdealOrEachPartThatIsOn) {
  EXPECT_EQ(describe(XrayPhysicsSpec{}).rfind("ideal", 0), 0u);
  XrayPhysicsSpec p;
  p.scatter = clinical_scatter();
  const std::string one = describe(p);
  EXPECT_NE(one.find("scatter 0.05/cm, 40 mm, grid"), std::string::npos) << one;
  EXPECT_EQ(one.find("spectrum"), std::string::npos) << one;
  const std::string all = describe(clinical_physics());
  for (const char* part : {"spectrum 120 kVp", "scatter", "detector glare", "anatomy soft 3 mm"})
    EXPECT_NE(all.find(part), std::string::npos) << part << ": " << all;
}

}  // namespace
}  // namespace lftrack::sim_spec

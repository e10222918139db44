#include "core/pipeline/options.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

namespace uavm {
namespace {

std::string WriteTemp(const std::string& name, const std::string& text) {
  const auto p = std::filesystem::temp_directory_path() / ("uavm_opt_" + name + std::to_string(::getpid()) + ".yaml");
  std::ofstream(p) << text;
  return p.string();
}

TEST(OptionsTest, DefaultsAreValid) {
  std::string why;
  const PipelineOptions defaults;  // named: GCC 12 warns falsely about a temporary's strings
  EXPECT_TRUE(defaults.Check(&why)) << why;
}

TEST(OptionsTest, YamlOverridesAndRoundTrips) {
  PipelineOptions o;
  std::string err;
  ASSERT_TRUE(LoadOptionsYaml(
      WriteTemp("ok", "work_long_side: 800\nmodel: affine\nmatching:\n  ratio: 0.7\nrefine:\n  max_seconds: 5\n"), &o,
      &err))
      << err;
  EXPECT_EQ(o.work_long_side, 800);
  EXPECT_EQ(o.refine.model, MotionModel::kAffine);
  EXPECT_DOUBLE_EQ(o.refine.max_seconds, 5.0);
  EXPECT_NE(ToYaml(o).find("model: affine"), std::string::npos);
  EXPECT_DOUBLE_EQ(o.matching.ratio, 0.7);
  PipelineOptions back;
  ASSERT_TRUE(LoadOptionsYaml(WriteTemp("rt", ToYaml(o)), &back, &err)) << err;
  EXPECT_EQ(ToYaml(back), ToYaml(o));
}

TEST(OptionsTest, BadConfigsGiveClearErrors) {
  struct Case {
    const char* text;
    const char* expect;
  };
  for (const Case& c :
       {Case{"work_long_sid: 800\n", "unknown key 'work_long_sid'"},
        Case{"matching:\n  ratoi: 0.7\n", "unknown key 'matching.ratoi'"}, Case{"work_long_side: big\n", "wrong type"},
        Case{"work_long_side: -5\n", "work_long_side"}, Case{"matching: 3\n", "must be a mapping"},
        Case{"model: projective\n", "'model' must be affine or homography"},
        Case{"refine:\n  huber_px: -1\n", "refine:"}, Case{"[1, 2\n", "config"}}) {
    const PipelineOptions defaults;
    PipelineOptions o;
    std::string err;
    EXPECT_FALSE(LoadOptionsYaml(WriteTemp("bad", c.text), &o, &err)) << c.text;
    EXPECT_NE(err.find(c.expect), std::string::npos) << err;
    EXPECT_EQ(o.work_long_side, defaults.work_long_side);  // a failed load changes nothing
  }
  PipelineOptions o;
  std::string err;
  EXPECT_TRUE(LoadOptionsYaml(WriteTemp("empty", ""), &o, &err)) << err;  // empty = defaults
}

// A section another unit reads (the program's `telemetry:`, hal's) is an unknown key to core unless it is told so.
TEST(OptionsTest, SectionsReadElsewhereArePassedOverOnlyWhenNamed) {
  const std::string yaml = "work_long_side: 800\ntelemetry:\n  latency_ms: 250\n";
  PipelineOptions p;
  std::string error;
  EXPECT_FALSE(ParseOptionsYaml(yaml, "core.yaml", &p, &error));
  EXPECT_EQ(error, "config core.yaml: unknown key 'telemetry'");
  EXPECT_EQ(p.work_long_side, PipelineOptions().work_long_side);  // a refused config changes nothing
  ASSERT_TRUE(ParseOptionsYaml(yaml, "core.yaml", &p, &error, {"telemetry"})) << error;
  EXPECT_EQ(p.work_long_side, 800);
}

}  // namespace
}  // namespace uavm

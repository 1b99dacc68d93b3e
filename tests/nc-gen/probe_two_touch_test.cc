// formloop's LinuxCNC probing program with a slow second touch and a LOG line per point
// (nc-gen/probe_program.h, touch_feed_mm_per_min > 0 and linuxcnc_log_file): the blocks of one point in
// order, the log line's fields, the option checks, and LinuxCNC's own interpreter accepting it. The
// single-touch program (the golden file of probe_dialects_test) is unchanged by these options' defaults;
// tests/linuxcnc runs this one on the controller.

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "metrology/probe.h"
#include "nc-gen/probe_program.h"
#include "tests/support/rs274.h"

namespace formloop::nc {
namespace {

metrology::ProbingPlan TwoPoints() {
  metrology::ProbingPlan plan;
  metrology::ProbePoint a;
  a.id = 4;
  a.point = {10, 5, 1};
  a.normal = Eigen::Vector3d(0.6, 0, 0.8);
  metrology::ProbePoint b;
  b.id = 12;
  b.point = {-10, 5, 0};
  b.normal = Eigen::Vector3d::UnitZ();
  plan.points = {a, b};
  return plan;
}

ProbeProgramOptions TwoTouches() {
  ProbeProgramOptions o;
  o.post.title = "two touches";
  o.safe_z_mm = 20;
  o.clearance_mm = 2;
  o.probe_feed_mm_per_min = 600;
  o.touch_feed_mm_per_min = 6;
  o.backoff_mm = 0.1;
  o.linuxcnc_log_file = "points.txt";
  o.linuxcnc_time_input = 0;
  return o;
}

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  return lines;
}

TEST(ProbeTwoTouchTest, EachPointIsApproachedBackedOffTouchedTimedAndLogged) {
  const auto text = PostLinuxCncProbing(TwoPoints(), TwoTouches());
  ASSERT_TRUE(text.ok()) << text.status().message();
  const std::vector<std::string> l = Lines(*text);
  auto at = [&l](const std::string& line) {
    for (std::size_t i = 0; i < l.size(); ++i) {
      if (l[i] == line) return static_cast<long>(i);
    }
    return -1L;
  };
  ASSERT_GE(at("(LOGOPEN,points.txt)"), 0) << *text;
  EXPECT_EQ(at("(LOG,formloop probe log 1: point id x y z tripped ax ay az t_s)"), at("(LOGOPEN,points.txt)") + 1);
  const long p = at("(point 4)");
  ASSERT_GE(p, 0);
  // Centre on the surface + R n = (10.6, 5, 1.8); start 2 mm further; search end 2 mm beyond.
  EXPECT_EQ(l[static_cast<std::size_t>(p + 1)], "G0 X11.8000 Y5.0000");
  EXPECT_EQ(l[static_cast<std::size_t>(p + 2)], "G0 Z3.4000");
  EXPECT_EQ(l[static_cast<std::size_t>(p + 3)], "G38.2 X9.4000 Y5.0000 Z0.2000 F600");
  EXPECT_EQ(l[static_cast<std::size_t>(p + 4)], "G91 G0 X0.0600 Y0.0000 Z0.0800") << "back off 0.1 mm along +n";
  EXPECT_EQ(l[static_cast<std::size_t>(p + 5)], "G90");
  EXPECT_EQ(l[static_cast<std::size_t>(p + 6)], "G38.2 X9.4000 Y5.0000 Z0.2000 F6");
  EXPECT_EQ(l[static_cast<std::size_t>(p + 7)], "M66 E0 L0");
  EXPECT_EQ(l[static_cast<std::size_t>(p + 8)],
            "(LOG,point 4 #5061 #5062 #5063 #5070 -0.600000000 0.000000000 -0.800000000 #5399)");
  EXPECT_EQ(l[static_cast<std::size_t>(p + 9)], "G0 X11.8000 Y5.0000 Z3.4000");
  EXPECT_GE(at("(LOGCLOSE)"), 0);
  EXPECT_LT(at("(PROBECLOSE)"), at("M30"));
}

TEST(ProbeTwoTouchTest, OptionsThatCannotWorkAreRefusedNamingTheField) {
  auto refused = [](ProbeProgramOptions o, const std::string& field) {
    const auto r = PostLinuxCncProbing(TwoPoints(), o);
    ASSERT_FALSE(r.ok()) << field;
    EXPECT_NE(r.status().message().find(field), std::string::npos) << r.status().message();
  };
  ProbeProgramOptions o = TwoTouches();
  o.touch_feed_mm_per_min = 900;  // faster than the approach
  refused(o, "probe.touch_feed_mm_per_min");
  o = TwoTouches();
  o.backoff_mm = 2.5;  // beyond the clearance: the touch would start above the approach's start
  refused(o, "probe.backoff_mm");
  o = TwoTouches();
  o.linuxcnc_log_file = "a,b.txt";
  refused(o, "probe.linuxcnc_log_file");
  o = TwoTouches();
  o.post.limits.travel_max_mm.z() = 3.45;  // the back-off from a contact at the start reaches 3.48
  refused(o, "probe point 4");
}

TEST(ProbeTwoTouchTest, LinuxCncInterpreterAcceptsItWithTwoProbesPerPoint) {
  if (!testing::Rs274Installed()) {
    GTEST_SKIP() << "rs274 not found: LinuxCNC's interpreter is not installed (Debian linuxcnc-uspace)";
  }
  const auto text = PostLinuxCncProbing(TwoPoints(), TwoTouches());
  ASSERT_TRUE(text.ok());
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("formloop-two-touch-" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::ofstream(dir / "p.ngc") << *text;
  // With the probe tool in rs274's tool table (tests/support/rs274.h): the program changes to it.
  int code = 0;
  std::string said;
  const std::string canon = testing::RunRs274(dir / "p.ngc", &code, &said);
  std::filesystem::remove_all(dir);
  int probes = 0;
  for (const testing::CanonMove& m : testing::ParseCanon(canon).moves) probes += m.kind == testing::CanonKind::kProbe;
  EXPECT_EQ(code, 0) << said;
  EXPECT_EQ(probes, 4);
}

}  // namespace
}  // namespace formloop::nc

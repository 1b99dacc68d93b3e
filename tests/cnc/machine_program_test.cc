// The machine-side programs (cnc/machine_program.h) and their readers (cnc/macro_code.h):
//   - golden files of a 3-point plan in the three dialects (FORMLOOP_UPDATE_GOLDEN=1 rewrites them);
//   - every program formloop writes reads back with the dialect's reader, both layouts;
//   - the readers refuse what is wrong and name the line (addresses, syntax, unmatched blocks,
//     missing jump targets, unbracketed LinuxCNC expressions);
//   - the interpreter's dialect semantics (FIX, ROUND, vacant, LinuxCNC's C-int round);
//   - LinuxCNC's own interpreter `rs274` accepts the LinuxCNC program: run as written (no collector:
//     it must end in the program's COLLECTOR OFFLINE abort after exactly the dwells formloop's
//     interpreter makes), and run with its two HAL transport lines replaced by an instant collector
//     in G-code, so every line of the program runs in rs274; the data words rs274 writes equal the
//     packing of the deviations it measured, and formloop's interpreter writes the same words;
//   - refusals: too many points, ids out of order, a position beyond the travel, a feed beyond the limit.

#include "cnc/machine_program.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include "cnc/controller.h"
#include "cnc/macro_interpreter.h"
#include "core/atomic_file.h"
#include "core/point_io.h"
#include "tests/support/rs274.h"
#include "tests/support/test_dir.h"

namespace formloop::cnc {
namespace {

const Dialect kDialects[] = {Dialect::kFanuc, Dialect::kLinuxCnc, Dialect::kSinumerik};

MachineProgramOptions Options(Dialect d, Layout layout = Layout::kPacked) {
  MachineProgramOptions o;
  o.dialect = d;
  o.layout = layout;
  o.probe.post.decimals = d == Dialect::kFanuc ? 3 : 4;
  o.probe.post.title = "golden 3-point plan";
  return o;
}

std::filesystem::path GoldenDir() { return std::filesystem::path(FORMLOOP_SOURCE_DIR) / "tests" / "cnc" / "golden"; }

TEST(MachineProgramGolden, ThreePointPlanInEachDialect) {
  const auto plan = SyntheticPlan(3);
  for (const Dialect d : kDialects) {
    const auto program = WriteMachineProgram(plan, Options(d));
    ASSERT_TRUE(program.ok()) << program.status().ToString();
    for (const auto& f : program->files) {
      const auto path = GoldenDir() / f.name;
      if (std::getenv("FORMLOOP_UPDATE_GOLDEN") != nullptr) {
        ASSERT_TRUE(WriteFileAtomic(path, f.text).ok());
      }
      const auto golden = ReadFile(path);
      ASSERT_TRUE(golden.ok()) << path << " is missing: FORMLOOP_UPDATE_GOLDEN=1 writes it";
      EXPECT_EQ(f.text, *golden) << f.name << " differs from its golden file";
    }
  }
}

TEST(MachineProgramReaders, EveryWrittenProgramReadsBack) {
  for (const Dialect d : kDialects) {
    for (const Layout layout : {Layout::kPacked, Layout::kSplit}) {
      for (const int n : {1, 7, 2000}) {
        auto o = Options(d, layout);
        const auto program = WriteMachineProgram(SyntheticPlan(n), o);
        ASSERT_TRUE(program.ok()) << program.status().ToString();
        MacroLimits limits;
        limits.linuxcnc_ports = layout == Layout::kSplit ? 6 : 4;
        const auto code = ReadMacroProgram(d, program->files, limits);
        ASSERT_TRUE(code.ok()) << DialectName(d) << " " << LayoutName(layout) << ": " << code.status().ToString();
        EXPECT_EQ(code->marks.size(), static_cast<std::size_t>(n));
      }
    }
  }
  // The SPLIT layout needs six analog ports on LinuxCNC: with the default four the reader says so.
  const auto split = WriteMachineProgram(SyntheticPlan(2), Options(Dialect::kLinuxCnc, Layout::kSplit));
  const auto refused = ReadMacroProgram(Dialect::kLinuxCnc, split->files);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("num_aio"), std::string::npos) << refused.status().message();
}

// Each broken program: (dialect, text, the line the error must name, a piece of the message).
struct Broken {
  Dialect dialect;
  std::string text;
  int line;
  std::string says;
};

TEST(MachineProgramReaders, RefuseWhatIsWrongAndNameTheLine) {
  const std::vector<Broken> cases = {
      {Dialect::kFanuc, "%\nO1\n#1200=1\nM30\n%\n", 3, "cannot be written"},
      {Dialect::kFanuc, "%\nO1\n#100=#5000\nM30\n%\n", 3, "is not a Fanuc variable"},
      {Dialect::kFanuc, "%\nO1\nWHILE [#100 LT 3] DO1\nG04 X0.02\nEND2\nM30\n%\n", 5,
       "END2 without a matching open DO2"},
      {Dialect::kFanuc, "%\nO1\nGOTO 7\nM30\n%\n", 3, "GOTO target N7"},
      {Dialect::kFanuc, "%\nO1\n#100=[1+2\nM30\n%\n", 3, "to close an expression"},
      {Dialect::kFanuc, "%\nO1\n#100=SIN[1]\nM30\n%\n", 3, "function 'SIN'"},
      {Dialect::kFanuc, "%\nO1\nG04 P20\nM30\n%\n", 3, "G04 needs X"},
      {Dialect::kFanuc, "%\nO1\nM98 P2\nM30\n%\n", 3, "call of O2"},
      {Dialect::kFanuc, "%\nO1\nG00 X1\n%\n", 4, "no M30 or M99"},
      {Dialect::kFanuc, "%\nO1\nG31 X1 Y2 Z3\nM30\n%\n", 3, "needs its feed"},
      {Dialect::kLinuxCnc, "%\n#1000 = #1000+1\nM2\n%\n", 2, "must be bracketed"},
      {Dialect::kLinuxCnc, "%\no100 while [#1000 LT 3]\nG4 P0.02\no101 endwhile\nM2\n%\n", 4,
       "endwhile without its while"},
      {Dialect::kLinuxCnc, "%\no<fl_send> call\nM2\n%\n", 2, "called before it is defined"},
      {Dialect::kLinuxCnc, "%\nM68 E7 Q[1]\nM2\n%\n", 2, "beyond motion.num_aio"},
      {Dialect::kLinuxCnc, "%\nG4 P1\nM64 P4\nM2\n%\n", 3, "beyond motion.num_dio"},
      {Dialect::kLinuxCnc, "%\nM65\nM2\n%\n", 2, "M65 needs P<digital port>"},
      {Dialect::kLinuxCnc, "%\n#5070 = 1\nM2\n%\n", 2, "cannot be written"},
      {Dialect::kLinuxCnc, "%\no100 if [1]\nM2\n%\n", 3, "ends inside o100"},
      {Dialect::kSinumerik, "R100=1\nM30\n", 1, "beyond R99"},
      {Dialect::kSinumerik, "WHILE (R1 < 3)\nG4 F0.02\nM30\n", 3, "inside an open WHILE"},
      {Dialect::kSinumerik, "IF R1 == 1\nENDWHILE\nM30\n", 2, "ENDWHILE without WHILE"},
      {Dialect::kSinumerik, "SETAL(12)\nM30\n", 1, "cycle alarms are 60000..69999"},
      {Dialect::kSinumerik, "MEAS=1 G0 X1 Y2 Z3 F100\nM30\n", 1, "MEAS=1 needs G1"},
      {Dialect::kSinumerik, "FL_SEND\nM30\n", 1, "call of FL_SEND"},
  };
  for (const auto& c : cases) {
    const auto code = ReadMacroProgram(c.dialect, {{"p", c.text}});
    ASSERT_FALSE(code.ok()) << DialectName(c.dialect) << ":\n" << c.text;
    const std::string message = code.status().message();
    EXPECT_NE(message.find("p:" + std::to_string(c.line) + ":"), std::string::npos) << message;
    EXPECT_NE(message.find(c.says), std::string::npos) << message;
  }
}

// An environment for the interpreter's semantics: variables in a map, ports in a map, no probe.
class MapEnvironment : public MachineEnvironment {
 public:
  std::map<int, double> vars;
  std::map<int, double> ports;
  std::vector<std::pair<int, double>> port_writes;
  std::vector<std::string> messages;
  bool probe_at_target = false;  // like rs274's standalone canon: the probe "stops" at the target
  MacroValue ReadVariable(int n) override {
    const auto it = vars.find(n);
    return it == vars.end() ? MacroValue() : MacroValue(it->second);
  }
  void WriteVariable(int n, MacroValue v) override {
    if (v) {
      vars[n] = *v;
    } else {
      vars.erase(n);
    }
  }
  double PortIn(int port) override { return ports[port]; }
  void PortOut(int port, double value) override {
    ports[port] = value;
    port_writes.emplace_back(port, value);
  }
  std::vector<std::pair<int, bool>> digital_writes;
  void DigitalOut(int port, bool on) override {
    MachineEnvironment::DigitalOut(port, on);
    digital_writes.emplace_back(port, on);
  }
  ProbeOutcome Probe(const std::array<double, 3>&, const std::array<double, 3>& to, double) override {
    ProbeOutcome out;
    out.tripped = probe_at_target;
    out.position = to;
    return out;
  }
  void Message(const std::string& text) override { messages.push_back(text); }
};

// Runs a program to its end or alarm; returns the number of dwells.
int RunToEnd(MacroInterpreter& interpreter) {
  int dwells = 0;
  for (;;) {
    const auto step = interpreter.Run();
    if (step.state != MacroInterpreter::State::kRunning) return dwells;
    ++dwells;
  }
}

TEST(MacroInterpreter, DialectSemantics) {
  {
    const auto code = ReadMacroProgram(Dialect::kFanuc, {{"f",
                                                          "%\nO1\n#100=FIX[-1.5]\n#101=FUP[-1.2]\n#102=ROUND[-2.5]\n"
                                                          "#103=[#104 EQ 0]\n#105=[#104 LT 1]\n#106=#104+1\n#107=#0\n"
                                                          "#108=2+3*4\n#109=[1 EQ 1] OR [1 EQ 2]\nM30\n%\n"}});
    ASSERT_TRUE(code.ok()) << code.status().ToString();
    MapEnvironment env;
    MacroInterpreter in(&*code, &env);
    RunToEnd(in);
    EXPECT_EQ(in.state(), MacroInterpreter::State::kEnded);
    EXPECT_EQ(env.vars[100], -1);        // FIX truncates toward zero
    EXPECT_EQ(env.vars[101], -2);        // FUP away from zero
    EXPECT_EQ(env.vars[102], -3);        // ROUND half away from zero
    EXPECT_EQ(env.vars[103], 0);         // vacant EQ 0 is false on Fanuc
    EXPECT_EQ(env.vars[105], 1);         // ... but vacant LT 1 treats it as 0
    EXPECT_EQ(env.vars[106], 1);         // vacant + 1 = 1
    EXPECT_EQ(env.vars.count(107), 0u);  // #107 = #0 leaves it vacant
    EXPECT_EQ(env.vars[108], 14);
    EXPECT_EQ(env.vars[109], 1);
  }
  {
    const auto code = ReadMacroProgram(
        Dialect::kLinuxCnc,
        {{"l",
          "%\n#1000 = fix[-1.5]\n#1001 = round[-1.5]\n#1002 = round[68719476735.4]\n#1003 = fup[-1.2]\n"
          "#1004 = [2 + 3 * 4]\n#1005 = [1 EQ 1 AND 2 GT 3]\nM68 E1 Q[#1000 + 0.5]\nM2\n%\n"}});
    ASSERT_TRUE(code.ok()) << code.status().ToString();
    MapEnvironment env;
    MacroInterpreter in(&*code, &env);
    RunToEnd(in);
    ASSERT_EQ(env.port_writes.size(), 1u);
    EXPECT_EQ(env.port_writes[0], std::make_pair(1, -1.5));  // fix = floor: −2, + 0.5
    // The parameters live in the interpreter; read them back through a port.
  }
  {
    const auto code =
        ReadMacroProgram(Dialect::kLinuxCnc, {{"l",
                                               "%\n#1002 = round[68719476735.4]\nM68 E0 Q#1002\n#1001 = round[-1.5]\n"
                                               "M68 E1 Q#1001\nM2\n%\n"}});
    ASSERT_TRUE(code.ok());
    MapEnvironment env;
    MacroInterpreter in(&*code, &env);
    RunToEnd(in);
    EXPECT_EQ(env.ports[0], -2147483648.0);  // LinuxCNC's round goes through a C int (rs274 prints the same)
    EXPECT_EQ(env.ports[1], -2);
  }
  {
    // Digital outputs (the link's commit bits) read back through their inputs: M66 P<k> L0 → #5399.
    const auto code =
        ReadMacroProgram(Dialect::kLinuxCnc, {{"l",
                                               "%\nM66 P2 L0\nM68 E0 Q#5399\nM64 P2\nM66 P2 L0\n"
                                               "M68 E1 Q#5399\nM65 P2\nM66 P2 L0\nM68 E3 Q#5399\nM2\n%\n"}});
    ASSERT_TRUE(code.ok()) << code.status().ToString();
    MapEnvironment env;
    MacroInterpreter in(&*code, &env);
    RunToEnd(in);
    EXPECT_EQ(env.port_writes, (std::vector<std::pair<int, double>>{{0, 0.0}, {1, 1.0}, {3, 0.0}}));
  }
  {
    const auto code =
        ReadMacroProgram(Dialect::kSinumerik, {{"s",
                                                "R1=TRUNC(-1.5)\nR2=ROUND(2.5)\nR3=R9+1\nIF (R3 == 1) AND (R2 > 2)\n"
                                                "R4=7\nELSE\nR4=8\nENDIF\nM30\n"}});
    ASSERT_TRUE(code.ok()) << code.status().ToString();
    MapEnvironment env;
    MacroInterpreter in(&*code, &env);
    RunToEnd(in);
    EXPECT_EQ(env.vars[1], -1);
    EXPECT_EQ(env.vars[2], 3);
    EXPECT_EQ(env.vars[3], 1);  // R parameters are 0 until set
    EXPECT_EQ(env.vars[4], 7);
  }
  {
    // Division by zero and a loop without a dwell are alarms, not hangs.
    const auto code = ReadMacroProgram(Dialect::kFanuc, {{"f", "%\nO1\n#100=1/#101\nM30\n%\n"}});
    MapEnvironment env;
    env.vars[101] = 0;
    MacroInterpreter in(&*code, &env);
    RunToEnd(in);
    EXPECT_EQ(in.state(), MacroInterpreter::State::kAlarm);
    EXPECT_NE(in.alarm_text().find("division by zero"), std::string::npos);
    const auto loop = ReadMacroProgram(Dialect::kFanuc, {{"f", "%\nO1\nWHILE [1 EQ 1] DO1\n#100=1\nEND1\nM30\n%\n"}});
    MacroInterpreter spin(&*loop, &env);
    RunToEnd(spin);
    EXPECT_EQ(spin.state(), MacroInterpreter::State::kAlarm);
  }
}

// ---- LinuxCNC's rs274 ----------------------------------------------------------------------------

// Through tests/support/rs274.h, which lets one rs274 run at a time (parallel runs disturb each other).
std::string Rs274(const std::filesystem::path& program, int* exit_code) {
  std::string console;
  std::string canon = formloop::testing::RunRs274(program, exit_code, &console);
  std::ofstream(program.string() + ".console") << console;
  return canon;
}

std::vector<std::pair<int, double>> AuxOutputs(const std::string& canon) {
  std::vector<std::pair<int, double>> out;
  static const std::regex re(R"(SET_AUX_OUTPUT_VALUE\((\d+),([-0-9.]+)\))");
  for (std::sregex_iterator it(canon.begin(), canon.end(), re), end; it != end; ++it) {
    out.emplace_back(std::stoi((*it)[1]), std::stod((*it)[2]));
  }
  return out;
}

int Count(const std::string& text, const std::string& what) {
  int n = 0;
  for (auto p = text.find(what); p != std::string::npos; p = text.find(what, p + 1)) ++n;
  return n;
}

// The LinuxCNC program with its HAL transport (M66 reads, M68 writes) replaced by numbered parameters
// #4000 + port and an instant collector: a POINT_READY word written to port 0 is answered with its
// acknowledgement, FINISHED with IDLE. Everything else stays as written.
std::string Loopback(const std::string& program) {
  std::istringstream in(program);
  std::ostringstream out;
  std::string line;
  int pending_port = -1, block = 900;
  bool first = true;
  static const std::regex m66(R"(^M66 E(\d+) L0$)"), m68(R"(^M68 E(\d+) Q(.*)$)");
  std::smatch m;
  while (std::getline(in, line)) {
    if (std::regex_match(line, m, m66)) {
      pending_port = std::stoi(m[1]);
      continue;
    }
    if (pending_port >= 0) {
      const auto at = line.find("#5399");
      line.replace(at, 5, "#" + std::to_string(4000 + pending_port));
      pending_port = -1;
    }
    out << line << "\n";
    if (first) {
      out << "#4000 = 36864\n#4002 = 0\n#4003 = 0\n";  // the collector armed the block
      first = false;
    }
    if (std::regex_match(line, m, m68)) {
      const int port = std::stoi(m[1]);
      out << "#" << 4000 + port << " = " << m[2].str() << "\n";
      if (port == 0) {
        out << "o" << block << " if [[#4000 GE 57344] AND [#4000 LT 61440]]\n#4000 = [#4000 - 57344 + 36864]\no"
            << block << " endif\n";
        ++block;
        out << "o" << block << " if [#4000 GE 61440]\n#4000 = 0\no" << block << " endif\n";
        ++block;
      }
    }
  }
  return out.str();
}

class Rs274Test : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!formloop::testing::Rs274Installed()) {
      GTEST_SKIP() << "rs274 (linuxcnc-uspace) is not installed; scripts/setup.sh installs it";
    }
    dir_ = formloop::testing::FreshTestDir("formloop-cnc-rs274");
  }
  void TearDown() override {
    if (!dir_.empty()) std::filesystem::remove_all(dir_);
  }
  std::filesystem::path dir_;
};

TEST_F(Rs274Test, TheProgramAsWrittenEndsInItsOwnCollectorOfflineAlarm) {
  auto o = Options(Dialect::kLinuxCnc);
  o.arm_timeout_s = 2;  // 100 looks of 20 ms
  const auto program = WriteMachineProgram(SyntheticPlan(3), o);
  ASSERT_TRUE(program.ok());
  const auto path = dir_ / "measure.ngc";
  ASSERT_TRUE(WriteFileAtomic(path, program->files[0].text).ok());
  int code = 0;
  const std::string canon = Rs274(path, &code);
  const auto console = *ReadFile(path.string() + ".console");
  EXPECT_NE(code, 0);  // an abort
  EXPECT_NE(console.find("FORMLOOP 1 COLLECTOR OFFLINE"), std::string::npos) << console;
  // formloop's interpreter on the same program with nobody answering: the same dwells, the same abort.
  const auto read = ReadMacroProgram(Dialect::kLinuxCnc, program->files);
  ASSERT_TRUE(read.ok());
  MapEnvironment env;
  MacroInterpreter interpreter(&*read, &env);
  const int dwells = RunToEnd(interpreter);
  EXPECT_EQ(interpreter.state(), MacroInterpreter::State::kAlarm);
  EXPECT_EQ(interpreter.alarm_text(), "FORMLOOP 1 COLLECTOR OFFLINE");
  EXPECT_EQ(dwells, 100);
  EXPECT_EQ(Count(canon, "DWELL(0.0200)"), dwells);
  // Q was incremented through its analog port first: SET_AUX_OUTPUT_VALUE(2, 1).
  const auto aux = AuxOutputs(canon);
  ASSERT_EQ(aux.size(), 1u);
  EXPECT_EQ(aux[0], std::make_pair(2, 1.0));
}

// Every line through rs274: an instant collector in G-code in place of the two HAL lines. rs274's
// probe "stops" at the programmed end, so each axis measures end − reference: with a 0.05 mm search
// the values are in range, with 2 mm the Z value overflows and the program writes the sentinel.
TEST_F(Rs274Test, EveryLineRunsInRs274AndTheDataWordsAreThePackedDeviations) {
  for (const double search_mm : {0.05, 2.0}) {
    auto o = Options(Dialect::kLinuxCnc);
    o.probe.search_mm = search_mm;
    const auto plan = SyntheticPlan(5);
    const auto program = WriteMachineProgram(plan, o);
    ASSERT_TRUE(program.ok());
    const std::string text = Loopback(program->files[0].text);
    const auto path = dir_ / "loopback.ngc";
    ASSERT_TRUE(WriteFileAtomic(path, text).ok());
    int code = 0;
    const std::string canon = Rs274(path, &code);
    EXPECT_EQ(code, 0) << *ReadFile(path.string() + ".console");
    EXPECT_EQ(Count(canon, "STRAIGHT_PROBE("), 5);
    EXPECT_NE(canon.find("PROGRAM_END()"), std::string::npos);
    // Expected: per point D then C = POINT_READY(i); at the end FINISHED(5).
    std::vector<std::pair<int, double>> expected = {{2, 1.0}};
    int overflowed = 0;
    for (const auto& p : plan.points) {
      const ProbePath path_of = ProbePathOf(p, o.probe);
      std::array<int, 3> v{};
      for (int a = 0; a < 3; ++a) {
        double end = 0;
        ParseDouble(FormatFixed(path_of.end[a], 4), &end);
        v[a] = QuantiseDeviation(end - path_of.reference[a]);
        overflowed += v[a] == kOverflowValue ? 1 : 0;
      }
      expected.emplace_back(1, *PackData(v));
      expected.emplace_back(0, EncodeControl(PointReadyWord(static_cast<int>(p.id))));
    }
    expected.emplace_back(0, EncodeControl(FinishedWord(5)));
    EXPECT_EQ(AuxOutputs(canon), expected) << "search " << search_mm;
    EXPECT_EQ(overflowed, search_mm > 1 ? 5 : 0);
    // formloop's interpreter on the same text writes the same words.
    const auto read = ReadMacroProgram(Dialect::kLinuxCnc, {{"loopback.ngc", text}});
    ASSERT_TRUE(read.ok()) << read.status().ToString();
    MapEnvironment env;
    env.probe_at_target = true;
    MacroInterpreter interpreter(&*read, &env);
    RunToEnd(interpreter);
    EXPECT_EQ(interpreter.state(), MacroInterpreter::State::kEnded) << interpreter.alarm_text();
    EXPECT_EQ(env.port_writes, expected);
    // Each write is committed by flipping its port's digital output (the link's event on HAL).
    ASSERT_EQ(env.digital_writes.size(), expected.size());
    std::map<int, bool> level;
    for (std::size_t k = 0; k < expected.size(); ++k) {
      const auto [port, on] = env.digital_writes[k];
      EXPECT_EQ(port, expected[k].first) << "write " << k;
      EXPECT_EQ(on, !level[port]) << "write " << k << " does not flip its commit bit";
      level[port] = on;
    }
  }
}

TEST(MachineProgramRefusals, PlansAndLimitsItCannotWrite) {
  EXPECT_EQ(WriteMachineProgram(SyntheticPlan(2001), Options(Dialect::kFanuc)).status().code(), StatusCode::kBadInput);
  auto plan = SyntheticPlan(3);
  plan.points[1].id = 7;
  const auto ids = WriteMachineProgram(plan, Options(Dialect::kFanuc));
  ASSERT_FALSE(ids.ok());
  EXPECT_NE(ids.status().message().find("renumber"), std::string::npos);
  auto far = SyntheticPlan(3);
  far.points[2].point.x() = 400;  // beyond the default X travel of ±300 mm
  const auto travel = WriteMachineProgram(far, Options(Dialect::kSinumerik));
  EXPECT_EQ(travel.status().code(), StatusCode::kSafetyLimit);
  EXPECT_NE(travel.status().message().find("probe point 3"), std::string::npos) << travel.status().message();
  auto fast = Options(Dialect::kLinuxCnc);
  fast.probe.probe_feed_mm_per_min = 20000;
  EXPECT_EQ(WriteMachineProgram(SyntheticPlan(3), fast).status().code(), StatusCode::kSafetyLimit);
  auto dwell = Options(Dialect::kFanuc);
  dwell.dwell_s = 0.0005;  // G04 X takes milliseconds
  EXPECT_EQ(WriteMachineProgram(SyntheticPlan(3), dwell).status().code(), StatusCode::kBadInput);
  auto block = Options(Dialect::kFanuc);
  block.base = 150;  // the scratch variables' range, volatile
  EXPECT_EQ(WriteMachineProgram(SyntheticPlan(3), block).status().code(), StatusCode::kBadInput);
}

}  // namespace
}  // namespace formloop::cnc

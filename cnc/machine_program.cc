#include "cnc/machine_program.h"

#include <cmath>
#include <functional>
#include <sstream>

#include "core/point_io.h"

namespace formloop::cnc {

namespace {

// Scratch variables, as offsets from the dialect's scratch base.
enum Scratch {
  kCount = 0,  // loop counter of the waits
  kId = 1,     // the point id being sent
  kRef = 2,    // 2..4 reference x, y, z
  kEnd = 5,    // 5..7 probe end x, y, z
  kV = 8,      // 8..10 quantised v_x, v_y, v_z
  kC = 11,     // the control word as last read
  kHd = 12,    // holder bit
  kPt = 13,    // point field
  kSt = 14,    // state field
  kTmp = 15,   // Q + 1, A
  kNumScratch = 16,
};

int ScratchBase(Dialect d) {
  switch (d) {
    case Dialect::kFanuc:
      return 150;
    case Dialect::kLinuxCnc:
      return 1150;
    case Dialect::kSinumerik:
      return 70;
  }
  return 0;
}

// How each dialect spells the few constructs the program needs.
class Emitter {
 public:
  Emitter(Dialect d, BlockLayout block, int decimals) : d_(d), block_(block), decimals_(decimals) {}

  Dialect dialect() const { return d_; }
  std::string S(int k) const { return Var(ScratchBase(d_) + k); }
  std::string Var(int n) const { return (d_ == Dialect::kSinumerik ? "R" : "#") + std::to_string(n); }
  std::string Br(const std::string& x) const { return d_ == Dialect::kSinumerik ? "(" + x + ")" : "[" + x + "]"; }
  std::string Cmp(const std::string& a, const char* op, const std::string& b) const {
    std::string o = op;
    if (d_ == Dialect::kSinumerik) {
      static const std::pair<const char*, const char*> kMap[] = {{"EQ", "=="}, {"NE", "<>"}, {"GT", ">"},
                                                                 {"GE", ">="}, {"LT", "<"},  {"LE", "<="}};
      for (const auto& [w, s] : kMap) {
        if (o == w) o = s;
      }
    }
    return Br(a + " " + o + " " + b);
  }
  std::string Fix(const std::string& x) const { return (d_ == Dialect::kSinumerik ? "TRUNC" : "FIX") + Br(x); }
  std::string Round(const std::string& x) const { return "ROUND" + Br(x); }
  std::string Abs(const std::string& x) const { return "ABS" + Br(x); }
  std::string Num(double v) const { return FormatFixed(v, decimals_); }
  std::string Ref(double v) const { return FormatFixed(v, 4); }
  std::string Int(long long v) const { return std::to_string(v); }

  void Line(const std::string& text) { lines_.push_back(text); }
  void Comment(const std::string& text) {
    if (d_ == Dialect::kSinumerik) {
      Line("; " + text);
    } else {
      Line("(" + text + ")");
    }
  }
  // LinuxCNC takes one value after '=' (a number, a parameter, a function or a [group]): an
  // expression with operators must be bracketed there.
  void Assign(int var, const std::string& expr) {
    if (d_ != Dialect::kLinuxCnc) {
      Line(Var(var) + "=" + expr);
      return;
    }
    const bool simple = expr.find_first_of("+*/", 0) == std::string::npos && expr.find('-', 1) == std::string::npos;
    Line(Var(var) + " = " + (simple ? expr : "[" + expr + "]"));
  }
  void AssignS(int k, const std::string& expr) { Assign(ScratchBase(d_) + k, expr); }
  // Reads block address base+offset into scratch k. LinuxCNC: M66 waits for the motion queue to run
  // empty, so the read happens after the dwell before it. Sinumerik: STOPRE stops the preprocessing,
  // which would otherwise run through the wait loop ahead of the main run with a stale value. Fanuc
  // buffers one NC block ahead: the read after G04 runs while that dwell executes, one dwell early,
  // which only shifts the look and leaves the loop's timing as it is.
  void ReadBlock(int offset, int k) {
    if (d_ == Dialect::kLinuxCnc) {
      Line("M66 E" + Int(block_.base + offset) + " L0");
      AssignS(k, "#5399");
    } else {
      if (d_ == Dialect::kSinumerik) Line("STOPRE");
      AssignS(k, Var(block_.base + offset));
    }
  }
  // LinuxCNC: HAL carries levels, so each write is committed by toggling digital output <port>
  // (M64 sets, M65 clears; its present level is read back through digital input <port>, which the
  // configuration wires to it): the link sees every write as an event, a value equal to the last one
  // included (cnc/linuxcnc_link.h). M68 and M64/M65 are immediate and reach motion in this order.
  void WriteBlock(int offset, const std::string& expr) {
    if (d_ == Dialect::kLinuxCnc) {
      const std::string port = Int(block_.base + offset);
      Line("M68 E" + port + " Q" + Br(expr));
      Line("M66 P" + port + " L0");
      If(Cmp("#5399", "EQ", "0"), "", [&] { Line("M64 P" + port); });
      If(Cmp("#5399", "EQ", "1"), "", [&] { Line("M65 P" + port); });
    } else {
      Assign(block_.base + offset, expr);
    }
  }
  void Dwell(double s) {
    switch (d_) {
      case Dialect::kFanuc:
        Line("G04 X" + FormatFixed(s, 3));
        break;
      case Dialect::kLinuxCnc:
        Line("G4 P" + FormatFixed(s, 3));
        break;
      case Dialect::kSinumerik:
        Line("G4 F" + FormatFixed(s, 3));
        break;
    }
  }
  void Alarm(int n, const std::string& text) {
    switch (d_) {
      case Dialect::kFanuc:
        Line("#3000=" + Int(n) + "(" + text + ")");
        break;
      case Dialect::kLinuxCnc:
        Line("(abort, FORMLOOP " + Int(n) + " " + text + ")");
        break;
      case Dialect::kSinumerik:
        Line("MSG(\"FORMLOOP: " + text + "\")");
        Line("SETAL(" + Int(65000 + n) + ") ; " + text);
        break;
    }
  }
  void Message(const std::string& text) {
    switch (d_) {
      case Dialect::kFanuc:
        Line("#3006=1(" + text + ")");
        break;
      case Dialect::kLinuxCnc:
        Line("(msg, " + text + ")");
        break;
      case Dialect::kSinumerik:
        Line("MSG(\"" + text + "\")");
        break;
    }
  }
  // while (cond) { body }; Fanuc DO levels follow the nesting depth (1..3).
  void While(const std::string& cond, const std::function<void()>& body) {
    const int id = next_block_++;
    switch (d_) {
      case Dialect::kFanuc: {
        const int level = ++loop_depth_;
        Line("WHILE " + cond + " DO" + Int(level));
        body();
        Line("END" + Int(level));
        --loop_depth_;
        break;
      }
      case Dialect::kLinuxCnc:
        Line("o" + Int(id) + " while " + cond);
        body();
        Line("o" + Int(id) + " endwhile");
        break;
      case Dialect::kSinumerik:
        Line("WHILE " + cond);
        body();
        Line("ENDWHILE");
        break;
    }
  }
  // if (cond) { body }. Fanuc has no block IF: IF [not cond] GOTO n ... Nn, with `negated` the
  // complementary condition (the caller states it, Fanuc has no NOT).
  void If(const std::string& cond, const std::string& negated, const std::function<void()>& body) {
    const int id = next_block_++;
    switch (d_) {
      case Dialect::kFanuc: {
        const int label = next_label_++;
        Line("IF " + negated + " GOTO " + Int(label));
        body();
        Line("N" + Int(label));
        break;
      }
      case Dialect::kLinuxCnc:
        Line("o" + Int(id) + " if " + cond);
        body();
        Line("o" + Int(id) + " endif");
        break;
      case Dialect::kSinumerik:
        Line("IF " + cond);
        body();
        Line("ENDIF");
        break;
    }
  }
  void Move(bool rapid, const std::array<double, 3>& p, bool z_only = false) {
    const std::string g = d_ == Dialect::kFanuc ? (rapid ? "G00" : "G01") : (rapid ? "G0" : "G1");
    if (z_only) {
      Line(g + " Z" + Num(p[2]));
    } else {
      Line(g + " X" + Num(p[0]) + " Y" + Num(p[1]) + " Z" + Num(p[2]));
    }
  }
  void MoveXY(const std::array<double, 3>& p) {
    Line(std::string(d_ == Dialect::kFanuc ? "G00" : "G0") + " X" + Num(p[0]) + " Y" + Num(p[1]));
  }
  void Probe(double feed) {
    const std::string xyz = d_ == Dialect::kSinumerik ? "X=" + S(kEnd) + " Y=" + S(kEnd + 1) + " Z=" + S(kEnd + 2)
                                                      : "X" + S(kEnd) + " Y" + S(kEnd + 1) + " Z" + S(kEnd + 2);
    const std::string f = "F" + FormatFixed(feed, 0);
    switch (d_) {
      case Dialect::kFanuc:
        Line("G31 " + xyz + " " + f);
        break;
      case Dialect::kLinuxCnc:
        Line("G38.2 " + xyz + " " + f);
        break;
      case Dialect::kSinumerik:
        Line("MEAS=1 G1 " + xyz + " " + f);
        Line("STOPRE");
        break;
    }
  }
  std::string Measured(int axis) const {
    if (d_ == Dialect::kSinumerik) return std::string("$AA_MW[") + "XYZ"[axis] + "]";
    return "#" + Int(5061 + axis);
  }
  std::string Text() const {
    std::string out;
    for (const auto& l : lines_) out += l + "\n";
    return out;
  }
  void Clear() { lines_.clear(); }

 private:
  Dialect d_;
  BlockLayout block_;
  int decimals_;
  std::vector<std::string> lines_;
  int next_block_ = 100;
  int next_label_ = 1;
  int loop_depth_ = 0;
};

// Loop iterations of a wait of `timeout_s` with one dwell of `dwell_s` per look.
long long Looks(double timeout_s, double dwell_s) {
  return static_cast<long long>(std::ceil(timeout_s / dwell_s - 1e-9));
}

// count := 0; while (waiting AND count < looks) { dwell; count := count + 1; read C; after_read() }.
// Every wait of the program has this shape: its timeout is a number of looks, one dwell each.
void WaitLoop(Emitter& e, const std::string& waiting, double timeout_s, double dwell_s,
              const std::function<void()>& after_read = {}) {
  e.AssignS(kCount, "0");
  e.While(e.Br(waiting + " AND " + e.Cmp(e.S(kCount), "LT", e.Int(Looks(timeout_s, dwell_s)))), [&] {
    e.Dwell(dwell_s);
    e.AssignS(kCount, e.S(kCount) + "+1");
    e.ReadBlock(0, kC);
    if (after_read) after_read();
  });
}

constexpr int kAlarmOffline = 1, kAlarmTimeout = 2, kAlarmAborted = 3, kAlarmHandshake = 4, kAlarmNg = 5,
              kAlarmProbe = 6;

// The send subprogram's body: M2 (quantise, pack, write data then control) and M3.
void SendBody(Emitter& e, const MachineProgramOptions& o) {
  const BlockLayout block = o.Block();
  const Dialect d = e.dialect();
  // A probe that never triggered.
  if (d == Dialect::kFanuc) {
    const std::string at_end = e.Cmp(e.Abs(e.Measured(0) + "-" + e.S(kEnd)), "LT", "0.0001") + " AND " +
                               e.Cmp(e.Abs(e.Measured(1) + "-" + e.S(kEnd + 1)), "LT", "0.0001") + " AND " +
                               e.Cmp(e.Abs(e.Measured(2) + "-" + e.S(kEnd + 2)), "LT", "0.0001");
    const std::string moved = e.Cmp(e.Abs(e.Measured(0) + "-" + e.S(kEnd)), "GE", "0.0001") + " OR " +
                              e.Cmp(e.Abs(e.Measured(1) + "-" + e.S(kEnd + 1)), "GE", "0.0001") + " OR " +
                              e.Cmp(e.Abs(e.Measured(2) + "-" + e.S(kEnd + 2)), "GE", "0.0001");
    e.If(e.Br(at_end), e.Br(moved), [&] { e.Alarm(kAlarmProbe, "PROBE DID NOT TRIGGER"); });
  } else if (d == Dialect::kSinumerik) {
    e.If(e.Cmp("$AC_MEA[1]", "EQ", "0"), "", [&] { e.Alarm(kAlarmProbe, "PROBE DID NOT TRIGGER"); });
  }
  for (int a = 0; a < 3; ++a) {
    e.AssignS(kV + a, e.Round(e.Br(e.Measured(a) + "-" + e.S(kRef + a)) + "*10000"));
    e.If(e.Cmp(e.Abs(e.S(kV + a)), "GE", "1000"), e.Cmp(e.Abs(e.S(kV + a)), "LT", "1000"),
         [&] { e.AssignS(kV + a, "-2048"); });
  }
  if (block.layout == Layout::kPacked) {
    for (int a = 0; a < 3; ++a) {
      e.If(e.Cmp(e.S(kV + a), "LT", "0"), e.Cmp(e.S(kV + a), "GE", "0"),
           [&] { e.AssignS(kV + a, e.S(kV + a) + "+4096"); });
    }
    e.WriteBlock(1, e.S(kV) + "*16777216+" + e.S(kV + 1) + "*4096+" + e.S(kV + 2));
  } else {
    for (int a = 0; a < 3; ++a) e.WriteBlock(1 + a, e.S(kV + a));
  }
  e.WriteBlock(0, e.Int(static_cast<long long>(EncodeControl(PointReadyWord(0)))) + "+" + e.S(kId));
  // M3: wait for the hand-back.
  e.AssignS(kHd, "1");
  WaitLoop(e, e.Cmp(e.S(kHd), "EQ", "1"), o.ack_timeout_s, o.dwell_s,
           [&] { e.AssignS(kHd, e.Fix(e.S(kC) + "/16384") + "-2*" + e.Fix(e.S(kC) + "/32768")); });
  e.If(e.Cmp(e.S(kHd), "EQ", "1"), e.Cmp(e.S(kHd), "NE", "1"), [&] { e.Alarm(kAlarmTimeout, "COLLECTOR TIMEOUT"); });
  e.AssignS(kPt, e.S(kC) + "-4096*" + e.Fix(e.S(kC) + "/4096"));
  e.AssignS(kSt, e.Fix(e.S(kC) + "/4096") + "-4*" + e.Fix(e.S(kC) + "/16384"));
  e.If(e.Cmp(e.S(kPt), "EQ", "4095"), e.Cmp(e.S(kPt), "NE", "4095"),
       [&] { e.Alarm(kAlarmAborted, "ABORTED BY COLLECTOR"); });
  e.If(e.Cmp(e.S(kSt), "NE", "1"), e.Cmp(e.S(kSt), "EQ", "1"), [&] { e.Alarm(kAlarmHandshake, "HANDSHAKE ERROR"); });
  e.If(e.Cmp(e.S(kPt), "NE", e.S(kId)), e.Cmp(e.S(kPt), "EQ", e.S(kId)),
       [&] { e.Alarm(kAlarmHandshake, "HANDSHAKE ERROR"); });
}

std::string Title(const MachineProgramOptions& o, std::size_t points) {
  const BlockLayout b = o.Block();
  std::string where;
  if (o.dialect == Dialect::kLinuxCnc) {
    where = "HAL analog ports E" + std::to_string(b.base) + "-E" + std::to_string(b.base + b.size() - 1) +
            " M68 OUT M66 IN M64/M65 COMMIT";
  } else {
    const std::string v = o.dialect == Dialect::kSinumerik ? "R" : "#";
    where = v + std::to_string(b.base) + "-" + v + std::to_string(b.base + b.size() - 1);
  }
  return "FORMLOOP MEASURING PROGRAM " + std::to_string(points) + " POINTS - HANDSHAKE BLOCK " + where + " " +
         (b.layout == Layout::kPacked ? "PACKED" : "SPLIT") + " - DWELL " + FormatFixed(o.dwell_s, 3) + " S";
}

}  // namespace

Status MachineProgramOptions::Validate() const {
  FL_RETURN_IF_ERROR(probe.Validate());
  // The programs state the dwell in whole milliseconds (Fanuc G04 X takes 0.001 s steps).
  if (!(dwell_s >= 0.001 && dwell_s <= 1 && std::fabs(dwell_s * 1000 - std::round(dwell_s * 1000)) < 1e-9)) {
    return Status::BadInput("dwell_s must be a whole number of milliseconds in [0.001, 1] s");
  }
  for (const auto& [name, t] : {std::pair<const char*, double>{"arm_timeout_s", arm_timeout_s},
                                {"ack_timeout_s", ack_timeout_s},
                                {"finish_timeout_s", finish_timeout_s}}) {
    if (!(t >= dwell_s && t <= 3600)) return Status::BadInput(std::string(name) + " must be in [dwell_s, 3600] s");
  }
  const BlockLayout b = Block();
  switch (dialect) {
    case Dialect::kFanuc:
      if (b.base < 500 || b.base + b.size() - 1 > 999) {
        return Status::BadInput("Fanuc block #" + std::to_string(b.base) +
                                ".. must lie in the retained common variables #500-#999");
      }
      if (program_number < 1 || program_number > 9998) return Status::BadInput("program_number must be 1..9998");
      break;
    case Dialect::kSinumerik:
      if (b.base < ScratchBase(dialect) + kNumScratch || b.base + b.size() - 1 > probe.sinumerik_r_last) {
        return Status::BadInput("Sinumerik block R" + std::to_string(b.base) + ".. must lie between R" +
                                std::to_string(ScratchBase(dialect) + kNumScratch) + " and R" +
                                std::to_string(probe.sinumerik_r_last));
      }
      break;
    case Dialect::kLinuxCnc:
      if (b.base < 0 || b.base + b.size() > 64) return Status::BadInput("LinuxCNC analog ports must be E0..E63");
      break;
  }
  return Status::Ok();
}

int MachineProgramOptions::ResolvedBase() const {
  if (base >= 0) return base;
  switch (dialect) {
    case Dialect::kFanuc:
      return 900;
    case Dialect::kSinumerik:
      return 90;
    case Dialect::kLinuxCnc:
      return 0;
  }
  return 0;
}

std::array<double, 3> ReferenceOf(const metrology::ProbePoint& point, double ball_radius_mm) {
  std::array<double, 3> r{};
  for (int a = 0; a < 3; ++a) {
    const double v = point.point[a] + ball_radius_mm * point.normal[a];
    double parsed = 0;
    ParseDouble(FormatFixed(v, 4), &parsed);  // exactly what the program states
    r[a] = parsed;
  }
  return r;
}

ProbePath ProbePathOf(const metrology::ProbePoint& p, const nc::ProbeProgramOptions& o) {
  ProbePath path;
  for (int a = 0; a < 3; ++a) {
    const double centre = p.point[a] + o.ball_radius_mm * p.normal[a];
    path.clearance[a] = centre + o.clearance_mm * p.normal[a];
    path.end[a] = centre - o.search_mm * p.normal[a];
  }
  path.above = path.clearance;
  path.above[2] = o.safe_z_mm;
  path.reference = ReferenceOf(p, o.ball_radius_mm);
  return path;
}

std::string MainProgramFileName(Dialect dialect) {
  switch (dialect) {
    case Dialect::kFanuc:
      return "measure.nc";
    case Dialect::kLinuxCnc:
      return "measure.ngc";
    case Dialect::kSinumerik:
      return "FL_MEASURE.MPF";
  }
  return "measure";
}

Result<MachineProgram> WriteMachineProgram(const metrology::ProbingPlan& plan, const MachineProgramOptions& o) {
  FL_RETURN_IF_ERROR(o.Validate());
  const std::size_t n = plan.points.size();
  if (n == 0) return Status::BadInput("the probing plan has no points");
  if (n > static_cast<std::size_t>(kMaxPointId)) {
    return Status::BadInput("the plan has " + std::to_string(n) + " points; one measuring run carries at most " +
                            std::to_string(kMaxPointId) + " (12-bit point ids); split the plan into runs");
  }
  for (std::size_t k = 0; k < n; ++k) {
    if (plan.points[k].id != static_cast<std::int64_t>(k + 1)) {
      return Status::BadInput("point " + std::to_string(k + 1) + " of the plan has id " +
                              std::to_string(plan.points[k].id) +
                              "; the handshake sends ids 1..N in plan order, renumber the plan");
    }
  }
  if (o.probe.probe_feed_mm_per_min > o.probe.post.limits.max_feed_mm_per_min) {
    return Status::SafetyLimit("probe feed " + FormatFixed(o.probe.probe_feed_mm_per_min, 0) +
                               " mm/min exceeds the machine's feed limit; no measuring program was written");
  }
  std::vector<ProbePath> paths;
  for (const auto& p : plan.points) {
    ProbePath path = ProbePathOf(p, o.probe);
    const std::string what = "probe point " + std::to_string(p.id);
    for (const auto* q : {&path.above, &path.clearance, &path.end}) {
      FL_RETURN_IF_ERROR(nc::CheckTravel(o.probe.post.limits, Eigen::Vector3d((*q)[0], (*q)[1], (*q)[2]), what));
    }
    paths.push_back(path);
  }

  const BlockLayout block = o.Block();
  const Dialect d = o.dialect;
  Emitter e(d, block, o.probe.post.decimals);
  const int q_offset = block.run_counter() - block.base, a_offset = block.alarm() - block.base;
  MachineProgram program;
  program.block = block;
  program.points = static_cast<int>(n);
  const std::string title = Title(o, n);
  const std::string send_name = d == Dialect::kFanuc ? std::to_string(o.program_number + 1) : "FL_SEND";

  // Header.
  if (d == Dialect::kFanuc) {
    e.Line("%");
    e.Line("O" + std::to_string(o.program_number) + " (" + title + ")");
  } else if (d == Dialect::kLinuxCnc) {
    e.Line("%");
    e.Comment(title);
  } else {
    e.Comment(title);
  }
  if (!o.probe.post.title.empty()) e.Comment(o.probe.post.title);
  e.Comment("STYLUS BALL RADIUS " + FormatFixed(o.probe.ball_radius_mm, 4) +
            " MM - REFERENCE = BALL CENTRE AT NOMINAL CONTACT");
  if (d == Dialect::kLinuxCnc) {
    // The send subprogram first: LinuxCNC wants a sub defined before its call.
    e.Line("o<fl_send> sub");
    SendBody(e, o);
    e.Line("o<fl_send> endsub");
  }
  e.Line(d == Dialect::kSinumerik ? "G71 G90 G17 G40 G94" : "G21 G90 G17 G94 G40 G49 G80");
  // The probe in the spindle with its length offset (measured to the stylus-ball centre, the programmed
  // point), as in nc-gen's probing programs: T.. M6, then G43 H<tool> with the first Z move (Sinumerik: D1).
  const std::string probe_tool = std::to_string(o.probe.probe_tool);
  switch (d) {
    case Dialect::kFanuc:
      e.Line("T" + probe_tool + " M06");
      break;
    case Dialect::kLinuxCnc:
      e.Line("T" + probe_tool + " M6");
      break;
    case Dialect::kSinumerik:
      e.Line("T" + probe_tool + " D1");
      e.Line("M6");
      break;
  }
  // An earlier part's NG result waits for the operator.
  e.ReadBlock(a_offset, kTmp);
  e.If(e.Cmp(e.S(kTmp), "GT", "0"), e.Cmp(e.S(kTmp), "LE", "0"),
       [&] { e.Alarm(kAlarmNg, "DIMENSION NG - ACKNOWLEDGE THE ALARM REQUEST"); });
  // M0.
  e.ReadBlock(q_offset, kTmp);
  e.WriteBlock(q_offset, e.S(kTmp) + "+1");
  // M1.
  const std::string arm = e.Int(static_cast<long long>(EncodeControl(MeasuringWord(0))));
  e.ReadBlock(0, kC);
  WaitLoop(e, e.Cmp(e.S(kC), "NE", arm), o.arm_timeout_s, o.dwell_s);
  e.If(e.Cmp(e.S(kC), "NE", arm), e.Cmp(e.S(kC), "EQ", arm), [&] { e.Alarm(kAlarmOffline, "COLLECTOR OFFLINE"); });
  if (d == Dialect::kSinumerik) {
    e.Move(true, {0, 0, o.probe.safe_z_mm}, true);
  } else {
    e.Line(std::string(d == Dialect::kFanuc ? "G00" : "G0") + " G43 H" + probe_tool + " Z" + e.Num(o.probe.safe_z_mm));
  }
  const bool trips = o.log_trips && d == Dialect::kLinuxCnc;
  if (trips) e.Line("(PROBEOPEN " + nc::CommentText(o.probe.results_file) + ")");
  for (std::size_t k = 0; k < n; ++k) {
    const ProbePath& p = paths[k];
    e.Comment("POINT " + std::to_string(k + 1));
    e.MoveXY(p.above);
    e.Move(true, p.clearance, true);
    for (int a = 0; a < 3; ++a) e.AssignS(kEnd + a, e.Num(p.end[a]));
    e.Probe(o.probe.probe_feed_mm_per_min);
    e.AssignS(kId, std::to_string(k + 1));
    for (int a = 0; a < 3; ++a) e.AssignS(kRef + a, e.Ref(p.reference[a]));
    switch (d) {
      case Dialect::kFanuc:
        e.Line("M98 P" + send_name);
        break;
      case Dialect::kLinuxCnc:
        e.Line("o<fl_send> call");
        break;
      case Dialect::kSinumerik:
        e.Line(send_name);
        break;
    }
    e.Move(true, p.clearance);
    e.Move(true, p.above, true);
  }
  if (trips) e.Line("(PROBECLOSE)");
  // M4, M5.
  e.WriteBlock(0, e.Int(static_cast<long long>(EncodeControl(FinishedWord(static_cast<int>(n))))));
  e.ReadBlock(0, kC);
  WaitLoop(e, e.Cmp(e.S(kC), "NE", "0"), o.finish_timeout_s, o.dwell_s);
  e.If(e.Cmp(e.S(kC), "NE", "0"), e.Cmp(e.S(kC), "EQ", "0"), [&] { e.Message("MEASUREMENT NOT CONFIRMED"); });
  if (d == Dialect::kFanuc) {
    e.Line("M30");
    e.Line("O" + send_name + " (FORMLOOP SEND POINT - ID " + e.S(kId) + " REFERENCE " + e.S(kRef) + "-" +
           e.S(kRef + 2) + ")");
    SendBody(e, o);
    e.Line("M99");
    e.Line("%");
  } else if (d == Dialect::kLinuxCnc) {
    e.Line("M2");
    e.Line("%");
  } else {
    e.Line("M30");
  }
  program.files.push_back({MainProgramFileName(d), e.Text()});
  if (d == Dialect::kSinumerik) {
    e.Clear();
    e.Line("PROC FL_SEND");
    e.Comment("FORMLOOP SEND POINT - ID " + e.S(kId) + " REFERENCE " + e.S(kRef) + "-" + e.S(kRef + 2));
    SendBody(e, o);
    e.Line("M17");
    program.files.push_back({"FL_SEND.SPF", e.Text()});
  }
  return program;
}

Result<metrology::ProbeLog> ProbeLogOfSession(const Session& session, const metrology::ProbingPlan& plan,
                                              const std::vector<Eigen::Vector3d>& approaches, double ball_radius_mm,
                                              std::vector<int>* skipped) {
  metrology::ProbeLog log;
  for (const auto& p : session.points) {
    if (p.id < 1 || p.id > static_cast<int>(plan.points.size())) {
      return Status::BadInput("point " + std::to_string(p.id) + " is not in the plan (" +
                              std::to_string(plan.points.size()) + " points)");
    }
    if (!p.decoded.ok()) {
      if (skipped != nullptr) skipped->push_back(p.id);
      continue;
    }
    const auto& planned = plan.points[static_cast<std::size_t>(p.id - 1)];
    const auto ref = ReferenceOf(planned, ball_radius_mm);
    metrology::ProbeRecord r;
    r.id = p.id;
    for (std::size_t k = 0; k < 3; ++k) {
      r.centre[static_cast<Eigen::Index>(k)] = ref[k] + p.decoded.v[k] * kValueUnitMm;
    }
    r.approach = approaches.empty() ? Eigen::Vector3d(-planned.normal) : approaches[static_cast<std::size_t>(p.id - 1)];
    r.t_s = p.t_s;
    log.records.push_back(r);
  }
  return log;
}

}  // namespace formloop::cnc

#pragma once
// Runs a machine-side program (cnc/macro_code.h) the way its controller would, one instruction at a
// time, against a MachineEnvironment that holds the controller's memory, I/O and probe. The emulated
// controller (cnc/controller.h) drives it from its event scheduler: Run() executes until the next
// instruction that takes time (a dwell or a probing move), the end, or an alarm, and says how long to
// wait; the controller schedules the next Run() after that time.
//
// Modelled per dialect (cnc/macro_code.h): vacant Fanuc variables, rounding and truncation functions,
// LinuxCNC's C-int round, the probe result variables (Fanuc #5061..#5063 = skip position, the end
// point when the skip signal never came; LinuxCNC #5061..#5063 and #5070, G38.2 without contact is an
// error; Sinumerik $AA_MW[X..Z] and $AC_MEA[1]), division by zero as an alarm, a call depth limit,
// and a guard against loops that never let time pass.

#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

#include "cnc/macro_code.h"
#include "cnc/transport.h"

namespace formloop::cnc {

struct ProbeOutcome {
  bool tripped = false;
  std::array<double, 3> position{};  // where the stylus centre stopped (the trigger point when tripped)
  double duration_s = 0;
};

class MachineEnvironment {
 public:
  virtual ~MachineEnvironment() = default;
  // Fanuc #n and Sinumerik Rn: the controller's variable memory (what the API also sees).
  virtual MacroValue ReadVariable(int number) = 0;
  virtual void WriteVariable(int number, MacroValue value) = 0;
  // LinuxCNC analog I/O: M66 E<port> L0 reads, M68 E<port> Q<v> writes (HAL motion.analog-in/out).
  virtual double PortIn(int port) = 0;
  virtual void PortOut(int port, double value) = 0;
  // LinuxCNC digital I/O: M64/M65 P<port> set/clear motion.digital-out-NN, M66 P<port> L0 reads
  // motion.digital-in-NN. formloop's configuration wires each output back to its input (the link's
  // commit bits, cnc/linuxcnc_link.h); so does this default.
  virtual bool DigitalIn(int port) { return digital_[port]; }
  virtual void DigitalOut(int port, bool on) { digital_[port] = on; }
  virtual ProbeOutcome Probe(const std::array<double, 3>& from, const std::array<double, 3>& to, double feed) = 0;
  virtual void Message(const std::string& text) = 0;
  // Called at each "point <id>" comment before the point's blocks run: go on, continue at another
  // point's comment (a repeated or skipped block), or stop the program here (a reset).
  struct MarkAction {
    enum class Kind { kContinue, kJump, kStop } kind = Kind::kContinue;
    int target = 0;
  };
  virtual MarkAction OnPointMark(int id) { return {}; }

 private:
  std::map<int, bool> digital_;
};

class MacroInterpreter {
 public:
  enum class State { kRunning, kEnded, kAlarm, kStopped };
  struct Step {
    State state = State::kRunning;
    double wait_s = 0;  // kRunning: time the executed instruction takes before the next Run()
  };

  MacroInterpreter(const MacroCode* code, MachineEnvironment* env);

  Step Run();
  // kStopped: OnPointMark asked to stop (a reset); Restart() continues from the top.
  // Back to the program's first instruction (a reset and cycle start); LinuxCNC parameters are kept
  // (they live in the interpreter as on the real controller), the call stack and alarm are cleared.
  void Restart();
  // Continues at the "point <id>" comment (fault injection: an operator restarting at a block, a
  // block skip). False when the program has no such mark.
  bool JumpToMark(int id);

  State state() const { return state_; }
  int alarm_number() const { return alarm_number_; }
  const std::string& alarm_text() const { return alarm_text_; }
  // "file:line" of the instruction executed last.
  std::string Where() const;
  std::uint64_t executed() const { return executed_; }
  // Largest number of instructions run without time passing before the guard raises an alarm.
  static constexpr std::uint64_t kMaxInstructionsWithoutTime = 2'000'000;
  static constexpr int kMaxCallDepth = 8;

 private:
  MacroValue Eval(const Expr& e);
  double Number(const Expr& e);  // vacant → 0
  MacroValue ReadVar(const VarRef& v);
  void WriteVar(const VarRef& v, MacroValue value);
  void RaiseAlarm(int number, std::string text);

  const MacroCode* code_;
  MachineEnvironment* env_;
  int pc_ = 0;
  std::vector<int> stack_;
  State state_ = State::kRunning;
  int alarm_number_ = 0;
  std::string alarm_text_;
  std::unordered_map<int, double> params_;  // LinuxCNC numbered parameters
  std::array<double, 3> position_{};
  std::array<double, 3> measured_{};
  bool measured_ok_ = false;
  int last_pc_ = 0;
  std::uint64_t executed_ = 0;
};

}  // namespace formloop::cnc

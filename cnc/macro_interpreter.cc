#include "cnc/macro_interpreter.h"

#include <climits>
#include <cmath>

namespace formloop::cnc {

namespace {

struct ArithmeticError {
  std::string what;
};

double RoundHalfAway(double x) { return x >= 0 ? std::floor(x + 0.5) : -std::floor(-x + 0.5); }

// LinuxCNC's round[]: (double)(int)(x ± 0.5); a value a C int cannot hold comes out as INT_MIN on
// x86-64 (cvttsd2si), which is what the installed rs274 prints for round[68719476735.4].
double RoundCInt(double x) {
  const double shifted = x + (x < 0 ? -0.5 : 0.5);
  if (!(shifted > static_cast<double>(INT_MIN) - 1.0 && shifted < static_cast<double>(INT_MAX) + 1.0)) {
    return static_cast<double>(INT_MIN);
  }
  return static_cast<double>(static_cast<int>(shifted));
}

}  // namespace

MacroInterpreter::MacroInterpreter(const MacroCode* code, MachineEnvironment* env) : code_(code), env_(env) {
  pc_ = code_->entry;
}

void MacroInterpreter::Restart() {
  pc_ = code_->entry;
  stack_.clear();
  state_ = State::kRunning;
  alarm_number_ = 0;
  alarm_text_.clear();
}

bool MacroInterpreter::JumpToMark(int id) {
  const auto it = code_->marks.find(id);
  if (it == code_->marks.end()) return false;
  pc_ = it->second;
  return true;
}

std::string MacroInterpreter::Where() const {
  if (last_pc_ < 0 || last_pc_ >= static_cast<int>(code_->instrs.size())) return "?";
  const SourcePos& p = code_->instrs[last_pc_].pos;
  return code_->files[p.file] + ":" + std::to_string(p.line);
}

void MacroInterpreter::RaiseAlarm(int number, std::string text) {
  state_ = State::kAlarm;
  alarm_number_ = number;
  alarm_text_ = std::move(text);
}

MacroValue MacroInterpreter::ReadVar(const VarRef& v) {
  switch (v.space) {
    case VarRef::Space::kMeasured:
      return measured_[v.number];
    case VarRef::Space::kMeasureStatus:
      return measured_ok_ ? 1.0 : 0.0;
    case VarRef::Space::kNumbered:
      break;
  }
  const int n = v.number;
  switch (code_->dialect) {
    case Dialect::kFanuc:
      if (n == 0) return std::nullopt;
      if (n >= 5061 && n <= 5063) return measured_[n - 5061];
      return env_->ReadVariable(n);
    case Dialect::kLinuxCnc: {
      if (n >= 5061 && n <= 5063) return measured_[n - 5061];
      if (n == 5070) return measured_ok_ ? 1.0 : 0.0;
      const auto it = params_.find(n);
      return it == params_.end() ? 0.0 : it->second;
    }
    case Dialect::kSinumerik: {
      const MacroValue value = env_->ReadVariable(n);
      return value ? value : MacroValue(0.0);  // R parameters are never vacant
    }
  }
  return std::nullopt;
}

void MacroInterpreter::WriteVar(const VarRef& v, MacroValue value) {
  if (code_->dialect == Dialect::kLinuxCnc) {
    params_[v.number] = value.value_or(0.0);
  } else {
    env_->WriteVariable(v.number, code_->dialect == Dialect::kSinumerik ? MacroValue(value.value_or(0.0)) : value);
  }
}

double MacroInterpreter::Number(const Expr& e) { return Eval(e).value_or(0.0); }

MacroValue MacroInterpreter::Eval(const Expr& e) {
  using Op = Expr::Op;
  switch (e.op) {
    case Op::kNumber:
      return e.number;
    case Op::kVar:
      return ReadVar(e.var);
    case Op::kNeg:
      return -Number(e.args[0]);
    case Op::kAdd:
      return Number(e.args[0]) + Number(e.args[1]);
    case Op::kSub:
      return Number(e.args[0]) - Number(e.args[1]);
    case Op::kMul:
      return Number(e.args[0]) * Number(e.args[1]);
    case Op::kDiv: {
      const double den = Number(e.args[1]);
      if (den == 0) throw ArithmeticError{"division by zero"};
      return Number(e.args[0]) / den;
    }
    case Op::kEq:
    case Op::kNe: {
      // Fanuc tells vacant from 0 in EQ and NE; the other dialects have no vacant values.
      const MacroValue a = Eval(e.args[0]), b = Eval(e.args[1]);
      const bool equal = (a.has_value() == b.has_value()) && (!a || *a == *b);
      return (e.op == Op::kEq) == equal ? 1.0 : 0.0;
    }
    case Op::kGt:
      return Number(e.args[0]) > Number(e.args[1]) ? 1.0 : 0.0;
    case Op::kGe:
      return Number(e.args[0]) >= Number(e.args[1]) ? 1.0 : 0.0;
    case Op::kLt:
      return Number(e.args[0]) < Number(e.args[1]) ? 1.0 : 0.0;
    case Op::kLe:
      return Number(e.args[0]) <= Number(e.args[1]) ? 1.0 : 0.0;
    case Op::kAnd:
      return (Number(e.args[0]) != 0 && Number(e.args[1]) != 0) ? 1.0 : 0.0;
    case Op::kOr:
      return (Number(e.args[0]) != 0 || Number(e.args[1]) != 0) ? 1.0 : 0.0;
    case Op::kTrunc:
      return std::trunc(Number(e.args[0]));
    case Op::kFloor:
      return std::floor(Number(e.args[0]));
    case Op::kCeil:
      return std::ceil(Number(e.args[0]));
    case Op::kAwayFromZero: {
      const double x = Number(e.args[0]);
      return x >= 0 ? std::ceil(x) : -std::ceil(-x);
    }
    case Op::kRound:
      return RoundHalfAway(Number(e.args[0]));
    case Op::kRoundCInt:
      return RoundCInt(Number(e.args[0]));
    case Op::kAbs:
      return std::fabs(Number(e.args[0]));
  }
  return std::nullopt;
}

MacroInterpreter::Step MacroInterpreter::Run() {
  std::uint64_t without_time = 0;
  while (state_ == State::kRunning) {
    if (pc_ < 0 || pc_ >= static_cast<int>(code_->instrs.size())) {
      RaiseAlarm(1, "execution ran past the end of the program");
      break;
    }
    if (++without_time > kMaxInstructionsWithoutTime) {
      RaiseAlarm(2, "the program loops without a dwell at " + Where());
      break;
    }
    const Instr& in = code_->instrs[pc_];
    last_pc_ = pc_;
    ++executed_;
    ++pc_;
    try {
      switch (in.kind) {
        case Instr::Kind::kNop:
          if (in.mark > 0) {
            const auto action = env_->OnPointMark(in.mark);
            if (action.kind == MachineEnvironment::MarkAction::Kind::kStop) {
              pc_ = last_pc_;
              state_ = State::kStopped;
            } else if (action.kind == MachineEnvironment::MarkAction::Kind::kJump && action.target != in.mark) {
              const auto it = code_->marks.find(action.target);
              if (it != code_->marks.end()) pc_ = it->second + 1;
            }
          }
          break;
        case Instr::Kind::kAssign:
          WriteVar(in.target, Eval(in.value));
          break;
        case Instr::Kind::kJump:
          pc_ = in.jump;
          break;
        case Instr::Kind::kJumpIf:
          if (Number(in.value) != 0) pc_ = in.jump;
          break;
        case Instr::Kind::kJumpIfNot:
          if (Number(in.value) == 0) pc_ = in.jump;
          break;
        case Instr::Kind::kDwell: {
          const double seconds = Number(in.value);
          if (!(seconds >= 0)) throw ArithmeticError{"negative dwell"};
          return Step{State::kRunning, seconds};
        }
        case Instr::Kind::kMove:
          for (int a = 0; a < 3; ++a) {
            if (in.axes[a]) position_[a] = Number(*in.axes[a]);
          }
          break;
        case Instr::Kind::kProbe: {
          std::array<double, 3> target = position_;
          for (int a = 0; a < 3; ++a) target[a] = Number(*in.axes[a]);
          const ProbeOutcome out = env_->Probe(position_, target, Number(*in.feed));
          measured_ok_ = out.tripped;
          if (out.tripped) {
            measured_ = out.position;
          } else if (code_->dialect == Dialect::kFanuc) {
            measured_ = target;  // G31 without a skip signal ends at the programmed point
          } else if (code_->dialect == Dialect::kLinuxCnc) {
            RaiseAlarm(0, "G38.2: move finished without making contact");
          }
          position_ = out.tripped ? out.position : target;
          if (state_ != State::kRunning) break;
          return Step{State::kRunning, out.duration_s};
        }
        case Instr::Kind::kCall:
          if (static_cast<int>(stack_.size()) >= kMaxCallDepth)
            throw ArithmeticError{"subprogram calls nested too deep"};
          stack_.push_back(pc_);
          pc_ = in.jump;
          break;
        case Instr::Kind::kReturn:
          if (stack_.empty()) {
            RaiseAlarm(3, "return without a call");
            break;
          }
          pc_ = stack_.back();
          stack_.pop_back();
          break;
        case Instr::Kind::kEnd:
          state_ = State::kEnded;
          break;
        case Instr::Kind::kAlarm:
          RaiseAlarm(in.number, in.text);
          break;
        case Instr::Kind::kMessage:
          env_->Message(in.text);
          break;
        case Instr::Kind::kPortOut:
          env_->PortOut(in.number, Number(in.value));
          break;
        case Instr::Kind::kPortIn:
          params_[5399] = env_->PortIn(in.number);
          break;
        case Instr::Kind::kDigitalOut:
          env_->DigitalOut(in.number, Number(in.value) != 0);
          break;
        case Instr::Kind::kDigitalIn:
          params_[5399] = env_->DigitalIn(in.number) ? 1 : 0;
          break;
      }
    } catch (const ArithmeticError& e) {
      RaiseAlarm(4, e.what + " at " + Where());
    }
  }
  return Step{state_, 0};
}

}  // namespace formloop::cnc

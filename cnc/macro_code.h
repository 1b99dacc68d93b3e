#pragma once
// Machine-side macro programs read into one instruction list, for the three dialects formloop writes
// (cnc/machine_program.h): Fanuc custom macro B, LinuxCNC O-codes with numbered parameters, Siemens
// Sinumerik 840D with R parameters. The reader accepts exactly the subset formloop writes (plus
// comments and modal codes), checks every line — addresses of variables against the dialect's ranges,
// expression syntax, matched loops and conditionals, jump and call targets — and names the file and
// line of the first problem. The interpreter (cnc/macro_interpreter.h) runs the result in the
// emulated controller, so the program a shop loads is the program the tests run.
//
// Dialect semantics that differ and are modelled, not smoothed over:
//   Fanuc  FIX truncates toward zero, FUP away from zero, ROUND half away from zero; a vacant variable
//          (#0) reads as 0 in arithmetic and GT/GE/LT/LE but EQ/NE tell it from 0; [] group; AND
//          binds like *, OR like + (Fanuc's precedence), comparisons only in IF/WHILE.
//          Manual: FANUC Series 0i-MODEL F Operator's Manual (B-64604EN), "Custom macro".
//   LinuxCNC fix = floor, fup = ceil, round = half away from zero through a C int (values beyond
//          ±2^31 come out as −2147483648, as the installed rs274 shows); [] group; parameters are 0
//          until set. LinuxCNC G-code reference, "O Codes", "Numbered parameters", M66/M68.
//   Sinumerik TRUNC toward zero, ROUND half away from zero; () group; ==, <>, AND, OR.
//          SINUMERIK 840D sl Programming Manual Job Planning, "Flexible NC programming".

#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "core/status.h"

namespace formloop::cnc {

enum class Dialect { kFanuc, kLinuxCnc, kSinumerik };
const char* DialectName(Dialect dialect);  // "fanuc", "linuxcnc", "sinumerik"
Result<Dialect> ParseDialect(const std::string& name);

// A variable: Fanuc #n, LinuxCNC #n, Sinumerik Rn; the probe's measured position and its status.
struct VarRef {
  enum class Space : std::uint8_t { kNumbered, kMeasured, kMeasureStatus };
  Space space = Space::kNumbered;
  int number = 0;  // kNumbered: the number; kMeasured: axis 0..2
};

struct Expr {
  enum class Op : std::uint8_t {
    kNumber,
    kVar,
    kNeg,
    kAdd,
    kSub,
    kMul,
    kDiv,
    kEq,
    kNe,
    kGt,
    kGe,
    kLt,
    kLe,
    kAnd,
    kOr,
    kTrunc,         // toward zero (Fanuc FIX, Sinumerik TRUNC)
    kFloor,         // LinuxCNC fix
    kCeil,          // LinuxCNC fup
    kAwayFromZero,  // Fanuc FUP
    kRound,         // half away from zero in double (Fanuc ROUND, Sinumerik ROUND)
    kRoundCInt,     // LinuxCNC round: half away from zero through a C int
    kAbs,
  };
  Op op = Op::kNumber;
  double number = 0;
  VarRef var;
  std::vector<Expr> args;
};

struct SourcePos {
  int file = 0;  // index into MacroCode::files
  int line = 0;  // 1-based
};

struct Instr {
  enum class Kind : std::uint8_t {
    kNop,        // comments, modal codes, STOPRE; `mark` > 0 for a "point <id>" comment
    kAssign,     // target = value
    kJump,       // to `jump`
    kJumpIf,     // to `jump` when value (a condition) is true (Fanuc IF [..] GOTO n)
    kJumpIfNot,  // to `jump` when value (a condition) is false (loops, IF/ENDIF)
    kDwell,      // value = seconds
    kMove,       // rapid or feed to axes (absolute, mm)
    kProbe,      // probing move to axes; result in the measured variables
    kCall,       // to `jump`, pushing the return address
    kReturn,
    kEnd,         // program end (M30 / M2)
    kAlarm,       // alarm `number` with `text`; the program stops
    kMessage,     // operator message `text`; the program goes on
    kPortOut,     // LinuxCNC M68 E<number> Q<value>
    kPortIn,      // LinuxCNC M66 E<number> L0 → #5399
    kDigitalOut,  // LinuxCNC M64 P<number> (on, value 1) / M65 P<number> (off, value 0)
    kDigitalIn,   // LinuxCNC M66 P<number> L0 → #5399 (0 or 1)
  };
  Kind kind = Kind::kNop;
  SourcePos pos;
  VarRef target;
  Expr value;
  std::array<std::optional<Expr>, 3> axes;
  std::optional<Expr> feed;
  bool rapid = false;
  int jump = -1;
  int number = 0;
  int mark = 0;
  std::string text;
};

struct MacroFile {
  std::string name;  // file name, for messages
  std::string text;
};

struct MacroCode {
  Dialect dialect = Dialect::kFanuc;
  std::vector<std::string> files;
  std::vector<Instr> instrs;
  int entry = 0;                    // first instruction of the main program
  std::map<int, int> marks;         // point id → instruction of its "point <id>" comment
  std::map<std::string, int> subs;  // subprogram name ("1001", "fl_send", "FL_SEND") → entry
};

// Variable ranges a program may use (reads and writes), per dialect; defaults are the controllers'
// standard ones. Fanuc: #1–#33 local, #100–#199 and #500–#999 common; LinuxCNC: #1–#5000 user
// (#5061–#5063, #5070, #5399 read only); Sinumerik: R0..R<r_last> (MD28050 MM_NUM_R_PARAM − 1).
struct MacroLimits {
  int sinumerik_r_last = 99;
  // motion.num_aio and motion.num_dio, analog and digital ports (LinuxCNC's default 4 each; motmod
  // num_aio=N num_dio=N raise them).
  int linuxcnc_ports = 4;
};

// Reads and checks the files of one program (the first file holds the main program; Sinumerik
// subprograms follow as their own files, named NAME.SPF). Errors name file, line and what is wrong.
Result<MacroCode> ReadMacroProgram(Dialect dialect, const std::vector<MacroFile>& files,
                                   const MacroLimits& limits = {});

}  // namespace formloop::cnc

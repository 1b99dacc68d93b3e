#pragma once
// Test support: LinuxCNC's standalone interpreter `rs274 -g` (Debian linuxcnc-uspace) as the reference
// reader of RS274NGC programs, run with a tool table as a machine would run them, and a parser of its
// canonical commands written here, independent of formloop's G-code reader (nc-gen/gcode_reader.h), so the
// two can be compared:
//
//   STRAIGHT_TRAVERSE(x, y, z, a, b, c)      G0
//   STRAIGHT_FEED(x, y, z, a, b, c)          G1
//   STRAIGHT_PROBE(x, y, z, ...)             G38.x
//   ARC_FEED(first_end, second_end, first_centre, second_centre, rotation, axis_end, a, b, c)
//       in the selected plane: XY first = X, second = Y, axis = Z; XZ first = Z, second = X, axis = Y;
//       YZ first = Y, second = Z, axis = X. rotation > 0 counter-clockwise in (first, second),
//       < 0 clockwise; |rotation| − 1 extra full turns.
//
// Positions are in the program's units and its current work coordinate system (as rs274 prints them):
// the controlled point, without the tool length offset, which rs274 reports apart
// (USE_TOOL_LENGTH_OFFSET). The parser keeps the tool in the spindle (SELECT_TOOL, CHANGE_TOOL) and the
// active length offset at every motion.
//
// The tool table (Rs274ToolLengthsMm) gives every tool formloop's tests use a different, non-zero length,
// so a program that does not activate the length offset of the tool in the spindle (G43 H<tool>) is
// caught (tests/nc-gen/rs274_test.cc): the offset at its moves is then 0 or another tool's. Without a table
// rs274 knows tools 1-3 with length 0; this table holds those and the probe's default number 99. The
// standalone interpreter reads the table in its machine units, inches (a Z of 3.0 becomes 76.2 mm in its
// millimetre output), so the lengths are written in inches and stated here in mm.

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include <fcntl.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <Eigen/Core>

namespace formloop::testing {

inline bool Rs274Installed() { return std::system("command -v rs274 >/dev/null 2>&1") == 0; }

// Tool number -> length in mm (a whole number of tenths of an inch, so the inch table is exact).
inline const std::map<int, double>& Rs274ToolLengthsMm() {
  static const std::map<int, double> lengths = {{1, 63.5}, {2, 71.12}, {3, 76.2}, {99, 114.3}};
  return lengths;
}

// Runs `rs274 -t table -g program` with the tool table above and returns the canonical commands (empty
// when rs274 wrote none); *exit_code and *console receive the exit status and what rs274 printed. rs274
// keeps its tool table in shared memory, so two of them running at once disturb each other ("Requested
// tool 1 not found", bus errors): runs from parallel ctest processes take turns through an exclusive lock
// on a file in the temp directory. The table and the canonical output go to the temp directory, never
// next to the program (which may sit in read-only reference data).
inline std::string RunRs274(const std::filesystem::path& program, int* exit_code, std::string* console) {
  const std::filesystem::path lock_path = std::filesystem::temp_directory_path() / "formloop-rs274.lock";
  const int lock = ::open(lock_path.c_str(), O_RDWR | O_CREAT, 0666);
  if (lock >= 0) ::flock(lock, LOCK_EX);
  const std::string stem = (std::filesystem::temp_directory_path() /
                            ("formloop-rs274-" + std::to_string(::getpid()) + "-" + program.filename().string()))
                               .string();
  const std::filesystem::path canon = stem + ".canon", table = stem + ".tbl";
  {
    std::ofstream out(table);
    int pocket = 1;
    for (const auto& [tool, length_mm] : Rs274ToolLengthsMm()) {
      char line[96];
      std::snprintf(line, sizeof line, "T%d P%d Z%.4f D0.25 ;formloop test tool\n", tool, pocket++, length_mm / 25.4);
      out << line;
    }
  }
  const std::string command =
      "rs274 -t " + table.string() + " -g " + program.string() + " " + canon.string() + " </dev/null 2>&1";
  FILE* pipe = ::popen(command.c_str(), "r");
  std::array<char, 4096> buffer{};
  std::size_t n;
  console->clear();
  while (pipe != nullptr && (n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0)
    console->append(buffer.data(), n);
  const int status = pipe != nullptr ? ::pclose(pipe) : -1;
  *exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream in(canon);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::filesystem::remove(canon);
  std::filesystem::remove(table);
  if (lock >= 0) ::close(lock);  // releases the lock
  return text;
}

enum class CanonKind { kTraverse, kFeed, kProbe, kArc };

inline const char* CanonKindName(CanonKind k) {
  switch (k) {
    case CanonKind::kTraverse:
      return "STRAIGHT_TRAVERSE";
    case CanonKind::kFeed:
      return "STRAIGHT_FEED";
    case CanonKind::kProbe:
      return "STRAIGHT_PROBE";
    case CanonKind::kArc:
      return "ARC_FEED";
  }
  return "?";
}

// One motion of rs274's canonical output, X Y Z in program units.
struct CanonMove {
  CanonKind kind = CanonKind::kTraverse;
  Eigen::Vector3d start = Eigen::Vector3d::Zero();  // the previous motion's end (rs274 starts at 0, 0, 0)
  Eigen::Vector3d p = Eigen::Vector3d::Zero();      // end point
  int decimals = 0;                                 // printed decimals of the positions
  double feed = 0;                                  // modal SET_FEED_RATE when the move was issued
  long line = 0;                                    // line of the canon output
  std::string n_word;                               // "N0240" or "N....."
  int tool = 0;              // tool in the spindle (SELECT_TOOL before the last CHANGE_TOOL), 0 for none
  double tool_length_z = 0;  // active tool length offset along Z (USE_TOOL_LENGTH_OFFSET), program units
  // Arcs: plane axes (u, v, w) as indices into X, Y, Z, centre (u, v), turns and direction.
  int u = 0, v = 1, w = 2;
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();
  int rotation = 0;
  // Point at a fraction λ of the arc (angle and radius linear in λ, as LinuxCNC interpolates).
  Eigen::Vector3d ArcPoint(double lambda) const {
    const double kTwoPi = 2 * std::numbers::pi;
    const Eigen::Vector2d s(start[u] - centre.x(), start[v] - centre.y());
    const Eigen::Vector2d e(p[u] - centre.x(), p[v] - centre.y());
    const double ts = std::atan2(s.y(), s.x()), te = std::atan2(e.y(), e.x());
    double sweep = rotation > 0 ? te - ts : ts - te;
    sweep = std::fmod(sweep, kTwoPi);
    if (sweep < 0) sweep += kTwoPi;
    if (sweep < 1e-12) sweep = kTwoPi;  // LinuxCNC: coincident ends are a full turn
    sweep += kTwoPi * (std::abs(rotation) - 1);
    const double theta = ts + (rotation > 0 ? 1 : -1) * lambda * sweep;
    const double r = s.norm() + lambda * (e.norm() - s.norm());
    Eigen::Vector3d q;
    q[u] = centre.x() + r * std::cos(theta);
    q[v] = centre.y() + r * std::sin(theta);
    q[w] = start[w] + lambda * (p[w] - start[w]);
    return q;
  }
};

struct Canon {
  std::vector<CanonMove> moves;
  int mm_units = 0, inch_units = 0, other_units = 0;  // USE_LENGTH_UNITS(...) lines
  int unparsed_motion = 0;                            // motion lines this parser could not read
  int comments = 0;
  std::vector<std::string> comment_texts;
  // Each comment with the number of motions printed before it (to place markers turned into comments).
  std::vector<std::pair<std::size_t, std::string>> comments_at;
};

inline int CanonDecimalsOf(const std::string& number) {
  const auto dot = number.find('.');
  if (dot == std::string::npos) return 0;
  int d = 0;
  for (std::size_t i = dot + 1; i < number.size() && std::isdigit(static_cast<unsigned char>(number[i])); ++i) ++d;
  return d;
}

// Lines look like "   17 N..... STRAIGHT_TRAVERSE(1.2346, 2.0000, 10.0000, 0.0000, 0.0000, 0.0000)".
inline Canon ParseCanon(const std::string& text) {
  Canon out;
  std::istringstream in(text);
  std::string line;
  long number = 0;
  double feed = 0, tool_length_z = 0;
  int selected = 0, spindle = 0;
  int u = 0, v = 1, w = 2;
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  while (std::getline(in, line)) {
    ++number;
    const auto open = line.find('(');
    const auto close = line.rfind(')');
    if (open == std::string::npos || close == std::string::npos || close < open) continue;
    const auto name_start = line.find_last_of(' ', open);
    const std::string name = line.substr(name_start == std::string::npos ? 0 : name_start + 1,
                                         open - (name_start == std::string::npos ? 0 : name_start + 1));
    std::string n_word;
    {
      std::istringstream head(line.substr(0, open));
      std::string first;
      head >> first >> n_word;
    }
    auto add = [&](CanonMove& m) {
      m.start = position;
      m.feed = feed;
      m.line = number;
      m.n_word = n_word;
      m.tool = spindle;
      m.tool_length_z = tool_length_z;
      position = m.p;
      out.moves.push_back(m);
    };
    std::vector<std::string> args;
    {
      std::string arg;
      std::istringstream a(line.substr(open + 1, close - open - 1));
      while (std::getline(a, arg, ',')) {
        arg.erase(0, arg.find_first_not_of(' '));
        args.push_back(arg);
      }
    }
    if (name == "USE_LENGTH_UNITS") {
      if (!args.empty() && args[0] == "CANON_UNITS_MM") {
        ++out.mm_units;
      } else if (!args.empty() && args[0] == "CANON_UNITS_INCHES") {
        ++out.inch_units;
      } else {
        ++out.other_units;
      }
    } else if (name == "COMMENT") {
      ++out.comments;
      std::string c = line.substr(open + 1, close - open - 1);
      if (c.size() >= 2 && c.front() == '"' && c.back() == '"') c = c.substr(1, c.size() - 2);
      out.comment_texts.push_back(c);
      out.comments_at.emplace_back(out.moves.size(), c);
    } else if (name == "SELECT_PLANE" && !args.empty()) {
      if (args[0] == "CANON_PLANE_XZ") {
        u = 2, v = 0, w = 1;
      } else if (args[0] == "CANON_PLANE_YZ") {
        u = 1, v = 2, w = 0;
      } else {
        u = 0, v = 1, w = 2;
      }
    } else if (name == "SELECT_TOOL" && !args.empty()) {
      selected = std::atoi(args[0].c_str());
    } else if (name == "CHANGE_TOOL") {
      spindle = selected;
    } else if (name == "USE_TOOL_LENGTH_OFFSET" && !args.empty()) {
      std::istringstream offset(args[0]);  // "x y z" of the offset, then other fields
      double x = 0, y = 0;
      offset >> x >> y >> tool_length_z;
    } else if (name == "SET_FEED_RATE" && !args.empty()) {
      feed = std::strtod(args[0].c_str(), nullptr);
    } else if (name == "STRAIGHT_TRAVERSE" || name == "STRAIGHT_FEED" || name == "STRAIGHT_PROBE") {
      if (args.size() < 3) {
        ++out.unparsed_motion;
        continue;
      }
      CanonMove m;
      m.kind = name == "STRAIGHT_TRAVERSE" ? CanonKind::kTraverse
               : name == "STRAIGHT_FEED"   ? CanonKind::kFeed
                                           : CanonKind::kProbe;
      for (int a = 0; a < 3; ++a) m.p[a] = std::strtod(args[a].c_str(), nullptr);
      m.decimals = std::min({CanonDecimalsOf(args[0]), CanonDecimalsOf(args[1]), CanonDecimalsOf(args[2])});
      add(m);
    } else if (name == "ARC_FEED") {
      if (args.size() < 6) {
        ++out.unparsed_motion;
        continue;
      }
      CanonMove m;
      m.kind = CanonKind::kArc;
      m.u = u, m.v = v, m.w = w;
      m.p[u] = std::strtod(args[0].c_str(), nullptr);
      m.p[v] = std::strtod(args[1].c_str(), nullptr);
      m.centre = Eigen::Vector2d(std::strtod(args[2].c_str(), nullptr), std::strtod(args[3].c_str(), nullptr));
      m.rotation = std::atoi(args[4].c_str());
      m.p[w] = std::strtod(args[5].c_str(), nullptr);
      m.decimals = std::min({CanonDecimalsOf(args[0]), CanonDecimalsOf(args[1]), CanonDecimalsOf(args[5])});
      add(m);
    }
  }
  return out;
}

}  // namespace formloop::testing

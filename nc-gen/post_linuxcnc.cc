#include <cctype>
#include <cmath>
#include <sstream>

#include "core/point_io.h"
#include "nc-gen/post.h"

namespace formloop::nc {

Status MachineLimits::Validate() const {
  for (int a = 0; a < 3; ++a) {
    if (!(travel_min_mm[a] < travel_max_mm[a])) {
      return Status::BadInput(Where{.field = "machine.travel"}, "travel_min must be below travel_max on every axis");
    }
  }
  if (!(max_feed_mm_per_min > 0)) return Status::BadInput(Where{.field = "machine.max_feed_mm_per_min"}, "must be > 0");
  if (!(max_spindle_rpm > 0)) return Status::BadInput(Where{.field = "machine.max_spindle_rpm"}, "must be > 0");
  return Status::Ok();
}

nlohmann::json MachineLimits::ToJson() const {
  return {{"travel_min_mm", {travel_min_mm.x(), travel_min_mm.y(), travel_min_mm.z()}},
          {"travel_max_mm", {travel_max_mm.x(), travel_max_mm.y(), travel_max_mm.z()}},
          {"max_feed_mm_per_min", max_feed_mm_per_min},
          {"max_spindle_rpm", max_spindle_rpm}};
}

Status CheckTravel(const MachineLimits& limits, const Eigen::Vector3d& tip, const std::string& what) {
  static const char* kAxis[] = {"X", "Y", "Z"};
  for (int a = 0; a < 3; ++a) {
    if (tip[a] < limits.travel_min_mm[a] || tip[a] > limits.travel_max_mm[a]) {
      return Status::SafetyLimit(what + ": " + kAxis[a] + " " + FormatFixed(tip[a], 4) + " mm is outside the travel " +
                                 FormatFixed(limits.travel_min_mm[a], 3) + " .. " +
                                 FormatFixed(limits.travel_max_mm[a], 3) +
                                 " mm; no program was written. Fix: move the work offset or check the part and "
                                 "machine limits");
    }
  }
  return Status::Ok();
}

std::string CommentText(const std::string& text) {
  std::string out = text;
  for (char& c : out) {
    if (c == '(') c = '[';
    if (c == ')') c = ']';
    if (static_cast<unsigned char>(c) < 0x20) c = ' ';
  }
  return out;
}

namespace {

class Writer {
 public:
  Writer(const PostOptions& options) : options_(options) {}
  void Line(const std::string& text) {
    if (options_.block_numbers && !text.empty() && text[0] != '(' && text[0] != '%') {
      out_ << 'N' << (block_ += 10) << ' ';
    }
    out_ << text << '\n';
  }
  std::string Num(double value) const {
    std::string s = FormatFixed(value, options_.decimals);
    if (s == "-" + FormatFixed(0.0, options_.decimals)) s = FormatFixed(0.0, options_.decimals);
    return s;
  }
  std::string Xyz(const Eigen::Vector3d& p) const { return "X" + Num(p.x()) + " Y" + Num(p.y()) + " Z" + Num(p.z()); }
  std::string str() const { return out_.str(); }

 private:
  const PostOptions& options_;
  std::ostringstream out_;
  long block_ = 0;
};

}  // namespace

Result<std::string> PostLinuxCnc(const Toolpath& path, const PostOptions& options) {
  FL_RETURN_IF_ERROR(options.limits.Validate());
  const ToolpathOptions& tp = path.options;
  if (path.points.empty()) return Status::BadInput("the tool path has no points; nothing to post");
  // Safety first: nothing is formatted unless every position and rate is within the limits.
  if (tp.feed_mm_per_min > options.limits.max_feed_mm_per_min ||
      tp.plunge_feed_mm_per_min > options.limits.max_feed_mm_per_min) {
    return Status::SafetyLimit("feed " + FormatFixed(tp.feed_mm_per_min, 0) + " mm/min exceeds the machine limit " +
                               FormatFixed(options.limits.max_feed_mm_per_min, 0) + " mm/min; no program was written");
  }
  if (tp.spindle_rpm > options.limits.max_spindle_rpm) {
    return Status::SafetyLimit("spindle " + FormatFixed(tp.spindle_rpm, 0) + " rpm exceeds the machine limit " +
                               FormatFixed(options.limits.max_spindle_rpm, 0) + " rpm; no program was written");
  }
  for (std::size_t k = 0; k < path.points.size(); ++k) {
    const ClPoint& cl = path.points[k];
    FL_RETURN_IF_ERROR(CheckTravel(options.limits, cl.tip,
                                   "CL point " + std::to_string(k) + " (pass " + std::to_string(cl.pass) + ")"));
    Eigen::Vector3d above = cl.tip;
    above.z() = path.safe_z_mm;
    FL_RETURN_IF_ERROR(CheckTravel(options.limits, above, "safe-Z rapid above CL point " + std::to_string(k)));
  }

  Writer w(options);
  w.Line("%");
  w.Line("(" + CommentText(options.title) + ")");
  w.Line("(ball-end tool T" + std::to_string(tp.tool.number) + " radius " + w.Num(tp.tool.radius_mm) +
         " mm; programmed point = ball tip; " + std::to_string(path.passes) + " passes)");
  w.Line("G21 G90 G17 G94 G40 G49 G80");
  w.Line("G64 P0.001");
  w.Line("T" + std::to_string(tp.tool.number) + " M6");
  w.Line("S" + FormatFixed(tp.spindle_rpm, 0) + " M3");
  w.Line("G0 Z" + w.Num(path.safe_z_mm));
  w.Line("(cut)");
  int current_pass = -1;
  for (std::size_t k = 0; k < path.points.size(); ++k) {
    const ClPoint& cl = path.points[k];
    if (cl.pass != current_pass) {
      if (current_pass >= 0) w.Line("G0 Z" + w.Num(path.safe_z_mm));
      current_pass = cl.pass;
      w.Line("(pass " + std::to_string(cl.pass) + ")");
      w.Line("G0 X" + w.Num(cl.tip.x()) + " Y" + w.Num(cl.tip.y()));
      w.Line("G1 " + w.Xyz(cl.tip) + " F" + FormatFixed(tp.plunge_feed_mm_per_min, 0));
      w.Line("F" + FormatFixed(tp.feed_mm_per_min, 0));
      continue;
    }
    w.Line("G1 " + w.Xyz(cl.tip));
  }
  w.Line("G0 Z" + w.Num(path.safe_z_mm));
  w.Line("M5");
  w.Line("M30");
  w.Line("%");
  return w.str();
}

Result<std::vector<ProgramMove>> ReadLinuxCncMoves(const std::string& text, const std::string& source) {
  std::vector<ProgramMove> moves;
  std::istringstream in(text);
  std::string raw;
  long line_no = 0;
  Eigen::Vector3d position = Eigen::Vector3d::Constant(std::nan(""));
  double feed = 0;
  int motion = -1;  // 0 rapid, 1 feed
  while (std::getline(in, raw)) {
    ++line_no;
    std::string comment;
    std::string code;
    int depth = 0;
    for (char c : raw) {
      if (c == '(') {
        ++depth;
        continue;
      }
      if (c == ')') {
        --depth;
        continue;
      }
      if (depth > 0) {
        comment += c;
      } else if (c == ';') {
        break;
      } else if (!std::isspace(static_cast<unsigned char>(c))) {
        code += static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
      }
    }
    if (code.empty() || code == "%") continue;
    bool has_xyz = false;
    std::size_t i = 0;
    while (i < code.size()) {
      const char letter = code[i++];
      std::size_t j = i;
      while (j < code.size() && (std::isdigit(static_cast<unsigned char>(code[j])) || code[j] == '.' ||
                                 code[j] == '-' || code[j] == '+')) {
        ++j;
      }
      double value = 0;
      if (!std::isalpha(static_cast<unsigned char>(letter)) || !ParseDouble(code.substr(i, j - i), &value)) {
        return Status::BadInput(Where{.file = source, .line = line_no},
                                "cannot read word '" + code.substr(i - 1, j - i + 1) + "'",
                                "only formloop's own LinuxCNC output can be read back");
      }
      i = j;
      switch (letter) {
        case 'N': break;
        case 'G':
          if (value == 0 || value == 1) {
            motion = static_cast<int>(value);
          } else if (value == 20 || value == 91) {
            return Status::BadInput(Where{.file = source, .line = line_no},
                                    "G" + FormatFixed(value, 0) + " (inch or incremental) is not supported",
                                    "program in G21 G90");
          }
          break;
        case 'X': position.x() = value; has_xyz = true; break;
        case 'Y': position.y() = value; has_xyz = true; break;
        case 'Z': position.z() = value; has_xyz = true; break;
        case 'F': feed = value; break;
        case 'M': case 'S': case 'T': case 'P': break;
        default:
          return Status::BadInput(Where{.file = source, .line = line_no},
                                  std::string("unsupported word '") + letter + "'",
                                  "only formloop's own LinuxCNC output can be read back");
      }
    }
    if (has_xyz) {
      if (motion < 0) {
        return Status::BadInput(Where{.file = source, .line = line_no}, "coordinates before any G0/G1");
      }
      ProgramMove move;
      move.rapid = motion == 0;
      move.tip = position;
      move.line = line_no;
      move.feed_mm_per_min = feed;
      move.comment = comment;
      moves.push_back(move);
    }
  }
  return moves;
}

}  // namespace formloop::nc

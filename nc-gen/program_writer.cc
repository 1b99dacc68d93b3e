#include "nc-gen/program_writer.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

#include "nc-gen/post.h"

namespace formloop::nc::internal {
namespace {

constexpr const char* kAxis = "XYZ";
constexpr double kTwoPi = 2 * std::numbers::pi;

double Wrap2Pi(double a) {
  a = std::fmod(a, kTwoPi);
  if (a < 0) a += kTwoPi;
  return a;
}

// v on the grid of `decimals`, as an integer count of steps (the rounding FormatCoordinate does).
long long Ticks(double v, int decimals) {
  static constexpr double kPow10[] = {1, 10, 100, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9};
  return std::llround(RoundCoordinate(v, decimals) * kPow10[std::clamp(decimals, 0, 9)]);
}

struct Edit {
  std::uint32_t begin = 0, end = 0;
  std::string text;
};

// The text with the edits applied (edits do not overlap; insertions have begin == end).
std::string Apply(std::string_view text, std::vector<Edit>& edits) {
  // By position; an insertion goes before a replacement that starts where it is inserted.
  std::stable_sort(edits.begin(), edits.end(), [](const Edit& a, const Edit& b) {
    if (a.begin != b.begin) return a.begin < b.begin;
    return a.begin == a.end && b.begin != b.end;
  });
  std::string out;
  out.reserve(text.size() + 32);
  std::size_t at = 0;
  for (const Edit& e : edits) {
    out.append(text.substr(at, e.begin - at));
    out += e.text;
    at = e.end;
  }
  out.append(text.substr(at));
  return out;
}

// Replaces a word's value (keeping its letter as written).
Edit ReplaceValue(std::string_view text, const Word& w, const std::string& value) {
  return Edit{w.begin, w.end, std::string(1, text[w.begin]) + value};
}

// The end of the last word: where appended words go (before a trailing comment).
std::uint32_t AppendAt(const BlockRecord& b) {
  std::uint32_t at = b.head_end;
  for (const Word& w : b.words) at = std::max(at, w.end);
  return at;
}

}  // namespace

void BlockRecord::Assign(const Block& block, std::string_view line_end) {
  text.assign(block.text);
  eol.assign(line_end);
  words.assign(block.words.begin(), block.words.end());
  line = block.line;
  n_word = block.n_word;
  head_end = block.head_end;
  motion = block.motion;
  modal_motion = block.modal_motion;
  explicit_motion = block.explicit_motion;
  plane = block.plane;
  units = block.units;
  incremental = block.incremental;
  arc_absolute = block.arc_absolute;
  feed_mode = block.feed_mode;
  start = block.start;
  end = block.end;
  start_known = block.start_known;
  end_known = block.end_known;
  xyz_words = block.xyz_words;
  has_arc = block.has_arc;
  if (has_arc) arc = block.arc;
  length_mm = s_end_mm = 0;
}

const Word* BlockRecord::Find(char letter) const {
  for (const Word& w : words) {
    if (w.letter == letter) return &w;
  }
  return nullptr;
}

int ChordSegments(const ArcGeometry& arc, double chord_tolerance) {
  const double radius = std::max(arc.radius_start, arc.radius_end);
  const double theta_max = chord_tolerance >= radius
                               ? std::numbers::pi / 2
                               : std::min(std::numbers::pi / 2, 2 * std::acos(1 - chord_tolerance / radius));
  return std::max(1, static_cast<int>(std::ceil(arc.sweep_rad / theta_max - 1e-12)));
}

bool ProgramWriter::KeepsArc(const BlockRecord& block, const Eigen::Vector3d& end, const Eigen::Vector3d& centre,
                             int decimals, double radius_tolerance) const {
  const ArcGeometry& arc = block.arc;
  const PlaneAxes ax = AxesOf(arc.plane);
  const double q = std::pow(10.0, -decimals);
  const Eigen::Vector3d start = Controller(block.start);
  const Eigen::Vector2d s(start[ax.u], start[ax.v]);
  const Eigen::Vector2d e(RoundCoordinate(end[ax.u], decimals), RoundCoordinate(end[ax.v], decimals));
  Eigen::Vector2d c;
  const bool centre_form = block.Find(static_cast<char>('I' + ax.u)) || block.Find(static_cast<char>('I' + ax.v));
  if (centre_form) {
    c = block.arc_absolute
            ? Eigen::Vector2d(RoundCoordinate(centre[ax.u], decimals), RoundCoordinate(centre[ax.v], decimals))
            : s + Eigen::Vector2d(arc.centre[ax.u] - arc.start[ax.u], arc.centre[ax.v] - arc.start[ax.v]);
  } else {
    const Word* rw = block.Find('R');
    const double radius = rw != nullptr ? rw->value : arc.radius();
    const double chord = (e - s).norm();
    if (chord <= 0 || chord > 2 * std::abs(radius)) return false;
    const Eigen::Vector2d t = (e - s) / chord;
    const double d = std::sqrt(std::max(0.0, radius * radius - 0.25 * chord * chord));
    c = 0.5 * (s + e) + ((arc.ccw != (radius < 0)) ? 1.0 : -1.0) * d * Eigen::Vector2d(-t.y(), t.x());
  }
  const double rs = (s - c).norm(), re = (e - c).norm();
  const double ts = std::atan2(s.y() - c.y(), s.x() - c.x()), te = std::atan2(e.y() - c.y(), e.x() - c.x());
  double sweep = (e - s).norm() < 1e-12 ? kTwoPi : (arc.ccw ? Wrap2Pi(te - ts) : Wrap2Pi(ts - te));
  sweep += kTwoPi * std::max(0.0, std::floor(arc.sweep_rad / kTwoPi - 1e-9));
  return std::abs(rs - re) <= radius_tolerance && std::abs(sweep - arc.sweep_rad) * arc.radius() <= 2 * q;
}

ProgramWriter::ProgramWriter(GcodeDialect dialect, Sink sink) : dialect_(dialect), sink_(std::move(sink)) {}

const char* ProgramWriter::MotionCode(Motion motion) const {
  const bool fanuc = dialect_ == GcodeDialect::kFanuc;
  switch (motion) {
    case Motion::kRapid:
      return fanuc ? "G00" : "G0";
    case Motion::kLinear:
      return fanuc ? "G01" : "G1";
    case Motion::kArcCw:
      return fanuc ? "G02" : "G2";
    case Motion::kArcCcw:
      return fanuc ? "G03" : "G3";
    case Motion::kNone:
      break;
  }
  return "";
}

bool ProgramWriter::NeedsMotionCode(const BlockRecord& block) const {
  return changed_modal_ && block.motion != Motion::kNone && !block.explicit_motion &&
         emitted_modal_ != block.modal_motion;
}

void ProgramWriter::Emit(std::string&& text, std::string_view eol) {
  sink_(text);
  sink_(eol);
  ++lines_;
}

void ProgramWriter::Line(std::string_view text, std::string_view eol) {
  sink_(text);
  sink_(eol);
  ++lines_;
}

void ProgramWriter::Track(const BlockRecord& block) {
  if (block.explicit_motion) {
    emitted_modal_ = block.modal_motion;
    changed_modal_ = false;
  }
}

void ProgramWriter::Unchanged(const BlockRecord& block) {
  if (NeedsMotionCode(block)) {
    std::vector<Edit> edits{{block.head_end, block.head_end, std::string(MotionCode(block.modal_motion)) + " "}};
    Emit(Apply(block.text, edits), block.eol);
    emitted_modal_ = block.modal_motion;
    changed_modal_ = false;
  } else {
    Emit(std::string(block.text), block.eol);
  }
  Track(block);
  // Where the controller stands: an absolute axis word puts it on the nominal value; an increment or an
  // axis the block does not program keeps the offset it had.
  for (int a = 0; a < 3; ++a) {
    if ((block.xyz_words & (1u << a)) != 0 && !block.incremental) residual_[a] = 0;
  }
  if (block.motion == Motion::kNone && block.xyz_words != 0) {
    for (int a = 0; a < 3; ++a) {
      if ((block.xyz_words & (1u << a)) != 0) residual_[a] = 0;  // G92, G10 L20, G28 ...: renamed or re-homed
    }
  }
}

bool ProgramWriter::MoveEnd(const BlockRecord& block, const Eigen::Vector3d& end, const Eigen::Vector3d* centre,
                            int decimals) {
  std::vector<Edit> edits;
  std::string appended;
  const Eigen::Vector3d controller = block.start + residual_;
  Eigen::Vector3d residual = residual_;
  for (int a = 0; a < 3; ++a) {
    const Word* w = block.Find(kAxis[a]);
    const long long target = Ticks(end[a], decimals);
    if (!block.incremental) {
      if (w != nullptr) {
        if (target == Ticks(block.end[a], decimals)) {
          residual[a] = 0;  // the original word already says it
        } else {
          edits.push_back(ReplaceValue(block.text, *w, FormatCoordinate(end[a], decimals)));
          residual[a] = RoundCoordinate(end[a], decimals) - block.end[a];
        }
      } else if (target != Ticks(controller[a], decimals)) {
        appended += std::string(" ") + kAxis[a] + FormatCoordinate(end[a], decimals);
        residual[a] = RoundCoordinate(end[a], decimals) - block.end[a];
      }
      continue;
    }
    // Incremental: the written increment takes the controller from where it is to the rounded target.
    const double increment = RoundCoordinate(RoundCoordinate(end[a], decimals) - controller[a], decimals);
    const double nominal_increment = block.end[a] - block.start[a];
    if (w != nullptr) {
      if (Ticks(increment, decimals) != Ticks(nominal_increment, decimals)) {
        edits.push_back(ReplaceValue(block.text, *w, FormatCoordinate(increment, decimals)));
        residual[a] = controller[a] + increment - block.end[a];
      } else {
        residual[a] = controller[a] + nominal_increment - block.end[a];
      }
    } else if (Ticks(increment, decimals) != 0) {
      appended += std::string(" ") + kAxis[a] + FormatCoordinate(increment, decimals);
      residual[a] = controller[a] + increment - block.end[a];
    }
  }
  if (centre != nullptr && block.has_arc && block.arc_absolute) {
    const PlaneAxes ax = AxesOf(block.plane);
    for (int a : {ax.u, ax.v}) {
      const Word* w = block.Find(static_cast<char>('I' + a));
      if (w != nullptr && Ticks((*centre)[a], decimals) != Ticks(block.arc.centre[a], decimals)) {
        edits.push_back(ReplaceValue(block.text, *w, FormatCoordinate((*centre)[a], decimals)));
      }
    }
  }
  if (!appended.empty()) edits.push_back(Edit{AppendAt(block), AppendAt(block), appended});
  const bool changed = !edits.empty();
  if (NeedsMotionCode(block)) {
    edits.push_back(Edit{block.head_end, block.head_end, std::string(MotionCode(block.modal_motion)) + " "});
    emitted_modal_ = block.modal_motion;
    changed_modal_ = false;
  }
  Emit(edits.empty() ? std::string(block.text) : Apply(block.text, edits), block.eol);
  Track(block);
  residual_ = residual;
  return changed;
}

void ProgramWriter::Split(const BlockRecord& block, const std::vector<Eigen::Vector3d>& vertices, int decimals) {
  if (vertices.empty()) return;
  // First line: the block itself as a straight move to the first vertex.
  std::vector<Edit> edits;
  bool motion_replaced = false;
  for (const Word& w : block.words) {
    if (w.letter == 'G' && !w.expression) {
      const long t = std::lround(w.value * 10);
      if (t == 20 || t == 30) {
        edits.push_back(Edit{w.begin, w.end, MotionCode(Motion::kLinear)});
        motion_replaced = true;
      }
    } else if (w.letter == 'I' || w.letter == 'J' || w.letter == 'K' || w.letter == 'R' ||
               (w.letter == 'P' && dialect_ == GcodeDialect::kRs274ngc)) {
      std::uint32_t begin = w.begin;  // the word goes with the blanks before it
      while (begin > block.head_end && (block.text[begin - 1] == ' ' || block.text[begin - 1] == '\t')) --begin;
      edits.push_back(Edit{begin, w.end, ""});
    }
  }
  if (!motion_replaced) {
    edits.push_back(Edit{block.head_end, block.head_end, std::string(MotionCode(Motion::kLinear)) + " "});
  }
  Eigen::Vector3d controller = block.start + residual_;
  auto value = [&](const Eigen::Vector3d& v, int a) {
    if (!block.incremental) return FormatCoordinate(v[a], decimals);
    return FormatCoordinate(RoundCoordinate(RoundCoordinate(v[a], decimals) - controller[a], decimals), decimals);
  };
  std::string appended;
  for (int a = 0; a < 3; ++a) {
    const Word* w = block.Find(kAxis[a]);
    if (w != nullptr) {
      edits.push_back(ReplaceValue(block.text, *w, value(vertices[0], a)));
    } else {
      appended += std::string(" ") + kAxis[a] + value(vertices[0], a);
    }
  }
  if (!appended.empty()) edits.push_back(Edit{AppendAt(block), AppendAt(block), appended});
  const std::string_view eol = block.eol.empty() ? std::string_view("\n") : std::string_view(block.eol);
  auto advance = [&](const Eigen::Vector3d& v) {
    for (int a = 0; a < 3; ++a) {
      controller[a] = block.incremental
                          ? controller[a] + RoundCoordinate(RoundCoordinate(v[a], decimals) - controller[a], decimals)
                          : RoundCoordinate(v[a], decimals);
    }
  };
  std::string first = Apply(block.text, edits);
  advance(vertices[0]);
  Emit(std::move(first), vertices.size() == 1 ? std::string_view(block.eol) : eol);
  for (std::size_t i = 1; i < vertices.size(); ++i) {
    std::string line;
    for (int a = 0; a < 3; ++a) {
      if (a > 0) line += ' ';
      line += kAxis[a];
      line += value(vertices[i], a);
    }
    advance(vertices[i]);
    Emit(std::move(line), i + 1 == vertices.size() ? std::string_view(block.eol) : eol);
  }
  emitted_modal_ = Motion::kLinear;
  changed_modal_ = block.modal_motion != Motion::kLinear;
  residual_ = controller - block.end;
}

Status CheckWrittenDecimals(GcodeDialect dialect, int decimals_mm, int decimals_inch) {
  const PostDialect* post = FindPost(GcodeDialectName(dialect));
  const int max_mm = post != nullptr ? post->MaxDecimals() : 6;
  const int default_mm = post != nullptr ? post->DefaultDecimals() : 4;
  const std::string name = GcodeDialectName(dialect);
  if (decimals_mm < 1 || decimals_mm > max_mm) {
    return Status::BadInput(Where{.field = "--decimals"},
                            "a " + name + " program takes 1.." + std::to_string(max_mm) +
                                " coordinate decimals in mm, got " + std::to_string(decimals_mm),
                            "use " + std::to_string(default_mm) + " (the dialect's default)");
  }
  if (decimals_inch < 1 || decimals_inch > max_mm + 1) {
    return Status::BadInput(Where{.field = "--decimals-inch"},
                            "a " + name + " program takes 1.." + std::to_string(max_mm + 1) +
                                " coordinate decimals in inch, got " + std::to_string(decimals_inch),
                            "use " + std::to_string(default_mm + 1));
  }
  return Status::Ok();
}

}  // namespace formloop::nc::internal

// GcodeReader's interpretation of one lexed block (nc-gen/gcode_reader.h): the modal groups, the words
// each G- and M-code uses, the axes a recognised-but-unmodelled word makes unknown, units, and the arc
// geometry of G2/G3 (centre and R forms, full circles, helices, turn counts). Lexing, the line source and
// the coordinate text are in gcode_reader.cc.

#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/number_text.h"
#include "nc-gen/gcode_reader.h"

namespace formloop::nc {
namespace {

constexpr double kTwoPi = 2 * std::numbers::pi;
constexpr const char* kAxisLetters = "XYZ";

std::string GName(double g) {
  const int t = GTenths(g);
  return "G" + std::to_string(t / 10) + (t % 10 != 0 ? "." + std::to_string(t % 10) : "");
}

double Wrap2Pi(double a) {
  a = std::fmod(a, kTwoPi);
  if (a < 0) a += kTwoPi;
  return a;
}

// Index 0..8 of G54..G59.3 in the offset table, -1 for anything else.
int SystemIndex(int work_system) {
  if (work_system >= 54 && work_system <= 59) return work_system - 54;
  if (work_system >= 591 && work_system <= 593) return work_system - 591 + 6;
  return -1;
}

std::string WorkSystemName(int work_system) {
  if (work_system >= 5410) return "G54.1";
  if (work_system > 100) return GName(work_system / 10.0);
  return "G" + std::to_string(work_system);
}

}  // namespace

Status GcodeReader::Interpret(Block* block) {
  ++report_.blocks;
  const bool fanuc = options_.dialect == GcodeDialect::kFanuc;
  // Which words a G- or M-code of this block uses; a word nobody uses is reported.
  std::uint32_t used = 0;  // letters consumed, bit (letter - 'A'); '#' and 'O' words are always consumed
  auto use = [&used](const char* letters) {
    for (const char* c = letters; *c != 0; ++c) {
      if (*c >= 'A' && *c <= 'Z') used |= 1u << (*c - 'A');
    }
  };
  double motion_code = -1;     // G0..G3 in this block
  bool axis_consumer = false;  // G4/G10/G28/G30/G52/G53/G92: axis words are data, not a move
  bool unknown_position_all = false;
  bool unknown_given_axes = false;
  bool set_position_to_words = false;  // G92 / G10 L20 on the current system
  bool dwell = false;
  bool g10 = false, g52 = false, g92 = false;
  int new_work_system = work_system_;
  for (const Word& w : block->words) {
    if (w.letter == 'G') {
      if (w.expression) continue;
      block->g_codes.push_back(w.value);
    } else if (w.letter == 'M') {
      if (w.expression) continue;
      block->m_codes.push_back(static_cast<int>(std::lround(w.value)));
    }
  }
  for (double g : block->g_codes) {
    const int t = GTenths(g);
    const std::string name = GName(g);
    if (options_.dialect == GcodeDialect::kSinumerik && (t == 700 || t == 710)) {  // G70 inch, G71 mm
      SetUnits(t == 700 ? Units::kInch : Units::kMm);
      continue;
    }
    switch (t) {
      case 0:
      case 10:
      case 20:
      case 30:
        if (motion_code >= 0) {
          return Fail(line_, "E_MODAL_GROUP",
                      "two motion codes in one block (" + GName(motion_code) + ", " + name + ")", "split the block");
        }
        motion_code = g;
        break;
      case 40:  // dwell
        dwell = true;
        axis_consumer = true;
        use(fanuc ? "PXU" : "P");
        break;
      case 90:  // exact stop, one block
        break;
      case 100:
        g10 = true;
        axis_consumer = true;
        use("LPRXYZABCIJKQ");
        break;
      case 150:
        polar_ = false;
        break;
      case 160:
        polar_ = true;
        Note(block, NoteKind::kUnmodelled, name, "polar coordinates: the path is not modelled while G16 is on");
        break;
      case 170:
        plane_ = Plane::kXY;
        break;
      case 180:
        plane_ = Plane::kZX;
        break;
      case 190:
        plane_ = Plane::kYZ;
        break;
      case 200:
      case 210:
        SetUnits(t == 200 ? Units::kInch : Units::kMm);
        break;
      case 280:
      case 281:
      case 300:
      case 301:
        Note(block, NoteKind::kUnmodelled, name, "reference point return: the position after it is not known");
        axis_consumer = true;
        if (t == 280 || t == 300) {
          unknown_position_all = true;  // re-evaluated below when axis words restrict it
          unknown_given_axes = true;
        }
        use("PXYZABC");
        break;
      case 330:
      case 331:
      case 760:
        Note(block, NoteKind::kUnmodelled, name, "threading cycle: not modelled");
        unknown_position_all = true;
        use("KXYZIJRQLPEH");
        break;
      case 382:
      case 383:
      case 384:
      case 385:
      case 310:
        Note(block, NoteKind::kUnmodelled, name, "probing or skip move: where it stops is not known");
        axis_consumer = true;
        unknown_given_axes = true;
        use("XYZABCF");
        break;
      case 400:
        cutter_comp_ = 40;
        break;
      case 410:
      case 420:
      case 411:
      case 421:
        cutter_comp_ = t / 10;
        use("D");
        Note(block, NoteKind::kCompensation, name,
             "cutter radius compensation: the programmed contour is read; the controller offsets it");
        break;
      case 430:
      case 431:
      case 432:
      case 440:
      case 434:
      case 435:
        length_comp_ = g;
        use("H");
        break;
      case 490:
        length_comp_ = 49;
        break;
      case 500:
        scaling_ = false;
        break;
      case 510:
        scaling_ = true;
        use("IJKPXYZ");
        Note(block, NoteKind::kUnmodelled, name, "scaling: the path is not modelled while it is on");
        break;
      case 501:
        mirror_ = false;
        use("XYZ");
        break;
      case 511:
        mirror_ = true;
        use("XYZ");
        Note(block, NoteKind::kUnmodelled, name, "programmable mirror image: not modelled while it is on");
        break;
      case 520:
        g52 = true;
        axis_consumer = true;
        break;
      case 530:
        Note(block, NoteKind::kUnmodelled, name,
             "move in machine coordinates: the work position after it is not known");
        axis_consumer = true;
        unknown_given_axes = true;
        break;
      case 540:
      case 550:
      case 560:
      case 570:
      case 580:
      case 590:
        new_work_system = t / 10;
        break;
      case 591:
      case 592:
      case 593:
        new_work_system = 590 + t % 10;
        break;
      case 541:  // Fanuc additional work systems G54.1 Pn
        new_work_system = 5410;
        use("P");
        break;
      case 610:
      case 611:
      case 640:
        use("PQ");
        break;
      case 650:
      case 660:
      case 670:
        Note(block, NoteKind::kUnmodelled, name, "macro call: not executed");
        unknown_position_all = true;
        use("PLABCDEFHIJKMQRSTUVWXYZ");
        break;
      case 680:
      case 682:
        rotation_ = true;
        use("XYZIJKRPQABC");
        Note(block, NoteKind::kUnmodelled, name, "coordinate rotation or tilted plane: not modelled while it is on");
        axis_consumer = true;
        break;
      case 690:
        rotation_ = false;
        break;
      case 50:
      case 51:
      case 52:
      case 53:
        Note(block, NoteKind::kUnmodelled, name, "spline motion: not modelled");
        unknown_position_all = true;
        use("XYZIJKPQLR");
        break;
      case 70:
      case 80:
        Note(block, NoteKind::kUnmodelled, name, "lathe diameter/radius mode: not modelled");
        break;
      case 700:
      case 710:
      case 711:
      case 720:
      case 721:
      case 730:
      case 740:
      case 810:
      case 820:
      case 830:
      case 840:
      case 841:
      case 850:
      case 860:
      case 870:
      case 880:
      case 890:
        cycle_ = true;
        Note(block, NoteKind::kUnmodelled, name, "canned cycle: its moves are not modelled");
        use("XYZRQPLIJKDF");
        break;
      case 800:
        cycle_ = false;
        break;
      case 900:
        incremental_ = false;
        break;
      case 910:
        incremental_ = true;
        break;
      case 901:
        arc_absolute_ = true;
        break;
      case 911:
        arc_absolute_ = false;
        break;
      case 920:
        g92 = true;
        axis_consumer = true;
        break;
      case 921:
      case 922:
        Note(block, NoteKind::kUnmodelled, name, "offset cancel: the work position after it is not known");
        unknown_position_all = true;
        break;
      case 923:
        Note(block, NoteKind::kUnmodelled, name, "offset restore: the work position after it is not known");
        unknown_position_all = true;
        break;
      case 930:
        feed_mode_ = FeedMode::kInverseTime;
        break;
      case 940:
        feed_mode_ = FeedMode::kUnitsPerMinute;
        break;
      case 950:
        feed_mode_ = FeedMode::kUnitsPerRevolution;
        break;
      case 960:
      case 970:
        use("SD");
        break;
      case 980:
      case 990:
        break;
      default:
        Note(block, NoteKind::kUnknown, name, "G-code the reader does not know");
    }
  }
  // M-codes.
  for (int m : block->m_codes) {
    const std::string name = "M" + std::to_string(m);
    if (std::find(options_.caller_m_codes.begin(), options_.caller_m_codes.end(), m) != options_.caller_m_codes.end()) {
      use("PIJK");
      continue;
    }
    switch (m) {
      case 2:
      case 30:
        block->program_end = true;
        break;
      case 0:
      case 1:
      case 3:
      case 4:
      case 5:
      case 6:
      case 7:
      case 8:
      case 9:
      case 48:
      case 49:
      case 60:
        break;
      case 19:  // spindle orientation
        use("RQP");
        break;
      case 50:
      case 51:
      case 52:
      case 53:
      case 61:
      case 62:
      case 63:
      case 64:
      case 65:
      case 66:
      case 67:
      case 68:
      case 70:
      case 71:
      case 72:
      case 73:
        use("PQELR");
        break;
      case 98:
      case 99:
        Note(block, NoteKind::kUnmodelled, name, "sub-program call or return: not executed");
        unknown_position_all = true;
        use("PLQ");
        break;
      default:
        if (m >= 100 && m <= 199 && !fanuc) {
          Note(block, NoteKind::kUnmodelled, name, "user-defined M-code: assumed not to move the axes");
          use("PQ");
        } else {
          Note(block, NoteKind::kUnmodelled, name,
               "machine function the reader does not know: assumed not to move the axes");
          use("PQ");
        }
    }
  }
  // Feed, spindle, tool.
  for (const Word& w : block->words) {
    if (w.letter == 'F' && !w.expression) {
      feed_ = w.value;
      block->has_feed_word = true;
    }
  }
  use("FSTGMN#O");
  // Work coordinate system.
  if (new_work_system != work_system_) {
    const int from = SystemIndex(work_system_), to = SystemIndex(new_work_system);
    unsigned still = 0;
    for (int a = 0; a < 3; ++a) {
      const unsigned bit = 1u << a;
      if (from >= 0 && to >= 0 && (offset_known_[from] & bit) && (offset_known_[to] & bit) && (known_ & bit)) {
        position_[a] += offsets_[from][a] - offsets_[to][a];
        still |= bit;
      }
    }
    if (still != known_) {
      Note(block, NoteKind::kUnmodelled, WorkSystemName(new_work_system),
           "change of work coordinate system with offsets the program does not set: the position is not known "
           "until every axis is programmed again");
    }
    known_ = still;
    work_system_ = new_work_system;
  }
  if (motion_code >= 0) {
    const int t = GTenths(motion_code);
    modal_motion_ = t == 0 ? Motion::kRapid : t == 10 ? Motion::kLinear : t == 20 ? Motion::kArcCw : Motion::kArcCcw;
    block->explicit_motion = true;
    cycle_ = false;
  }
  // Collect axis words.
  Eigen::Vector3d target = position_;
  unsigned target_known = known_;
  bool has_axis = false;
  unsigned expression_axes = 0;
  std::array<double, 3> rotary_target = rotary_;
  unsigned rotary_target_known = rotary_known_;
  for (const Word& w : block->words) {
    int a = -1;
    bool rotary = false;
    switch (w.letter) {
      case 'X':
        a = 0;
        break;
      case 'Y':
        a = 1;
        break;
      case 'Z':
        a = 2;
        break;
      case 'A':
        a = 0;
        rotary = true;
        break;
      case 'B':
        a = 1;
        rotary = true;
        break;
      case 'C':
        a = 2;
        rotary = true;
        break;
      default:
        continue;
    }
    if (dwell && fanuc && w.letter == 'X') continue;  // G04 X = dwell time
    has_axis = true;
    const unsigned bit = 1u << a;
    if (rotary) {
      block->rotary_words |= bit;
      if (w.expression) {
        rotary_target_known &= ~bit;
        continue;
      }
      const double v = Scale(w, false);
      if (incremental_) {
        rotary_target[a] += v;
      } else {
        rotary_target[a] = v;
        rotary_target_known |= bit;
      }
      continue;
    }
    block->xyz_words |= bit;
    if (w.expression) {
      expression_axes |= bit;
      target_known &= ~bit;
      continue;
    }
    const double v = Scale(w, true);
    if (incremental_) {
      target[a] += v;  // stays unknown when the start is
    } else {
      target[a] = v;
      target_known |= bit;
    }
  }
  // Words of other letters: used by the motion below or by the codes above, else reported.
  const bool arc_mode = modal_motion_ == Motion::kArcCw || modal_motion_ == Motion::kArcCcw;
  if (arc_mode && !axis_consumer) use(fanuc ? "IJKR" : "IJKRP");
  for (const Word& w : block->words) {
    if (std::strchr("XYZABC", w.letter) != nullptr) continue;
    if (w.letter == '#' || w.letter == 'O' ||
        (w.letter >= 'A' && w.letter <= 'Z' && (used & (1u << (w.letter - 'A'))))) {
      continue;
    }
    if (w.letter == 'U' || w.letter == 'V' || w.letter == 'W') {
      Note(block, NoteKind::kUnmodelled, std::string(1, w.letter), "extra linear axis: not modelled");
      continue;
    }
    if (w.letter == 'D' || w.letter == 'H') {
      continue;  // offset numbers on their own: no effect on the programmed path
    }
    Note(block, NoteKind::kUnknown, std::string(1, w.letter),
         std::string("word ") + w.letter + " has no use in this block");
  }
  // Non-motion uses of axis words.
  if (axis_consumer) {
    if (g92 || g52 || g10) {
      const Word* l = block->Find('L');
      const Word* p = block->Find('P');
      const bool l20 = g10 && l != nullptr && std::lround(l->value) == 20;
      const bool l2 = g10 && l != nullptr && std::lround(l->value) == 2;
      int system = -1;
      if (g10 && p != nullptr && !p->expression) {
        const long pv = std::lround(p->value);
        system = pv == 0 ? SystemIndex(work_system_) : static_cast<int>(pv - 1);
      }
      if (g92) {
        // G92: the current point takes the given coordinates (the offset is whatever makes it so).
        Note(block, NoteKind::kUnmodelled, "G92", "coordinate system offset: the current point is renamed");
        set_position_to_words = true;
      } else if (g52) {
        Note(block, NoteKind::kUnmodelled, "G52", "local coordinate system: the position is not known after it");
        unknown_position_all = true;
      } else if (l2 && system >= 0 && system < 9) {
        for (const Word& w : block->words) {
          const char* axis = std::strchr(kAxisLetters, w.letter);
          if (axis == nullptr) continue;
          const int a = static_cast<int>(axis - kAxisLetters);
          const unsigned bit = 1u << a;
          const double old_offset = offsets_[system][a];
          const bool old_known = (offset_known_[system] & bit) != 0;
          if (w.expression) {
            offset_known_[system] &= ~bit;
          } else {
            offsets_[system][a] = Scale(w, true);
            offset_known_[system] |= bit;
          }
          if (system == SystemIndex(work_system_)) {
            if (old_known && (offset_known_[system] & bit) && (known_ & bit)) {
              position_[a] += old_offset - offsets_[system][a];
            } else if (known_ & bit) {
              known_ &= ~bit;
              Note(block, NoteKind::kUnmodelled, "G10",
                   "offset of the active work coordinate system changed from an unknown value: the position is "
                   "not known until it is programmed again");
            }
          }
        }
      } else if (l20 && system >= 0 && system < 9) {
        // The offset is whatever makes the current point take the given coordinates.
        offset_known_[system] &= ~block->xyz_words;
        set_position_to_words = system == SystemIndex(work_system_);
      } else if (g10) {
        Note(block, NoteKind::kUnmodelled, "G10", "data setting (tool or offset table): not applied");
      }
    }
    if (set_position_to_words) {
      for (const Word& w : block->words) {
        const char* axis = std::strchr(kAxisLetters, w.letter);
        if (axis == nullptr) continue;
        const int a = static_cast<int>(axis - kAxisLetters);
        if (w.expression) {
          known_ &= ~(1u << a);
        } else {
          position_[a] = Scale(w, true);
          known_ |= 1u << a;
        }
      }
    }
    if (unknown_given_axes && !unknown_position_all) known_ &= ~block->xyz_words;
    if (unknown_position_all) {
      if (unknown_given_axes && block->xyz_words != 0) {
        known_ &= ~block->xyz_words;
      } else {
        known_ = 0;
      }
    }
    block->start = block->end = position_;
    block->start_known = block->end_known = known_;
    return Status::Ok();
  }
  if (unknown_position_all) {
    known_ = 0;
    block->start_known = block->end_known = 0;
    return Status::Ok();
  }
  if (!has_axis) {
    // No motion. (An arc mode with only centre words and no axes is a full circle in LinuxCNC and Fanuc.)
    const bool centre_only = arc_mode && (block->Find('I') || block->Find('J') || block->Find('K'));
    if (!centre_only) return Status::Ok();
  }
  if (cycle_) {
    // Hole positions of a modal canned cycle: X and Y go where the words say, Z is not known.
    known_ = target_known & ~4u;
    position_ = target;
    block->end = position_;
    block->end_known = known_;
    rotary_ = rotary_target;
    rotary_known_ = rotary_target_known;
    return Status::Ok();
  }
  if (modal_motion_ == Motion::kNone) {
    return Fail(line_, "E_NO_MOTION_MODE", "coordinates without a motion mode (G0, G1, G2 or G3)",
                "put the motion code into the block");
  }
  if (polar_ || scaling_ || mirror_ || rotation_) target_known = 0;
  for (int a = 0; a < 3; ++a) {
    if (rotary_target[a] != rotary_[a] && !(std::isnan(rotary_target[a]) && std::isnan(rotary_[a]))) {
      block->rotary_moved = true;
    }
  }
  rotary_ = rotary_target;
  rotary_known_ = rotary_target_known;
  block->motion = modal_motion_;
  block->start = position_;
  block->start_known = known_;
  if (modal_motion_ == Motion::kArcCw || modal_motion_ == Motion::kArcCcw) {
    FL_RETURN_IF_ERROR(Arc(block, target, target_known));
  } else {
    block->end = target;
    block->end_known = target_known;
  }
  position_ = block->end;
  known_ = block->end_known;
  return Status::Ok();
}

void GcodeReader::SetUnits(Units units) {
  if (units == units_) return;
  const double f = units == Units::kInch ? 1.0 / kMmPerInch : kMmPerInch;  // the position stays where it is
  position_ *= f;
  feed_ *= f;
  units_ = units;
}

Status GcodeReader::Arc(Block* block, const Eigen::Vector3d& target, unsigned target_known) {
  const PlaneAxes ax = AxesOf(plane_);
  const bool ccw = modal_motion_ == Motion::kArcCcw;
  block->end = target;
  block->end_known = target_known;
  const char centre_letter[3] = {'I', 'J', 'K'};
  const Word* cu = block->Find(centre_letter[ax.u]);
  const Word* cv = block->Find(centre_letter[ax.v]);
  const Word* cw = block->Find(centre_letter[ax.w]);
  const Word* r_word = block->Find('R');
  const Word* turns = options_.dialect == GcodeDialect::kRs274ngc ? block->Find('P') : nullptr;
  if (cw != nullptr) {
    Note(block, NoteKind::kUnknown, std::string(1, centre_letter[ax.w]),
         std::string("centre word along the plane's normal (") + PlaneCode(plane_) + ")");
  }
  const bool centre_form = cu != nullptr || cv != nullptr;
  if (!centre_form && r_word == nullptr) {
    return Fail(line_, "E_ARC_NO_CENTRE",
                std::string("arc (") + (ccw ? "G3" : "G2") + ", " + PlaneCode(plane_) + ") without centre words " +
                    centre_letter[ax.u] + "/" + centre_letter[ax.v] + " or R",
                "give the centre or the radius");
  }
  const unsigned plane_bits = (1u << ax.u) | (1u << ax.v) | (1u << ax.w);
  const bool any_expression = (cu && cu->expression) || (cv && cv->expression) || (r_word && r_word->expression) ||
                              (turns && turns->expression);
  if ((block->start_known & plane_bits) != plane_bits || (target_known & plane_bits) != plane_bits || any_expression) {
    Note(block, NoteKind::kUnmodelled, ccw ? "G3" : "G2",
         "arc from or to a position that is not known: its path is not modelled");
    block->end_known &= ~plane_bits;
    if (!any_expression && (target_known & plane_bits) == plane_bits) block->end_known = target_known;
    return Status::Ok();
  }
  ArcGeometry& arc = block->arc;
  arc.plane = plane_;
  arc.ccw = ccw;
  arc.start = block->start;
  arc.end = target;
  arc.rise = target[ax.w] - block->start[ax.w];
  const Eigen::Vector2d s(block->start[ax.u], block->start[ax.v]);
  const Eigen::Vector2d e(target[ax.u], target[ax.v]);
  const double unit_mm = units_ == Units::kInch ? kMmPerInch : 1.0;
  const double tiny = 1e-9;
  Eigen::Vector2d c;
  if (centre_form) {
    const double du = cu != nullptr ? Scale(*cu, true) : 0.0;
    const double dv = cv != nullptr ? Scale(*cv, true) : 0.0;
    if (arc_absolute_) {
      if (cu == nullptr || cv == nullptr) {
        return Fail(line_, "E_ARC_NO_CENTRE", "absolute arc centre (G90.1) needs both centre words",
                    "give both centre words");
      }
      c = Eigen::Vector2d(du, dv);
    } else {
      c = s + Eigen::Vector2d(du, dv);
    }
    arc.radius_start = (s - c).norm();
    arc.radius_end = (e - c).norm();
    const double mismatch_mm = std::abs(arc.radius_start - arc.radius_end) * unit_mm;
    if (mismatch_mm > options_.arc_radius_tolerance_mm) {
      return Fail(line_, "E_ARC_RADIUS",
                  "arc start radius " + FormatFixed(arc.radius_start, 4) + " and end radius " +
                      FormatFixed(arc.radius_end, 4) + " differ by " + FormatFixed(mismatch_mm, 4) +
                      " mm, more than the tolerance " + FormatFixed(options_.arc_radius_tolerance_mm, 4) + " mm",
                  "correct the centre words or the end point (or raise the arc radius tolerance)");
    }
    if (arc.radius_start < tiny) {
      return Fail(line_, "E_ARC_RADIUS", "arc with zero radius", "correct the centre words");
    }
  } else {
    const double r = Scale(*r_word, true);
    const double chord = (e - s).norm();
    if (chord < tiny) {
      return Fail(line_, "E_ARC_R_FULLCIRCLE", "R-form arc whose start and end coincide (a full circle)",
                  "program a full circle with centre words (I, J, K)");
    }
    if (chord > 2 * std::abs(r) + options_.arc_radius_tolerance_mm / unit_mm) {
      return Fail(
          line_, "E_ARC_R",
          "R-form arc: chord " + FormatFixed(chord, 4) + " longer than the diameter " + FormatFixed(2 * std::abs(r), 4),
          "correct R or the end point");
    }
    const Eigen::Vector2d mid = 0.5 * (s + e);
    const Eigen::Vector2d t = (e - s) / chord;
    const Eigen::Vector2d left(-t.y(), t.x());
    const double d = std::sqrt(std::max(0.0, r * r - 0.25 * chord * chord));
    const double side = (ccw != (r < 0)) ? 1.0 : -1.0;
    c = mid + side * d * left;
    arc.radius_start = (s - c).norm();
    arc.radius_end = (e - c).norm();
  }
  arc.centre = block->start;
  arc.centre[ax.u] = c.x();
  arc.centre[ax.v] = c.y();
  arc.theta_start_rad = std::atan2(s.y() - c.y(), s.x() - c.x());
  const double theta_end = std::atan2(e.y() - c.y(), e.x() - c.x());
  if ((e - s).norm() < tiny) {
    arc.sweep_rad = kTwoPi;
  } else {
    arc.sweep_rad = ccw ? Wrap2Pi(theta_end - arc.theta_start_rad) : Wrap2Pi(arc.theta_start_rad - theta_end);
  }
  if (turns != nullptr) {
    const long p = std::lround(turns->value);
    if (p < 1 || std::abs(turns->value - static_cast<double>(p)) > 1e-9) {
      return Fail(line_, "E_SYNTAX", "arc turn count P must be a positive integer", "write P1, P2, ...");
    }
    arc.sweep_rad += kTwoPi * static_cast<double>(p - 1);
  }
  block->has_arc = true;
  return Status::Ok();
}

}  // namespace formloop::nc

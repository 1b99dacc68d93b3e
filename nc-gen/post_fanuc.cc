// Fanuc 0i/30i post (Fanuc Series 0i-MODEL F / 30i-MODEL B operator's manuals, "Program configuration" and
// "Decimal point programming"): a program sits between '%' lines and starts with its O-number; comments
// are control-out/control-in parentheses and only a restricted upper-case character set is safe in them;
// an axis value without a decimal point is read in least input increments (X10 = 0.010 mm on IS-B), so
// every coordinate carries a decimal point (PostOptions::decimals >= 1) and IS-B machines want decimals
// <= 3; F and S are whole mm/min and rpm. Codes written: G21 mm, G90 absolute, G17 XY plane, G40/G49/G80
// cancel radius compensation, length compensation and canned cycles, G00/G01, T.. M06, S.. M03, M05, M30.

#include <cctype>
#include <string>

#include "core/number_text.h"
#include "nc-gen/post.h"
#include "nc-gen/post_text.h"

namespace formloop::nc::internal {

// Upper case; anything outside letters, digits, space and . , - + / * = : becomes a space (parentheses
// would end the comment early and '%' ends the program on tape-style transfers); runs of spaces collapse.
std::string FanucComment(const std::string& text) {
  static const std::string kSafe = " .,-+/*=:";
  std::string out;
  for (char c : text) {
    const unsigned char u = static_cast<unsigned char>(c);
    if (std::isalnum(u)) {
      out += static_cast<char>(std::toupper(u));
    } else {
      out += kSafe.find(c) != std::string::npos ? c : ' ';
    }
    if (out.size() >= 2 && out.back() == ' ' && out[out.size() - 2] == ' ') out.pop_back();  // one space per run
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

namespace {

class FanucPost : public PostDialect {
 public:
  std::string_view Name() const override { return "fanuc"; }
  std::string_view FileExtension() const override { return ".nc"; }

  Result<std::string> Format(const MoveList& list, const PostOptions& options) const override {
    ProgramText w(options, Numbering::kBlocks, "(", ")");
    const MoveListHeader& h = list.header;
    w.Raw("%");
    std::string number = std::to_string(options.program_number);
    w.Raw("O" + std::string(4 - number.size(), '0') + number);  // O0001..O9999
    w.Comment(FanucComment(options.title));
    w.Comment(FanucComment("ball-end tool T" + std::to_string(h.tool_number) + " radius " + w.Num(h.tool_radius_mm) +
                           " mm, programmed point = ball tip, " + std::to_string(h.passes) + " passes"));
    w.Block("G21 G90 G17 G40 G49 G80");
    w.Block("T" + std::to_string(h.tool_number) + " M06");
    w.Block("S" + FormatFixed(h.spindle_rpm, 0) + " M03");
    if (h.coolant) w.Block("M08");
    WriteWordAddressBody(list, "G00", "G01", FanucComment, &w);
    if (h.coolant) w.Block("M09");
    w.Block("M05");
    w.Block("M30");
    w.Raw("%");
    return w.Finish();
  }

  Result<std::vector<ProgramMove>> Read(const std::string& text, const std::string& source) const override {
    static const WordDialect kDialect{
        .name = "Fanuc", .paren_comments = true, .g_codes = {0, 1, 17, 21, 40, 49, 80, 90}, .other_letters = "NMSTO"};
    return ReadWordAddress(text, source, kDialect);
  }
};

}  // namespace

std::unique_ptr<PostDialect> MakeFanucPost() { return std::make_unique<FanucPost>(); }

}  // namespace formloop::nc::internal

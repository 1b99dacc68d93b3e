// Siemens Sinumerik 840D sl post (SINUMERIK 840D sl Programming Manual "Fundamentals"): ';' starts a
// comment to the end of the block; G71 metric, G90 absolute, G17 XY plane, G40 no radius compensation,
// G94 feed in mm/min; "T1 D1" selects the tool and its first cutting edge (length offset), M6 changes it;
// G0/G1 with axis words (plain "X10.000" is the short form of "X=10.000"); M3/M5 spindle; M30 end.
// Block numbers are optional "N" words.

#include <string>

#include "core/number_text.h"
#include "nc-gen/post.h"
#include "nc-gen/post_text.h"

namespace formloop::nc::internal {
namespace {

class SinumerikPost : public PostDialect {
 public:
  std::string_view Name() const override { return "sinumerik"; }
  std::string_view FileExtension() const override { return ".mpf"; }

  Result<std::string> Format(const MoveList& list, const PostOptions& options) const override {
    ProgramText w(options, Numbering::kBlocks, "; ", "");
    const MoveListHeader& h = list.header;
    w.Comment(PlainComment(options.title));
    w.Comment("ball-end tool T" + std::to_string(h.tool_number) + " radius " + w.Num(h.tool_radius_mm) +
              " mm; programmed point = ball tip; " + std::to_string(h.passes) + " passes");
    w.Block("G71 G90 G17 G40 G94");
    w.Block("T" + std::to_string(h.tool_number) + " D1");
    w.Block("M6");
    w.Block("S" + FormatFixed(h.spindle_rpm, 0) + " M3");
    if (h.coolant) w.Block("M8");
    WriteWordAddressBody(list, "G0", "G1", PlainComment, &w);
    if (h.coolant) w.Block("M9");
    w.Block("M5");
    w.Block("M30");
    return w.Finish();
  }

  Result<std::vector<ProgramMove>> Read(const std::string& text, const std::string& source) const override {
    static const WordDialect kDialect{
        .name = "Sinumerik", .paren_comments = false, .g_codes = {0, 1, 17, 40, 71, 90, 94}, .other_letters = "NMSTD"};
    return ReadWordAddress(text, source, kDialect);
  }
};

}  // namespace

std::unique_ptr<PostDialect> MakeSinumerikPost() { return std::make_unique<SinumerikPost>(); }

}  // namespace formloop::nc::internal

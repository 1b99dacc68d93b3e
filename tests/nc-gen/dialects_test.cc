// The canonical move list and the four controller dialects: golden programs byte for byte, round trips
// through each dialect's reader, locale independence, safety refusals and the line-length limit.
//
// The golden files were written by this implementation once and checked by eye against each dialect's
// rules (post_*.cc headers). To rewrite them after an intended change: FORMLOOP_UPDATE_GOLDEN=1 ctest ...

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <locale>
#include <sstream>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "core/parallel.h"
#include "nc-gen/moves.h"
#include "nc-gen/post.h"
#include "nc-gen/post_text.h"
#include "nc-gen/toolpath.h"
#include "tests/support/golden.h"
#include "tests/support/locale.h"

namespace formloop::nc {
namespace {

// 2 passes × 4 points, zig-zag, with the retract between them: small enough to read in a golden file,
// with negative, positive and zero coordinates and a coordinate that rounds (0.00004 at 3 decimals).
Toolpath SmallPath() {
  Toolpath path;
  path.options.tool.number = 2;
  path.options.tool.radius_mm = 3.0;
  path.options.feed_mm_per_min = 1200;
  path.options.plunge_feed_mm_per_min = 300;
  path.options.spindle_rpm = 12000;
  path.passes = 2;
  path.safe_z_mm = 10.0;
  const double z[2][4] = {{-1.25, -0.5, 0.00004, 0.75}, {0.5, -0.125, -2.0, -3.5}};
  for (int pass = 0; pass < 2; ++pass) {
    for (int i = 0; i < 4; ++i) {
      ClPoint cl;
      cl.pass = pass;
      cl.index_in_pass = i;
      const double x = pass == 0 ? -7.5 + 5.0 * i : 7.5 - 5.0 * i;
      cl.tip = Eigen::Vector3d(x, -2.0 + 2.5 * pass, z[pass][i]);
      path.points.push_back(cl);
    }
  }
  return path;
}

PostOptions GoldenOptions() {
  PostOptions o;
  o.title = "formloop small test path (2 passes)";
  o.decimals = 3;
  return o;
}

std::filesystem::path GoldenPath(const std::string& dialect) { return testing::GoldenPath("small", dialect); }
using testing::ReadGoldenText;

using formloop::testing::CommaNumpunct;
using formloop::testing::GlobalLocale;

TEST(MoveListTest, OneBuilderGivesTheCanonicalOrderAndProvenance) {
  const auto list = BuildMoveList(SmallPath());
  ASSERT_TRUE(list.ok()) << list.status().message();
  // start retract, "cut", then per pass: [retract], comment, rapid XY, plunge, set feed, 3 cuts; end retract.
  ASSERT_EQ(list->moves.size(), 1u + 1u + 7u + 8u + 1u);
  EXPECT_EQ(list->moves[0].type, MoveType::kRapid);
  EXPECT_EQ(list->moves[0].axes, kAxisZ);
  EXPECT_EQ(list->moves[1].text, "cut");
  long cl = 0;
  for (const Move& m : list->moves) {
    if (m.type == MoveType::kFeed) {
      EXPECT_EQ(m.cl_index, cl++);  // the i-th feed move is CL point i
    }
  }
  EXPECT_EQ(cl, 8);
  EXPECT_EQ(list->moves[4].Describe(4), "move 4 (pass 0, CL point 0, plunge)");
  EXPECT_EQ(list->header.tool_number, 2);
  EXPECT_FALSE(BuildMoveList(Toolpath{}).ok());
}

TEST(PostRegistryTest, FourDialectsAndUnknownNamesAreRefused) {
  EXPECT_EQ(PostNames(), (std::vector<std::string>{"linuxcnc", "fanuc", "heidenhain", "sinumerik"}));
  const auto r = Post(BuildMoveList(SmallPath()).value(), "mazatrol", PostOptions{});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("heidenhain"), std::string::npos) << r.status().message();
}

class DialectTest : public ::testing::TestWithParam<std::string> {};

TEST_P(DialectTest, MatchesTheGoldenFileByteForByte) {
  const auto text = Post(BuildMoveList(SmallPath()).value(), GetParam(), GoldenOptions());
  ASSERT_TRUE(text.ok()) << text.status().message();
  const auto golden = GoldenPath(GetParam());
  if (std::getenv("FORMLOOP_UPDATE_GOLDEN") != nullptr) {
    std::ofstream(golden, std::ios::binary) << *text;
    GTEST_SKIP() << "rewrote " << golden;
  }
  ASSERT_TRUE(std::filesystem::exists(golden)) << golden;
  EXPECT_EQ(*text, ReadGoldenText(golden)) << "output of the " << GetParam() << " post changed";
}

TEST_P(DialectTest, ReaderRecoversTheMovesToThePrintedPrecision) {
  const MoveList list = BuildMoveList(SmallPath()).value();
  for (const bool numbers : {false, true}) {
    PostOptions options = GoldenOptions();
    options.block_numbers = numbers;
    const auto text = Post(list, GetParam(), options);
    ASSERT_TRUE(text.ok()) << text.status().message();
    const auto read = ReadProgram(*text, GetParam(), "small");
    ASSERT_TRUE(read.ok()) << read.status().message();
    std::size_t r = 0;
    for (std::size_t i = 0; i < list.moves.size(); ++i) {
      const Move& m = list.moves[i];
      if (m.type != MoveType::kRapid && m.type != MoveType::kFeed) continue;
      ASSERT_LT(r, read->size()) << m.Describe(i);
      const ProgramMove& p = (*read)[r++];
      EXPECT_EQ(p.rapid, m.type == MoveType::kRapid) << m.Describe(i);
      for (int a = 0; a < 3; ++a) {
        if (std::isnan(m.tip[a])) {
          EXPECT_TRUE(std::isnan(p.tip[a])) << m.Describe(i);
        } else {
          EXPECT_LE(std::abs(p.tip[a] - m.tip[a]), 0.5e-3 + 1e-12) << m.Describe(i) << " axis " << a;
        }
      }
      if (m.type == MoveType::kFeed) {
        EXPECT_EQ(p.feed_mm_per_min, m.feed_mm_per_min) << m.Describe(i);
      }
    }
    EXPECT_EQ(r, read->size());
  }
}

TEST_P(DialectTest, CommaDecimalGlobalLocaleChangesNothing) {
  const MoveList list = BuildMoveList(SmallPath()).value();
  const auto classic = Post(list, GetParam(), GoldenOptions());
  ASSERT_TRUE(classic.ok());
  GlobalLocale scope(std::locale(std::locale::classic(), new CommaNumpunct));
  const auto comma = Post(list, GetParam(), GoldenOptions());
  ASSERT_TRUE(comma.ok());
  EXPECT_EQ(*comma, *classic);
  EXPECT_TRUE(ReadProgram(*comma, GetParam(), "comma").ok());
}

TEST_P(DialectTest, SafetyRefusalsNameTheMoveAndWriteNothing) {
  const MoveList list = BuildMoveList(SmallPath()).value();
  PostOptions travel = GoldenOptions();
  travel.limits.travel_max_mm.x() = 5.0;  // pass 0 reaches X 7.5 at its last point
  auto r = Post(list, GetParam(), travel);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kSafetyLimit);
  EXPECT_NE(r.status().message().find("move 8 (pass 0, CL point 3, cut): X 7.5000 mm is outside the travel"),
            std::string::npos)
      << r.status().message();

  Toolpath zero_feed = SmallPath();
  zero_feed.options.feed_mm_per_min = 0;
  r = Post(BuildMoveList(zero_feed).value(), GetParam(), GoldenOptions());
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kSafetyLimit);
  EXPECT_NE(r.status().message().find("move 5 (pass 0, cutting feed): feed 0 mm/min"), std::string::npos)
      << r.status().message();

  PostOptions slow = GoldenOptions();
  slow.limits.max_feed_mm_per_min = 1000;  // below the 1200 mm/min cutting feed
  r = Post(list, GetParam(), slow);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kSafetyLimit);
  EXPECT_NE(r.status().message().find("feed 1200 mm/min is outside 0 < F <= the machine limit 1000 mm/min"),
            std::string::npos)
      << r.status().message();
  EXPECT_NE(r.status().message().find("no program was written"), std::string::npos);

  PostOptions spindle = GoldenOptions();
  spindle.limits.max_spindle_rpm = 6000;
  EXPECT_EQ(Post(list, GetParam(), spindle).status().code(), StatusCode::kSafetyLimit);
}

TEST_P(DialectTest, LineLengthLimitWrapsCommentsAndRefusesBlocksThatCannotFit) {
  const MoveList list = BuildMoveList(SmallPath()).value();
  PostOptions wrap = GoldenOptions();
  wrap.title = "a long title that certainly does not fit on one line of forty characters";
  wrap.max_line_length = 40;
  const auto text = Post(list, GetParam(), wrap);
  ASSERT_TRUE(text.ok()) << text.status().message();
  std::istringstream lines(*text);
  for (std::string line; std::getline(lines, line);) EXPECT_LE(line.size(), 40u) << line;
  // Wrapped, not cut off (Fanuc comments are upper case).
  EXPECT_NE(text->find(GetParam() == "fanuc" ? "FORTY" : "forty"), std::string::npos) << *text;
  EXPECT_TRUE(ReadProgram(*text, GetParam(), "wrapped").ok());

  PostOptions tight = GoldenOptions();
  tight.decimals = 4;
  tight.max_line_length = 30;  // headers fit; "G1 X-7.5000 Y-2.0000 Z-1.2500 F300" and its kin cannot
  const auto refused = Post(list, GetParam(), tight);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kBadInput);
  EXPECT_NE(refused.status().message().find("over the limit of 30"), std::string::npos) << refused.status().message();
  EXPECT_NE(refused.status().message().find("-7.5000"), std::string::npos) << refused.status().message();
}

// Posting runs on every core in fixed chunks of moves (post_text.h FormatMovesInChunks): a path of several
// batches of chunks, with long pass comments that wrap and numbered blocks (the numbers and the wrapping
// follow the lines of the chunks before), gives the same bytes for 1 and 2 threads, as a held list and as
// moves made while they are visited; and a line over the limit deep in the path is refused the same way.
TEST_P(DialectTest, ChunkedPostIsTheSameBytesForOneAndTwoThreads) {
  Toolpath path = SmallPath();
  path.points.clear();
  path.passes = 60;
  for (int pass = 0; pass < path.passes; ++pass) {
    for (int i = 0; i < 1000; ++i) {  // 60,000 CL points: about 60,240 moves, two batches of 8 chunks
      ClPoint cl;
      cl.pass = pass;
      cl.index_in_pass = i;
      cl.tip = Eigen::Vector3d(-50.0 + 0.1 * i, -30.0 + pass, 0.5 * std::sin(0.01 * i + pass));
      path.points.push_back(cl);
    }
  }
  MoveList list = BuildMoveList(path).value();
  ASSERT_GT(list.moves.size(), static_cast<std::size_t>(internal::kPostChunk * internal::kPostBatchChunks));
  for (Move& m : list.moves) {
    if (m.type == MoveType::kComment) m.text += " of a long comment that wraps onto more than one line " + m.text;
  }
  PostOptions options = GoldenOptions();
  options.block_numbers = true;
  options.max_line_length = 52;
  const ToolpathMoves made = ToolpathMoves::Of(path).value();
  std::string first;
  for (const int threads : {1, 2}) {
    SetThreadCount(threads);
    const auto held = Post(list, GetParam(), options);
    const auto visited = Post(made, GetParam(), options);
    PostOptions tight = options;
    tight.max_line_length = 40;
    const auto refused = Post(list, GetParam(), tight);
    SetThreadCount(0);
    ASSERT_TRUE(held.ok()) << held.status().message();
    ASSERT_TRUE(visited.ok()) << visited.status().message();
    ASSERT_FALSE(refused.ok());
    EXPECT_NE(refused.status().message().find("over the limit of 40"), std::string::npos) << refused.status().message();
    const std::string wrapped = GetParam() == "fanuc" ? "WRAPS ONTO" : "wraps onto";
    EXPECT_NE(held->find(wrapped), std::string::npos);
    EXPECT_GT(std::count(held->begin(), held->end(), '\n'), 60000);
    // The modal state carried across the chunk and batch boundaries: the cutting feed is written once per pass
    // (no chunk restarts it), the plunge feed once per pass, the length offset once (the first rapid), the
    // numbers run on without a gap, and Heidenhain's M30 rides on the very last motion only.
    const auto count = [&](const std::string& word) {
      std::size_t n = 0;
      for (std::size_t at = held->find(word); at != std::string::npos; at = held->find(word, at + 1)) ++n;
      return n;
    };
    EXPECT_EQ(count("F1200\n"), 60u);
    EXPECT_EQ(count("F300\n"), 60u);
    EXPECT_EQ(count("M30"), 1u);
    EXPECT_EQ(count("G43 H2 Z"), GetParam() == "linuxcnc" || GetParam() == "fanuc" ? 1u : 0u);
    std::istringstream lines(*held);
    long expected = GetParam() == "heidenhain" ? 0 : options.block_start;
    for (std::string line; std::getline(lines, line);) {
      if (GetParam() == "heidenhain") {
        ASSERT_TRUE(line.starts_with(std::to_string(expected++) + " ")) << line;
      } else if (line.starts_with("N")) {
        ASSERT_TRUE(line.starts_with("N" + std::to_string(expected) + " ")) << line;
        expected += options.block_increment;
      }
    }
    EXPECT_GT(expected, 60000);
    if (threads == 1) {
      first = *held;
    } else {
      EXPECT_TRUE(*held == first) << "2 threads changed the program";
    }
    // The path's own moves post like the list did before its comments were lengthened: same moves, same blocks.
    const auto plain = Post(BuildMoveList(path).value(), GetParam(), options);
    ASSERT_TRUE(plain.ok());
    EXPECT_TRUE(*visited == *plain) << "moves made while visited differ from the held list";
  }
}

INSTANTIATE_TEST_SUITE_P(AllDialects, DialectTest, ::testing::ValuesIn(PostNames()),
                         [](const ::testing::TestParamInfo<std::string>& dialect) { return dialect.param; });

TEST(DialectReaderTest, EachReaderRefusesForeignBlocksWithTheLine) {
  const auto fanuc = ReadProgram("%\nO1234\nG21 G90\nG91 G01 X1. F100\n%\n", "fanuc", "f.nc");
  ASSERT_FALSE(fanuc.ok());
  EXPECT_NE(fanuc.status().message().find("f.nc:4"), std::string::npos) << fanuc.status().message();
  const auto siemens = ReadProgram("G71 G90\nG1 X1 Y1 Z1 F100\nG2 X2 Y2 CR=5\n", "sinumerik", "s.mpf");
  ASSERT_FALSE(siemens.ok());
  EXPECT_NE(siemens.status().message().find("s.mpf:3"), std::string::npos) << siemens.status().message();
  const auto tnc = ReadProgram("0 BEGIN PGM A MM\n1 L IX+1.000 R0 F100\n2 END PGM A MM\n", "heidenhain", "a.h");
  ASSERT_FALSE(tnc.ok());
  EXPECT_NE(tnc.status().message().find("a.h:2"), std::string::npos) << tnc.status().message();
  const auto numbering = ReadProgram("0 BEGIN PGM A MM\n2 L X+1.000 R0 F100\n", "heidenhain", "b.h");
  EXPECT_NE(numbering.status().message().find("b.h:2"), std::string::npos) << numbering.status().message();
  const auto inch = ReadProgram("0 BEGIN PGM A INCH\n1 END PGM A INCH\n", "heidenhain", "c.h");
  EXPECT_NE(inch.status().message().find("c.h:1"), std::string::npos) << inch.status().message();
}

}  // namespace
}  // namespace formloop::nc

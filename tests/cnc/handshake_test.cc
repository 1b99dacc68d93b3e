// The handshake's words (spec/tuning-and-link.md §7.2, acceptance check §9.12): the worked examples,
// every legal and a set of illegal control words, every value of every data field, a million random
// triples, the OVERFLOW sentinel and malformed fields, and the macro-arithmetic decoding the machine
// programs use, checked against the bit decoding for every 16-bit word.

#include "cnc/handshake.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "core/random.h"

namespace formloop::cnc {
namespace {

TEST(HandshakeWords, SpecExamples) {
  EXPECT_EQ(EncodeControl({1, 1, State::kPointReady, 1234}), 58578.0);
  const auto w = DecodeControl(58578);
  ASSERT_TRUE(w.has_value());
  EXPECT_EQ(*w, PointReadyWord(1234));
  EXPECT_EQ(ClassifyControl(*w), WordKind::kPointReady);

  const auto d = PackData({123, -456, 999});
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(*d, 2078508007.0);
  const auto back = UnpackData(2078508007.0);
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->v, (std::array<int, 3>{123, -456, 999}));
  EXPECT_TRUE(back->ok());
  // The fields themselves: 123, 4096 - 456 = 3640, 999.
  EXPECT_EQ(FieldOf(123), 123);
  EXPECT_EQ(FieldOf(-456), 3640);
  EXPECT_EQ(QuantiseDeviation(0.0123), 123);
  EXPECT_EQ(QuantiseDeviation(-0.0456), -456);
  EXPECT_EQ(QuantiseDeviation(0.0999), 999);
}

TEST(HandshakeWords, LegalAndIllegalControlWords) {
  EXPECT_EQ(ClassifyControlValue(0), WordKind::kIdle);
  EXPECT_EQ(ClassifyControlValue(EncodeControl(MeasuringWord(0))), WordKind::kMeasuring);
  EXPECT_EQ(EncodeControl(MeasuringWord(0)), 36864.0);
  EXPECT_EQ(ClassifyControlValue(EncodeControl(MeasuringWord(2000))), WordKind::kMeasuring);
  EXPECT_EQ(ClassifyControlValue(EncodeControl(PointReadyWord(1))), WordKind::kPointReady);
  EXPECT_EQ(ClassifyControlValue(EncodeControl(FinishedWord(2000))), WordKind::kFinished);
  EXPECT_EQ(ClassifyControlValue(EncodeControl(AbortWord())), WordKind::kAbort);
  EXPECT_EQ(EncodeControl(AbortWord()), 32768.0 + 4096 + 4095);
  // Illegal: wrong holder, state or lock; reserved ids; not a 16-bit whole number.
  for (const ControlWord w : {ControlWord{0, 1, State::kPointReady, 5}, ControlWord{1, 1, State::kPointReady, 0},
                              ControlWord{1, 1, State::kPointReady, 2001}, ControlWord{1, 0, State::kMeasuring, 2001},
                              ControlWord{1, 0, State::kPointReady, 5}, ControlWord{1, 1, State::kMeasuring, 5},
                              ControlWord{1, 0, State::kIdle, 0}, ControlWord{0, 0, State::kMeasuring, 3},
                              ControlWord{1, 1, State::kFinished, 0}, ControlWord{1, 1, State::kPointReady, 4095}}) {
    EXPECT_EQ(ClassifyControl(w), WordKind::kIllegal) << FormatControl(w);
  }
  for (const double v :
       {0.5, -1.0, 65536.0, 1e9, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
    EXPECT_EQ(ClassifyControlValue(v), WordKind::kIllegal) << v;
  }
  // Every 16-bit value decodes to the word that encodes back to it.
  for (int c = 0; c < 65536; ++c) {
    const auto w = DecodeControl(c);
    ASSERT_TRUE(w.has_value());
    EXPECT_EQ(EncodeControl(*w), c);
  }
}

// The machine programs decode C with FIX (truncation; the values are never negative) because macro
// arithmetic has no bit operators: PT = C − 4096·FIX[C/4096], ST = FIX[C/4096] − 4·FIX[C/16384],
// HD = FIX[C/16384] − 2·FIX[C/32768], LK = FIX[C/32768].
TEST(HandshakeWords, MacroArithmeticDecodingEqualsBitDecoding) {
  for (int c = 0; c < 65536; ++c) {
    const double x = c;
    const auto w = *DecodeControl(x);
    EXPECT_EQ(x - 4096 * std::trunc(x / 4096), w.point);
    EXPECT_EQ(std::trunc(x / 4096) - 4 * std::trunc(x / 16384), static_cast<int>(w.state));
    EXPECT_EQ(std::trunc(x / 16384) - 2 * std::trunc(x / 32768), w.holder);
    EXPECT_EQ(std::trunc(x / 32768), w.lock);
  }
}

TEST(HandshakeWords, EveryValueOfEveryFieldDecodesExactly) {
  for (int axis = 0; axis < 3; ++axis) {
    for (int v = -kValueLimit; v <= kValueLimit; ++v) {
      std::array<int, 3> in = {17, -5, 999};
      in[axis] = v;
      const auto d = PackData(in);
      ASSERT_TRUE(d.ok());
      ASSERT_GE(*d, 0);
      ASSERT_LE(*d, static_cast<double>(kMaxDataWord));
      const auto out = UnpackData(*d);
      ASSERT_TRUE(out.ok());
      ASSERT_EQ(out->v, in) << "axis " << axis << " v " << v;
      ASSERT_TRUE(out->ok());
    }
  }
}

TEST(HandshakeWords, AMillionRandomTriplesDecodeExactly) {
  Rng rng(22);
  for (int k = 0; k < 1'000'000; ++k) {
    std::array<int, 3> in{};
    for (int& v : in) v = static_cast<int>(rng.UniformIndex(2 * kValueLimit + 1)) - kValueLimit;
    const auto d = PackData(in);
    const auto out = UnpackData(*d);
    ASSERT_TRUE(out.ok());
    ASSERT_EQ(out->v, in);
  }
}

TEST(HandshakeWords, OverflowSentinelAndRangeErrors) {
  EXPECT_EQ(QuantiseDeviation(0.1), kOverflowValue);      // 1000 steps
  EXPECT_EQ(QuantiseDeviation(0.09995), kOverflowValue);  // 999.5 rounds away from zero to 1000
  EXPECT_EQ(QuantiseDeviation(-0.09994), -999);
  EXPECT_EQ(QuantiseDeviation(-0.15), kOverflowValue);
  EXPECT_EQ(QuantiseDeviation(-0.00005), -1);  // half away from zero
  EXPECT_EQ(QuantiseDeviation(std::numeric_limits<double>::quiet_NaN()), kOverflowValue);

  const auto sentinel = UnpackData(*PackData({kOverflowValue, 0, 5}));
  ASSERT_TRUE(sentinel.ok());
  EXPECT_EQ(sentinel->flags[0], AxisFlag::kOverflow);
  EXPECT_EQ(sentinel->flags[1], AxisFlag::kOk);
  EXPECT_EQ(sentinel->v[2], 5);
  EXPECT_FALSE(sentinel->ok());
  // Field 1500 on Y (v = 1500, which a program must never write: it writes the sentinel).
  const double d = 7.0 * 16777216 + 1500.0 * 4096 + 3;
  const auto range = UnpackData(d);
  ASSERT_TRUE(range.ok());
  EXPECT_EQ(range->flags[1], AxisFlag::kRangeError);
  EXPECT_EQ(range->v[1], 1500);
  // Field 2600 is v = 2600 − 4096 = −1496: also a range error.
  EXPECT_EQ(UnpackData(2600.0)->flags[2], AxisFlag::kRangeError);
  // Not a data word at all.
  for (const double bad : {0.5, -1.0, -2.0, 68719476736.0, std::numeric_limits<double>::quiet_NaN()}) {
    EXPECT_FALSE(UnpackData(bad).ok()) << bad;
  }
  EXPECT_TRUE(UnpackData(static_cast<double>(kMaxDataWord)).ok());
}

TEST(HandshakeWords, SplitLayout) {
  const BlockLayout split{Layout::kSplit, 500};
  EXPECT_EQ(split.data(), 501);
  EXPECT_EQ(split.run_counter(), 504);
  EXPECT_EQ(split.alarm(), 505);
  EXPECT_EQ(split.size(), 6);
  const BlockLayout packed{Layout::kPacked, 900};
  EXPECT_EQ(packed.run_counter(), 902);
  EXPECT_EQ(packed.size(), 4);
  const auto p = DecodeSplit({-999, 999, -1});
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(p->v, (std::array<int, 3>{-999, 999, -1}));
  EXPECT_EQ(DecodeSplit({-2048, 0, 1200})->flags[0], AxisFlag::kOverflow);
  EXPECT_EQ(DecodeSplit({-2048, 0, 1200})->flags[2], AxisFlag::kRangeError);
  EXPECT_FALSE(DecodeSplit({0.5, 0, 0}).ok());
  EXPECT_FALSE(DecodeSplit({kSplitEmpty, 0, 0}).ok());
}

}  // namespace
}  // namespace formloop::cnc

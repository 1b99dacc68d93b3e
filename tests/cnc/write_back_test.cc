// Confirmed write-back (cnc/write_back.h) against the emulated controller's offset table, in process:
// the write plan reader (format of /work/wt/WRITE_PLAN.md), the writer's own limit check (spec §9.10:
// 0.085 + 0.020 = 0.105 > 0.1 is never sent, 0.085 + 0.010 = 0.095 is), OFFSET_CHANGED, a read-back
// mismatch rolled back and verified, a refused write rolled back, and that a refusal sends nothing.

#include "cnc/write_back.h"

#include <gtest/gtest.h>

#include "core/json_io.h"
#include "core/point_io.h"
#include "tests/cnc/link_fixture.h"

namespace formloop::cnc {
namespace {

using testing::VirtualBench;

Json PlanJson(double delta_mm, const std::string& status = "SAFE", bool confirmed = true) {
  return Json::parse(R"({"format": "formloop.offset_write_plan", "version": 1, "session": "s", "status": ")" + status +
                     R"(", "blocked_reasons": [], "confirmed": )" + (confirmed ? "true" : "false") +
                     R"(, "not_reachable_acknowledged": [], "from_a_newer_tuning": {"x": 1}, "writes": [
      {"offset": "T3_radius_wear", "kind": "TOOL_RADIUS_WEAR", "tool": 3, "wcs": "", "axis": "", "address": "",
       "previous_mm": 0.085, "delta_mm": )" +
                     FormatExact(delta_mm) + R"(, "new_mm": )" + FormatExact(0.085 + delta_mm) +
                     R"(, "resolution_mm": 0.001, "baseline_mm": 0.0, "limit_mm": 0.1, "step_limit_mm": null},
      {"offset": "G55_Z", "kind": "WORK_OFFSET", "wcs": "G55", "axis": "Z", "previous_mm": -250.0, "delta_mm": -0.002,
       "new_mm": -250.002, "resolution_mm": 0.001, "baseline_mm": -250.0, "limit_mm": 0.05}]})");
}

ControllerOptions WithOffsets() {
  ControllerOptions o;
  o.points = 1;
  o.start_delay_s = 1e6;  // no measuring program: only the offset table matters here
  o.offsets["T3.radius_wear"] = OffsetEntry{0.085, -1, 1, 0.001};
  o.offsets["G55.Z"] = OffsetEntry{-250.0, -1000, 1000, 0.001};
  return o;
}

TEST(WritePlan, ReadsTheFormatAndNamesTheFieldOfAnError) {
  const auto plan = ParseWritePlan(PlanJson(0.010), "offsets.json");
  ASSERT_TRUE(plan.ok()) << plan.status().ToString();
  ASSERT_EQ(plan->writes.size(), 2u);
  EXPECT_EQ(plan->writes[0].address.ToString(), "T3.radius_wear");
  EXPECT_EQ(plan->writes[1].address.ToString(), "G55.Z");
  EXPECT_FALSE(plan->writes[0].step_limit_mm.has_value());

  struct Bad {
    std::string edit;  // a JSON pointer and its new value
    Json value;
    std::string field;
  };
  for (const Bad& b :
       {Bad{"/writes/1/limit_mm", -1, "writes[1].limit_mm"}, Bad{"/writes/0/kind", "TOOL_DIAMETER", "writes[0].kind"},
        Bad{"/writes/0/tool", 0, "writes[0].tool"}, Bad{"/format", "something", "format"},
        Bad{"/version", 2, "version"}, Bad{"/status", "MAYBE", "status"}, Bad{"/writes/1/wcs", "G60", "writes[1].wcs"},
        Bad{"/writes/0/resolution_mm", 0, "writes[0].resolution_mm"}}) {
    Json j = PlanJson(0.010);
    j[Json::json_pointer(b.edit)] = b.value;
    const auto bad = ParseWritePlan(j, "offsets.json");
    ASSERT_FALSE(bad.ok()) << b.edit;
    EXPECT_NE(bad.status().message().find("offsets.json: field '" + b.field + "'"), std::string::npos)
        << bad.status().message();
  }
  Json twice = PlanJson(0.010);
  twice["writes"][1] = twice["writes"][0];
  EXPECT_FALSE(ParseWritePlan(twice, "offsets.json").ok());
}

// Spec §9.10 on the writer's side: o_prev = 0.085 and δ = +0.020 give 0.105 > 0.1, so nothing is sent
// even when a (faulty) plan says SAFE; δ = +0.010 gives 0.095 and is written and verified.
TEST(WriteBack, Acceptance10TheLimitIsCheckedAgainAndNothingBeyondItIsSent) {
  VirtualBench bench(WithOffsets());
  const auto over = ParseWritePlan(PlanJson(0.020), "offsets.json");
  ASSERT_TRUE(over.ok());
  const auto refused = WriteBack(*bench.link, *over, true);
  ASSERT_TRUE(refused.ok());
  EXPECT_EQ(refused->outcome, "REFUSED");
  ASSERT_FALSE(refused->reasons.empty());
  EXPECT_NE(refused->reasons[0].find("0.105"), std::string::npos) << refused->reasons[0];
  EXPECT_EQ(bench.link->calls(), 0);  // not even a read
  EXPECT_EQ(*bench.controller->PeekOffset("T3.radius_wear"), 0.085);

  const auto ok = ParseWritePlan(PlanJson(0.010), "offsets.json");
  const auto written = WriteBack(*bench.link, *ok, true);
  ASSERT_TRUE(written.ok());
  EXPECT_EQ(written->outcome, "WRITTEN") << written->ToJson().dump();
  EXPECT_NEAR(*bench.controller->PeekOffset("T3.radius_wear"), 0.095, 1e-12);
  EXPECT_NEAR(*bench.controller->PeekOffset("G55.Z"), -250.002, 1e-9);
  EXPECT_NEAR(*written->items[0].read_back_mm, 0.095, 1e-12);
}

TEST(WriteBack, RefusesUnlessSafeConfirmedAndConfirmedByTheOperator) {
  VirtualBench bench(WithOffsets());
  for (const auto& [status, confirmed, operator_ok] : {std::tuple<std::string, bool, bool>{"RECHECK", true, true},
                                                       {"INTERVENE", true, true},
                                                       {"BLOCKED", true, true},
                                                       {"SAFE", false, true},
                                                       {"SAFE", true, false}}) {
    const auto plan = ParseWritePlan(PlanJson(0.010, status, confirmed), "offsets.json");
    ASSERT_TRUE(plan.ok());
    const auto r = WriteBack(*bench.link, *plan, operator_ok);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->outcome, "REFUSED") << status;
  }
  EXPECT_EQ(bench.link->calls(), 0);
  // A step limit and an inconsistent new value are refused too.
  Json step = PlanJson(0.010);
  step["writes"][0]["step_limit_mm"] = 0.005;
  EXPECT_EQ(WriteBack(*bench.link, *ParseWritePlan(step, "p"), true)->outcome, "REFUSED");
  Json wrong = PlanJson(0.010);
  wrong["writes"][0]["new_mm"] = 0.097;
  EXPECT_EQ(WriteBack(*bench.link, *ParseWritePlan(wrong, "p"), true)->outcome, "REFUSED");
  // A plan whose rounded changes were all zero has nothing to write: not a refusal, nothing sent.
  Json empty = PlanJson(0.010);
  empty["writes"] = Json::array();
  const auto nothing = WriteBack(*bench.link, *ParseWritePlan(empty, "p"), true);
  EXPECT_EQ(nothing->outcome, "NOTHING_TO_WRITE");
  EXPECT_TRUE(nothing->ok());
  EXPECT_EQ(bench.link->calls(), 0);
}

TEST(WriteBack, AnOffsetThatMovedSinceTheMeasurementAbortsBeforeWriting) {
  ControllerOptions o = WithOffsets();
  o.offsets["T3.radius_wear"].value_mm = 0.086;  // changed by 1 µm > resolution / 2
  VirtualBench bench(o);
  const auto r = WriteBack(*bench.link, *ParseWritePlan(PlanJson(0.010), "p"), true);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->outcome, "OFFSET_CHANGED");
  EXPECT_FALSE(r->items[0].written);
  EXPECT_EQ(*bench.controller->PeekOffset("T3.radius_wear"), 0.086);
  EXPECT_EQ(*bench.controller->PeekOffset("G55.Z"), -250.0);
}

TEST(WriteBack, AReadBackMismatchIsDetectedReportedAndEverythingRolledBack) {
  ControllerOptions o = WithOffsets();
  o.faults.offset_mismatch["G55.Z"] = 0.003;  // the controller stores 3 µm more than written, once
  VirtualBench bench(o);
  const auto r = WriteBack(*bench.link, *ParseWritePlan(PlanJson(0.010), "p"), true);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->outcome, "WRITE_VERIFY_FAILED");
  bool named = false;
  for (const auto& reason : r->reasons)
    named = named || reason.find("G55.Z was written -250.002 mm but reads back -249.999 mm") != std::string::npos;
  EXPECT_TRUE(named) << r->ToJson().dump(1);
  for (const auto& item : r->items) {
    EXPECT_TRUE(item.written);
    EXPECT_TRUE(item.rolled_back);
  }
  EXPECT_NEAR(*bench.controller->PeekOffset("T3.radius_wear"), 0.085, 1e-12);
  EXPECT_NEAR(*bench.controller->PeekOffset("G55.Z"), -250.0, 1e-9);
}

TEST(WriteBack, ARefusedWriteRollsBackWhatWasWritten) {
  ControllerOptions o = WithOffsets();
  o.faults.offset_reject.insert("G55.Z");
  VirtualBench bench(o);
  const auto r = WriteBack(*bench.link, *ParseWritePlan(PlanJson(0.010), "p"), true);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->outcome, "WRITE_FAILED");
  EXPECT_TRUE(r->items[0].written);
  EXPECT_FALSE(r->items[1].written);
  EXPECT_TRUE(r->items[0].rolled_back);
  EXPECT_TRUE(r->items[1].rolled_back);  // never changed: it reads its previous value
  EXPECT_NEAR(*bench.controller->PeekOffset("T3.radius_wear"), 0.085, 1e-12);
  EXPECT_EQ(*bench.controller->PeekOffset("G55.Z"), -250.0);  // it was never changed
}

}  // namespace
}  // namespace formloop::cnc

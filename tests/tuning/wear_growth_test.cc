// The wear-growth model (tuning/wear_growth.h) on synthetic series with a known shape and on the real data
// in data/reference (NASA/UC Berkeley milling, QIT-CEMC Ti6Al4V): per-case RMSE and leave-one-case-out error
// against the constant-rate baseline (issue 21 "what it must show" 5).

#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/number_text.h"
#include "tuning/wear_growth.h"

namespace formloop::tuning {
namespace {

const std::string kReference = std::string(FORMLOOP_REFERENCE_DIR) + "/";

// NASA milling: VB against time per case; rows without VB are skipped; cases with < 3 measurements left out.
std::vector<WearSeries> ReadNasa() {
  const auto table = ReadCsvTable(kReference + "nasa-milling-wear/milling_labels_with_tool_class.csv");
  EXPECT_TRUE(table.ok()) << table.status().ToString();
  if (!table.ok()) return {};
  const int col_case = table->Find("case"), col_vb = table->Find("VB"), col_t = table->Find("time");
  EXPECT_TRUE(col_case >= 0 && col_vb >= 0 && col_t >= 0);
  std::map<int, WearSeries> cases;
  for (const auto& c : table->rows) {
    double id = 0, vb = 0, t = 0;
    if (c[col_vb].empty() || !ParseDouble(c[col_case], &id) || !ParseDouble(c[col_vb], &vb) ||
        !ParseDouble(c[col_t], &t)) {
      continue;
    }
    WearSeries& s = cases[static_cast<int>(id)];
    s.name = "case " + c[col_case];
    s.time.push_back(t);
    s.wear_mm.push_back(vb);
  }
  std::vector<WearSeries> out;
  for (auto& [id, s] : cases) {
    if (s.time.size() >= 3) out.push_back(s);
  }
  return out;
}

// QIT-CEMC: side-teeth VBmax of cutting edges 1-4 against the cycle number (columns 1, 4, 7, 10). The file
// has a three-row header with quoted line breaks, so it is streamed line by line (core/csv.h CsvReader) and
// only rows whose first cell is a cycle number are kept.
std::vector<WearSeries> ReadQit(int max_cycle = 1000) {
  const auto text = ReadFile(kReference + "tool-wear-qit-cemc/tool_wear.csv");
  EXPECT_TRUE(text.ok());
  std::vector<WearSeries> edges(4);
  for (int e = 0; e < 4; ++e) edges[e].name = "edge " + std::to_string(e + 1);
  if (!text.ok()) return edges;
  CsvReader reader(*text);
  while (reader.Next()) {
    const auto& c = reader.cells();
    double cycle = 0;
    if (c.size() < 13 || !ParseDouble(c[0], &cycle) || cycle > max_cycle) continue;  // header rows fail here
    for (int e = 0; e < 4; ++e) {
      double vb = 0;
      if (!ParseDouble(c[1 + 3 * e], &vb)) continue;
      edges[e].time.push_back(cycle);
      edges[e].wear_mm.push_back(vb);
    }
  }
  return edges;
}

void Print(const std::string& title, const WearEvaluation& ev) {
  std::printf("%s: gamma (all) %.3f /mm\n", title.c_str(), ev.gamma_all);
  std::printf(
      "  %-8s %3s | fit RMSE model / const (mm) | LOCO gamma | one-step n, RMSE model / const | horizon n, RMSE model "
      "/ const\n",
      "case", "pts");
  for (const auto& c : ev.cases) {
    std::printf("  %-8s %3d |      %.4f / %.4f         |   %6.3f   |  %3d  %.4f / %.4f           |  %3d  %.4f / %.4f\n",
                c.name.c_str(), c.points, c.fit_rmse_model, c.fit_rmse_constant, c.gamma_loco, c.one_step_n,
                c.one_step_rmse_model, c.one_step_rmse_constant, c.horizon_n, c.horizon_rmse_model,
                c.horizon_rmse_constant);
  }
  std::printf(
      "  pooled: fit %.4f / %.4f; LOCO one-step %.4f / %.4f; LOCO horizon (second half from the first) %.4f / %.4f "
      "mm\n",
      ev.fit_rmse_model, ev.fit_rmse_constant, ev.one_step_rmse_model, ev.one_step_rmse_constant, ev.horizon_rmse_model,
      ev.horizon_rmse_constant);
}

// Series that follow dVB/dt = r·exp(γ·VB) exactly: the model predicts them exactly and recovers γ.
TEST(WearGrowth, RecoversAKnownShape) {
  const double gamma = 2.0;
  std::vector<WearSeries> series;
  for (int k = 0; k < 4; ++k) {
    WearSeries s;
    s.name = "synthetic " + std::to_string(k);
    const double w0 = 0.02 + 0.01 * k, r = 0.004 + 0.002 * k;
    for (int i = 0; i < 12; ++i) {
      s.time.push_back(3.0 * i);
      s.wear_mm.push_back(WearInverse(w0 + r * 3.0 * i, gamma));
    }
    series.push_back(s);
  }
  auto fitted = FitGrowthShape(series);
  ASSERT_TRUE(fitted.ok());
  EXPECT_NEAR(*fitted, gamma, 1e-4);
  auto change = PredictNextWearChange(series[1], 6, gamma, 18.0);
  ASSERT_TRUE(change.ok());
  EXPECT_NEAR(series[1].wear_mm[5] + *change, series[1].wear_mm[6], 1e-12);
  auto ev = EvaluateWearGrowth(series);
  ASSERT_TRUE(ev.ok());
  EXPECT_LT(ev->horizon_rmse_model, 1e-6);
  EXPECT_GT(ev->horizon_rmse_constant, 1e-3);  // a straight line cannot follow the acceleration
  // Flank wear to radius: VB 0.2 mm on a 7° clearance face, 0 rake → 0.0246 mm.
  EXPECT_NEAR(RadialWearFromFlankWear(0.2, 7.0), 0.2 * std::tan(7.0 * M_PI / 180), 1e-15);
}

TEST(WearGrowth, NasaMillingPerCaseAndLeaveOneCaseOut) {
  const auto cases = ReadNasa();
  ASSERT_EQ(cases.size(), 15u);  // case 6 has a single VB reading
  auto ev = EvaluateWearGrowth(cases);
  ASSERT_TRUE(ev.ok()) << ev.status().ToString();
  Print("NASA milling (VB vs time in min, 15 cases)", *ev);
  int one_step = 0;
  for (const auto& c : ev->cases) one_step += c.one_step_n;
  EXPECT_EQ(one_step, 115);  // Σ (points − 2)
  // Measured on this data (the test fails if the model regresses): over a horizon the growth model predicts the
  // second half of an unseen tool better than a constant rate; one measurement ahead it is no better (the
  // next reading is dominated by the 0.01-0.05 mm scatter of the VB readings), and not much worse.
  EXPECT_LT(ev->horizon_rmse_model, 0.9 * ev->horizon_rmse_constant);
  EXPECT_LT(ev->one_step_rmse_model, 1.15 * ev->one_step_rmse_constant);
  EXPECT_LE(ev->fit_rmse_model, ev->fit_rmse_constant);
}

TEST(WearGrowth, QitCemcEdgesLeaveOneEdgeOut) {
  const auto all = ReadQit();
  ASSERT_EQ(all.size(), 4u);
  ASSERT_EQ(all[0].time.size(), 68u);
  auto ev = EvaluateWearGrowth(all);
  ASSERT_TRUE(ev.ok());
  Print("QIT-CEMC side teeth VBmax (cycles 1-68, 4 edges of one tool)", *ev);
  // The readings fall and scatter after cycle ~20 (data README): over the monotone part alone as well.
  const auto early = ReadQit(20);
  auto ev20 = EvaluateWearGrowth(early);
  ASSERT_TRUE(ev20.ok());
  Print("QIT-CEMC side teeth VBmax (cycles 1-20)", *ev20);
  for (const auto* e : {&*ev, &*ev20}) {
    EXPECT_TRUE(std::isfinite(e->horizon_rmse_model) && std::isfinite(e->one_step_rmse_model));
    EXPECT_LT(e->one_step_rmse_model, 0.1);  // mm: the same order as the readings' scatter
  }
}

TEST(WearGrowth, ShortSeriesAreRefused) {
  std::vector<WearSeries> s(3);
  for (int k = 0; k < 3; ++k) {
    s[k].name = "s" + std::to_string(k);
    s[k].time = {0, 1, 2};
    s[k].wear_mm = {0, 0.1, 0.2};
  }
  s[2].time.pop_back();
  s[2].wear_mm.pop_back();
  auto ev = EvaluateWearGrowth(s);
  ASSERT_FALSE(ev.ok());
  EXPECT_NE(ev.status().message().find("'s2'"), std::string::npos);
}

}  // namespace
}  // namespace formloop::tuning

#pragma once
// Raster charts drawn on app::Canvas (the feed-control time plot of `formloop optimise`), with every label,
// axis and scale bar inside the picture, and the tick helpers the SVG charts of the run report
// (app/report_svg.h) share. Every function is deterministic: the same inputs give the same pixels.

#include <functional>
#include <string>
#include <vector>

#include "app/report_image.h"

namespace formloop::app {

// (x, y in mm) -> over the part or not: the run report's maps leave cells off the part blank (outside a
// trimmed face's edge or over its holes nothing is extrapolated).
using MapMask = std::function<bool(double x_mm, double y_mm)>;

// One histogram series of the run report (report_svg.h): values and how to draw and name them.
struct HistogramSeries {
  std::vector<double> values_um;
  std::string label;
  Rgb colour;
};

// One line of a time plot: values against time, drawn in one colour and named in the legend.
struct TimeSeries {
  std::vector<double> t_s, values;
  std::string label;
  Rgb colour;
};
// A horizontal reference line of a panel (a set point, a limit), dashed, labelled at its right end.
struct LevelLine {
  double value = 0;
  std::string label;
  Rgb colour;
};
struct TimePanel {
  std::vector<TimeSeries> series;
  std::vector<LevelLine> levels;
  std::string y_label;
};
// Panels stacked over one shared time axis (e.g. spindle current and feed of a feed-control run), each
// with its own y range covering its series and levels from 0, a legend per panel and the title on top.
Canvas DrawTimePanels(const std::vector<TimePanel>& panels, const std::string& title);

// Tick positions: "nice" steps (1, 2, 5 × 10^k) covering [lo, hi] with about `target` ticks.
std::vector<double> NiceTicks(double lo, double hi, int target);
// A tick label with as many decimals as the step needs ("0.5", "10", "-2.5").
std::string TickLabel(double value, double step);

}  // namespace formloop::app

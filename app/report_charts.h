#pragma once
// The pictures of the run report (app/report.h), drawn on app::Canvas with every label, axis and
// scale bar inside the picture, so a picture copied out of the report still says what it shows.
//
// Inputs are plain vectors: x_mm, y_mm  #P probe point positions in the part frame (mm);
// values_um #P values (µm); clusters #P LISA cluster codes (report_image.h), or empty.
// Every function is deterministic: the same inputs give the same pixels.

#include <functional>
#include <string>
#include <vector>

#include "app/report_image.h"

namespace formloop::app {

// A colour map of a scalar field over the points' (x, y) bounding box, equal scale on both axes.
// The raster is filled by inverse-distance weighting (power 2) over the points within 1.5 median
// point spacings of each pixel and left blank farther away, so holes and outlines stay visible;
// probe points are marked as dots. Colours: DivergingColour(value, max_abs_um), with a horizontal
// colour bar labelled in µm, so maps drawn with the same max_abs_um compare directly.
// With `inside` (x, y in mm -> part or not), pixels outside the part are left blank however near a point
// they lie: outside a trimmed face's edge or over its holes nothing is extrapolated.
using MapMask = std::function<bool(double x_mm, double y_mm)>;
Canvas DrawFieldMap(const std::vector<double>& x_mm, const std::vector<double>& y_mm,
                    const std::vector<double>& values_um, double max_abs_um, const std::string& title,
                    const std::string& bar_label, const MapMask& inside = {});

// LISA clusters at the point positions (same frame as DrawFieldMap), with a legend and counts.
Canvas DrawClusterMap(const std::vector<double>& x_mm, const std::vector<double>& y_mm,
                      const std::vector<int>& clusters, const std::string& title);

// One histogram series: values and how to draw and name them.
struct HistogramSeries {
  std::vector<double> values_um;
  std::string label;
  Rgb colour;
};
// Histograms on shared bins (bars of the series side by side in each bin), with dashed lines at
// ±tolerance_um (none when tolerance_um is NaN: no tolerance given).
Canvas DrawHistogram(const std::vector<HistogramSeries>& series, double tolerance_um, const std::string& title);

// Moran scatter plot (Anselin 1996): x = standardised value z_i, y = standardised spatial lag,
// points coloured by LISA cluster (clusters may be empty), axes through 0 and the line through the
// origin with slope moran_i (the slope of the lag on z for row-standardised weights).
Canvas DrawMoranScatter(const std::vector<double>& z, const std::vector<double>& lag_z,
                        const std::vector<int>& clusters, double moran_i, const std::string& title);

// Bars per category (e.g. form error per loop) with a dashed horizontal line at limit; bars above
// the limit are drawn in a warning colour. A NaN limit (none given) draws no line and no warning.
Canvas DrawBars(const std::vector<std::string>& labels, const std::vector<double>& values, double limit,
                const std::string& limit_label, const std::string& y_label, const std::string& title);

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

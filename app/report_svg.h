#pragma once
// The charts of the run report (app/report.h) as SVG for inline use in the HTML: real text (axis
// titles with units, tick labels, tolerance lines and legends), so they stay crisp at any zoom and print.
// Deviation maps show the interpolated field on a grid (InterpolateField), drawn as a smooth raster
// inside the SVG, with the probe points on top and a colour bar; every map and the 3-D view of the
// report use DivergingColour (report_image.h) with one ±max_abs scale.
//
// Every function is deterministic (numbers through core/number_text.h): same inputs, same bytes.

#include <string>
#include <vector>

#include "app/report_charts.h"
#include "app/report_image.h"

namespace formloop::app::report {

// A scalar field sampled on a regular grid over the points' (x, y) box: cell (i, j) centred at
// (x0 + (i + ½)·dx, y0 + (j + ½)·dy), j = 0 the lowest row. NaN where the field is not drawn.
struct FieldGrid {
  int nx = 0, ny = 0;
  double x0 = 0, y0 = 0, dx = 1, dy = 1;
  std::vector<double> values;  // nx × ny, row j at j·nx
  double At(int i, int j) const { return values[static_cast<std::size_t>(j) * nx + i]; }
};

// The field through the probe points, smoothed by a Gaussian kernel (Nadaraya–Watson; bandwidth
// 0.75 × the median probe spacing, support 2.5 bandwidths) on a grid of at most `max_cells` cells
// along the longer side. A cell is left NaN when no point lies within 1.5 spacings (holes and
// outlines stay visible) or when `inside` says it is off the part. For a field that is smooth
// between the points (the systematic field d_s) this shows the field, not rings around each point.
FieldGrid InterpolateField(const std::vector<double>& x_mm, const std::vector<double>& y_mm,
                           const std::vector<double>& values, int max_cells, const MapMask& inside = {});

// A colour map of `grid` with axes in mm (equal scale), the points as small dots, a colour bar over
// ±max_abs labelled `bar_label` (HTML allowed: subscripts as <tspan>), title on top.
std::string SvgFieldMap(const FieldGrid& grid, const std::vector<double>& x_mm, const std::vector<double>& y_mm,
                        double max_abs, const std::string& title, const std::string& bar_label);
// LISA clusters at the point positions with a legend and counts.
std::string SvgClusterMap(const std::vector<double>& x_mm, const std::vector<double>& y_mm,
                          const std::vector<int>& clusters, const std::string& title);
// Histograms on shared bins with dashed lines at ±tolerance_um (none when NaN) and a legend.
std::string SvgHistogram(const std::vector<HistogramSeries>& series, double tolerance_um, const std::string& title);
// Moran scatter: z against its spatial lag, coloured by cluster, with the line of slope moran_i.
std::string SvgMoranScatter(const std::vector<double>& z, const std::vector<double>& lag_z,
                            const std::vector<int>& clusters, double moran_i, const std::string& title);
// Bars per category with a dashed limit line (none when NaN); bars above it in a warning colour.
std::string SvgBars(const std::vector<std::string>& labels, const std::vector<double>& values, double limit,
                    const std::string& limit_label, const std::string& y_label, const std::string& title);

// "#rrggbb".
std::string HexOf(Rgb colour);
// An SVG <linearGradient> id'd `id` running through DivergingColour from −1 to +1 (for colour bars).
std::string DivergingGradient(const std::string& id);
// A zero-size <svg> defining the gradient "fl-scale" every colour bar of the page refers to: put it once
// at the top of <body>.
std::string ScaleDefinitions();

}  // namespace formloop::app::report

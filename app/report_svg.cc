#include "app/report_svg.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <fmt/format.h>

#include "app/report_html.h"
#include "core/number_text.h"

namespace formloop::app::report {
namespace {

constexpr const char* kInk = "#222222";
constexpr const char* kAxisGrey = "#888888";
constexpr const char* kGridGrey = "#e6e6e6";
constexpr const char* kLimitRed = "#d7191c";
constexpr const char* kBlankGrey = "#f0f0f0";

std::string F(double v) { return FormatFixed(v, 1); }

// A plot frame: [x_lo, x_hi] × [y_lo, y_hi] in data units drawn in the pixel box (left, top, w, h), y up.
struct Frame {
  double left = 0, top = 0, w = 1, h = 1;
  double x_lo = 0, x_hi = 1, y_lo = 0, y_hi = 1;
  double Px(double x) const { return left + (x - x_lo) / (x_hi - x_lo) * w; }
  double Py(double y) const { return top + h - (y - y_lo) / (y_hi - y_lo) * h; }
};

// An SVG document of fixed view box that scales with its container (CSS: svg.chart{max-width:100%}).
class Svg {
 public:
  Svg(double width, double height, const std::string& title) : width_(width), height_(height) {
    body_ += "<title>" + Esc(title) + "</title>\n";
    Text(width / 2, 20, Esc(title), "middle", "title");
  }
  // `markup` is already escaped (it may hold <tspan>s).
  void Text(double x, double y, const std::string& markup, const char* anchor = "start", const char* cls = "",
            const char* fill = kInk) {
    body_ += fmt::format("<text x=\"{}\" y=\"{}\" text-anchor=\"{}\"{}{}>{}</text>\n", F(x), F(y), anchor,
                         *cls ? fmt::format(" class=\"{}\"", cls) : "",
                         fill != kInk ? fmt::format(" fill=\"{}\"", fill) : "", markup);
  }
  // Text turned 90° anticlockwise, centred on (x, y).
  void VerticalText(double x, double y, const std::string& markup) {
    body_ += fmt::format("<text transform=\"translate({},{}) rotate(-90)\" text-anchor=\"middle\">{}</text>\n", F(x),
                         F(y), markup);
  }
  void Line(double x0, double y0, double x1, double y1, const char* stroke, double width = 1, bool dashed = false) {
    body_ += fmt::format("<line x1=\"{}\" y1=\"{}\" x2=\"{}\" y2=\"{}\" stroke=\"{}\" stroke-width=\"{}\"{}/>\n", F(x0),
                         F(y0), F(x1), F(y1), stroke, F(width), dashed ? " stroke-dasharray=\"6 4\"" : "");
  }
  void Rect(double x, double y, double w, double h, const std::string& fill, const char* stroke = "none") {
    body_ += fmt::format("<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"{}\"{}/>\n", F(x), F(y), F(w), F(h),
                         fill, std::string(stroke) != "none" ? fmt::format(" stroke=\"{}\"", stroke) : "");
  }
  void Raw(const std::string& markup) { body_ += markup; }
  std::string Str() const {
    return fmt::format(
        "<svg class=\"chart\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {0} {1}\" width=\"{0}\" "
        "height=\"{1}\" role=\"img\">\n{2}</svg>\n",
        F(width_), F(height_), body_);
  }

 private:
  double width_, height_;
  std::string body_;
};

// Ticks and labels on the left and bottom, the frame outline and the axis titles.
void Axes(Svg& svg, const Frame& f, const std::string& x_title, const std::string& y_title, int x_target = 6,
          int y_target = 5) {
  const std::vector<double> xt = NiceTicks(f.x_lo, f.x_hi, x_target);
  const std::vector<double> yt = NiceTicks(f.y_lo, f.y_hi, y_target);
  const double x_step = xt.size() > 1 ? xt[1] - xt[0] : 1, y_step = yt.size() > 1 ? yt[1] - yt[0] : 1;
  const double bottom = f.top + f.h;
  for (double t : xt) {
    svg.Line(f.Px(t), bottom, f.Px(t), bottom + 5, kInk);
    svg.Text(f.Px(t), bottom + 18, TickLabel(t, x_step), "middle");
  }
  for (double t : yt) {
    svg.Line(f.left - 5, f.Py(t), f.left, f.Py(t), kInk);
    svg.Text(f.left - 8, f.Py(t) + 4, TickLabel(t, y_step), "end");
  }
  svg.Raw(fmt::format("<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"{}\"/>\n", F(f.left),
                      F(f.top), F(f.w), F(f.h), kInk));
  svg.Text(f.left + f.w / 2, bottom + 38, x_title, "middle", "axis");
  svg.VerticalText(16, f.top + f.h / 2, y_title);
}

// The frame of a map: equal mm per pixel, at most max_w × max_h.
Frame MapFrame(double x_lo, double x_hi, double y_lo, double y_hi, double left, double top, double max_w,
               double max_h) {
  const double px_per_mm = std::min(max_w / (x_hi - x_lo), max_h / (y_hi - y_lo));
  return {left, top, (x_hi - x_lo) * px_per_mm, (y_hi - y_lo) * px_per_mm, x_lo, x_hi, y_lo, y_hi};
}

// A horizontal colour bar over ±max_abs centred at cx.
void ColourBar(Svg& svg, double cx, double top, double width, double max_abs, const std::string& label) {
  const double range = max_abs > 0 ? max_abs : 1;
  // The gradient is defined once per page (ScaleDefinitions), so every bar is the same scale object.
  svg.Rect(cx - width / 2, top, width, 14, "url(#fl-scale)", kInk);
  const std::vector<double> ticks = NiceTicks(-range, range, 5);
  const double step = ticks.size() > 1 ? ticks[1] - ticks[0] : 1;
  for (double t : ticks) {
    const double px = cx - width / 2 + (t + range) / (2 * range) * width;
    svg.Line(px, top + 14, px, top + 19, kInk);
    svg.Text(px, top + 32, TickLabel(t, step), "middle");
  }
  svg.Text(cx, top + 50, label, "middle", "axis");
}

// Points bucketed on a square grid of cell `cell_mm`, for radius queries.
class PointGrid {
 public:
  PointGrid(const std::vector<double>& x, const std::vector<double>& y, double x_lo, double y_lo, double x_hi,
            double y_hi, double cell_mm)
      : x_(x), y_(y), x_lo_(x_lo), y_lo_(y_lo), cell_(cell_mm) {
    nx_ = std::max(1, static_cast<int>(std::ceil((x_hi - x_lo) / cell_)) + 1);
    ny_ = std::max(1, static_cast<int>(std::ceil((y_hi - y_lo) / cell_)) + 1);
    cells_.resize(static_cast<std::size_t>(nx_) * static_cast<std::size_t>(ny_));
    for (std::size_t i = 0; i < x.size(); ++i) cells_[Cell(CellX(x[i]), CellY(y[i]))].push_back(i);
  }
  // Calls visit(i, distance) for every point within cell_mm of (x, y).
  template <typename Visit>
  void ForNear(double x, double y, Visit&& visit) const {
    const int cx = CellX(x), cy = CellY(y);
    for (int j = std::max(cy - 1, 0); j <= std::min(cy + 1, ny_ - 1); ++j) {
      for (int i = std::max(cx - 1, 0); i <= std::min(cx + 1, nx_ - 1); ++i) {
        for (std::size_t p : cells_[Cell(i, j)]) {
          const double d = std::hypot(x_[p] - x, y_[p] - y);
          if (d <= cell_) visit(p, d);
        }
      }
    }
  }

 private:
  int CellX(double x) const { return std::clamp(static_cast<int>(std::floor((x - x_lo_) / cell_)), 0, nx_ - 1); }
  int CellY(double y) const { return std::clamp(static_cast<int>(std::floor((y - y_lo_) / cell_)), 0, ny_ - 1); }
  std::size_t Cell(int i, int j) const { return static_cast<std::size_t>(j) * static_cast<std::size_t>(nx_) + i; }
  const std::vector<double>& x_;
  const std::vector<double>& y_;
  double x_lo_, y_lo_, cell_;
  int nx_ = 1, ny_ = 1;
  std::vector<std::vector<std::size_t>> cells_;
};

// Median nearest-neighbour distance over (up to) 500 evenly chosen points: the probe spacing. Neighbours
// are looked up in a bucket grid of about 4 points per cell (a million-point scan stays fast); a point
// with none within a cell's reach falls back to a scan of all points.
double PointSpacing(const std::vector<double>& x, const std::vector<double>& y) {
  const std::size_t n = x.size();
  if (n < 2) return 1;
  const auto [x_lo, x_hi] = std::minmax_element(x.begin(), x.end());
  const auto [y_lo, y_hi] = std::minmax_element(y.begin(), y.end());
  const double w = std::max(*x_hi - *x_lo, 1e-9), h = std::max(*y_hi - *y_lo, 1e-9);
  const double cell = std::max(2 * std::sqrt(w * h / static_cast<double>(n)), std::max(w, h) / 4096);
  const PointGrid grid(x, y, *x_lo, *y_lo, *x_hi, *y_hi, cell);
  const std::size_t stride = std::max<std::size_t>(1, n / 500);
  std::vector<double> nearest;
  for (std::size_t i = 0; i < n; i += stride) {
    double best = std::numeric_limits<double>::infinity();
    grid.ForNear(x[i], y[i], [&](std::size_t j, double d) {
      if (j != i && d > 0) best = std::min(best, d);
    });
    if (!std::isfinite(best)) {
      for (std::size_t j = 0; j < n; ++j) {
        const double d = std::hypot(x[i] - x[j], y[i] - y[j]);
        if (j != i && d > 0) best = std::min(best, d);
      }
    }
    if (std::isfinite(best)) nearest.push_back(best);
  }
  if (nearest.empty()) return 1;
  std::nth_element(nearest.begin(), nearest.begin() + static_cast<std::ptrdiff_t>(nearest.size() / 2), nearest.end());
  return nearest[nearest.size() / 2];
}

}  // namespace

std::string HexOf(Rgb c) { return fmt::format("#{:02x}{:02x}{:02x}", c.r, c.g, c.b); }

std::string ScaleDefinitions() {
  return "<svg width=\"0\" height=\"0\" style=\"position:absolute\" aria-hidden=\"true\"><defs>" +
         DivergingGradient("fl-scale") + "</defs></svg>\n";
}

std::string DivergingGradient(const std::string& id) {
  std::string out = "<linearGradient id=\"" + id + "\" x1=\"0\" x2=\"1\" y1=\"0\" y2=\"0\">";
  for (int k = 0; k <= 10; ++k) {
    out += fmt::format("<stop offset=\"{}\" stop-color=\"{}\"/>", FormatFixed(k / 10.0, 1),
                       HexOf(DivergingColour(-1 + k / 5.0, 1)));
  }
  return out + "</linearGradient>";
}

FieldGrid InterpolateField(const std::vector<double>& x, const std::vector<double>& y,
                           const std::vector<double>& values, int max_cells, const MapMask& inside) {
  FieldGrid g;
  if (x.empty() || values.size() != x.size()) return g;
  double x_lo = *std::min_element(x.begin(), x.end()), x_hi = *std::max_element(x.begin(), x.end());
  double y_lo = *std::min_element(y.begin(), y.end()), y_hi = *std::max_element(y.begin(), y.end());
  const double span = std::max({x_hi - x_lo, y_hi - y_lo, 1e-3});
  if (x_hi - x_lo < 1e-9 * span) x_lo -= span / 2, x_hi += span / 2;
  if (y_hi - y_lo < 1e-9 * span) y_lo -= span / 2, y_hi += span / 2;
  const double cell = std::max(x_hi - x_lo, y_hi - y_lo) / std::max(max_cells, 2);
  g.nx = std::max(2, static_cast<int>(std::ceil((x_hi - x_lo) / cell)));
  g.ny = std::max(2, static_cast<int>(std::ceil((y_hi - y_lo) / cell)));
  g.dx = (x_hi - x_lo) / g.nx, g.dy = (y_hi - y_lo) / g.ny, g.x0 = x_lo, g.y0 = y_lo;
  const double spacing = PointSpacing(x, y);
  const double h = 0.75 * spacing;
  // The support also stays above 1/1000 of the box so that nearly coincident points cannot make the
  // bucket grid huge.
  const double support = std::max(2.5 * h, span / 1000);
  const PointGrid near(x, y, x_lo, y_lo, x_hi, y_hi, support);
  g.values.assign(static_cast<std::size_t>(g.nx) * g.ny, std::numeric_limits<double>::quiet_NaN());
  for (int j = 0; j < g.ny; ++j) {
    for (int i = 0; i < g.nx; ++i) {
      const double cx = g.x0 + (i + 0.5) * g.dx, cy = g.y0 + (j + 0.5) * g.dy;
      if (inside && !inside(cx, cy)) continue;
      double sum_w = 0, sum_wv = 0, nearest = std::numeric_limits<double>::infinity();
      near.ForNear(cx, cy, [&](std::size_t p, double d) {
        const double w = std::exp(-0.5 * (d / h) * (d / h));
        sum_w += w, sum_wv += w * values[p];
        nearest = std::min(nearest, d);
      });
      if (sum_w > 0 && nearest <= 1.5 * spacing) g.values[static_cast<std::size_t>(j) * g.nx + i] = sum_wv / sum_w;
    }
  }
  return g;
}

std::string SvgFieldMap(const FieldGrid& grid, const std::vector<double>& x_mm, const std::vector<double>& y_mm,
                        double max_abs, const std::string& title, const std::string& bar_label) {
  const double x_hi = grid.x0 + grid.nx * grid.dx, y_hi = grid.y0 + grid.ny * grid.dy;
  const Frame f = MapFrame(grid.x0, x_hi, grid.y0, y_hi, 70, 40, 460, 340);
  Svg svg(std::max(560.0, f.left + f.w + 30), f.top + f.h + 120, title);
  if (grid.nx > 0) {
    // The grid as a raster (one pixel per cell, top row first), scaled smoothly by the browser.
    Canvas raster(grid.nx, grid.ny);
    for (int j = 0; j < grid.ny; ++j) {
      for (int i = 0; i < grid.nx; ++i) {
        const double v = grid.At(i, j);
        raster.Set(i, grid.ny - 1 - j, std::isfinite(v) ? DivergingColour(v, max_abs) : HexColour(0xf0f0f0));
      }
    }
    const Result<std::string> png = EncodePng(raster);
    if (png.ok()) {
      svg.Raw(
          fmt::format("<image x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" preserveAspectRatio=\"none\" "
                      "href=\"data:image/png;base64,{}\"/>\n",
                      F(f.left), F(f.top), F(f.w), F(f.h), Base64(*png)));
    }
    const double dot = x_mm.size() > 2000 ? 0.5 : 1.1;
    std::string dots = "<g fill=\"" + std::string(kInk) + "\" fill-opacity=\"0.55\">";
    // At most 20,000 dots (every k-th point of a dense scan).
    for (std::size_t i = 0; i < x_mm.size(); i += std::max<std::size_t>(1, x_mm.size() / 20000)) {
      dots += fmt::format("<circle cx=\"{}\" cy=\"{}\" r=\"{}\"/>", F(f.Px(x_mm[i])), F(f.Py(y_mm[i])), F(dot));
    }
    svg.Raw(dots + "</g>\n");
  } else {
    svg.Rect(f.left, f.top, f.w, f.h, kBlankGrey);
    svg.Text(f.left + f.w / 2, f.top + f.h / 2, "no points", "middle", "", kAxisGrey);
  }
  Axes(svg, f, "x (mm)", "y (mm)");
  ColourBar(svg, std::max(560.0, f.left + f.w + 30) / 2, f.top + f.h + 52, 360, max_abs, bar_label);
  return svg.Str();
}

std::string SvgClusterMap(const std::vector<double>& x_mm, const std::vector<double>& y_mm,
                          const std::vector<int>& clusters, const std::string& title) {
  double x_lo = 0, x_hi = 1, y_lo = 0, y_hi = 1;
  if (!x_mm.empty()) {
    x_lo = *std::min_element(x_mm.begin(), x_mm.end()), x_hi = *std::max_element(x_mm.begin(), x_mm.end());
    y_lo = *std::min_element(y_mm.begin(), y_mm.end()), y_hi = *std::max_element(y_mm.begin(), y_mm.end());
  }
  const double span = std::max({x_hi - x_lo, y_hi - y_lo, 1e-3});
  if (x_hi - x_lo < 1e-9 * span) x_lo -= span / 2, x_hi += span / 2;
  if (y_hi - y_lo < 1e-9 * span) y_lo -= span / 2, y_hi += span / 2;
  const Frame f = MapFrame(x_lo, x_hi, y_lo, y_hi, 70, 40, 460, 340);
  const double width = std::max(560.0, f.left + f.w + 30);
  Svg svg(width, f.top + f.h + 110, title);
  const double spacing_px = PointSpacing(x_mm, y_mm) * f.w / (x_hi - x_lo);
  const double r = std::clamp(0.4 * spacing_px, 1.2, 7.0);
  std::vector<int> counts(kLisaClusterCount, 0);
  std::string dots = "<g stroke=\"#555555\" stroke-width=\"0.4\">";
  for (std::size_t i = 0; i < x_mm.size(); ++i) {
    const int k = i < clusters.size() ? clusters[i] : 0;
    if (k >= 0 && k < kLisaClusterCount) ++counts[static_cast<std::size_t>(k)];
    if (i % std::max<std::size_t>(1, x_mm.size() / 20000) != 0) continue;  // at most 20,000 dots
    dots += fmt::format("<circle cx=\"{}\" cy=\"{}\" r=\"{}\" fill=\"{}\"/>", F(f.Px(x_mm[i])), F(f.Py(y_mm[i])), F(r),
                        HexOf(LisaColour(k)));
  }
  svg.Raw(dots + "</g>\n");
  Axes(svg, f, "x (mm)", "y (mm)");
  // Legend: three per row.
  for (int k = 0; k < kLisaClusterCount; ++k) {
    const double lx = 40 + (k % 3) * (width - 60) / 3, ly = f.top + f.h + 56 + (k / 3) * 20;
    svg.Rect(lx, ly - 10, 12, 12, HexOf(LisaColour(k)), kAxisGrey);
    svg.Text(lx + 18, ly, fmt::format("{} ({})", LisaName(k), counts[static_cast<std::size_t>(k)]));
  }
  return svg.Str();
}

std::string SvgHistogram(const std::vector<HistogramSeries>& series, double tolerance_um, const std::string& title) {
  const bool has_tolerance = std::isfinite(tolerance_um);
  double lo = has_tolerance ? -std::abs(tolerance_um) : std::numeric_limits<double>::infinity();
  double hi = has_tolerance ? std::abs(tolerance_um) : -std::numeric_limits<double>::infinity();
  for (const HistogramSeries& s : series) {
    for (double v : s.values_um) lo = std::min(lo, v), hi = std::max(hi, v);
  }
  if (!(hi > lo)) lo = -1, hi = 1;
  const double pad = 0.08 * (hi - lo);
  lo -= pad, hi += pad;
  constexpr int kBins = 30;
  std::vector<std::vector<int>> counts(series.size(), std::vector<int>(kBins, 0));
  int max_count = 1;
  for (std::size_t s = 0; s < series.size(); ++s) {
    for (double v : series[s].values_um) {
      const int b = std::clamp(static_cast<int>((v - lo) / (hi - lo) * kBins), 0, kBins - 1);
      max_count = std::max(max_count, ++counts[s][static_cast<std::size_t>(b)]);
    }
  }
  const Frame f{70, 40, 460, 280, lo, hi, 0, max_count * 1.25};
  Svg svg(560, f.top + f.h + 60, title);
  for (double t : NiceTicks(f.y_lo, f.y_hi, 5)) svg.Line(f.left, f.Py(t), f.left + f.w, f.Py(t), kGridGrey);
  const double bin = f.w / kBins, bar = bin / std::max<std::size_t>(series.size(), 1);
  for (std::size_t s = 0; s < series.size(); ++s) {
    std::string bars = "<g fill=\"" + HexOf(series[s].colour) + "\">";
    for (int b = 0; b < kBins; ++b) {
      const int n = counts[s][static_cast<std::size_t>(b)];
      if (n == 0) continue;
      bars += fmt::format("<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\"/>", F(f.left + b * bin + s * bar),
                          F(f.Py(n)), F(std::max(bar - 0.8, 0.5)), F(f.top + f.h - f.Py(n)));
    }
    svg.Raw(bars + "</g>\n");
  }
  if (has_tolerance) {
    const double t = std::abs(tolerance_um);
    svg.Line(f.Px(-t), f.top, f.Px(-t), f.top + f.h, kLimitRed, 1.5, true);
    svg.Line(f.Px(t), f.top, f.Px(t), f.top + f.h, kLimitRed, 1.5, true);
    // Labels on the inner side of each line, so neither is clipped at the frame's edge.
    svg.Text(f.Px(-t) + 4, f.top + 14, "−α = −" + Readable(t) + " µm", "start", "", kLimitRed);
    svg.Text(f.Px(t) - 4, f.top + 14, "+α", "end", "", kLimitRed);
  }
  Axes(svg, f, "deviation (µm)", "probe points");
  for (std::size_t s = 0; s < series.size(); ++s) {
    const double ly = f.top + 34 + s * 18;
    svg.Rect(f.left + f.w - 110, ly - 10, 12, 12, HexOf(series[s].colour));
    svg.Text(f.left + f.w - 92, ly, Esc(series[s].label));
  }
  return svg.Str();
}

std::string SvgMoranScatter(const std::vector<double>& z, const std::vector<double>& lag_z,
                            const std::vector<int>& clusters, double moran_i, const std::string& title) {
  double range = 1;
  for (std::size_t i = 0; i < z.size() && i < lag_z.size(); ++i) {
    range = std::max({range, std::abs(z[i]), std::abs(lag_z[i])});
  }
  range *= 1.1;
  const Frame f{70, 40, 400, 400, -range, range, -range, range};
  Svg svg(500, f.top + f.h + 60, title);
  for (double t : NiceTicks(-range, range, 6)) {
    svg.Line(f.Px(t), f.top, f.Px(t), f.top + f.h, kGridGrey);
    svg.Line(f.left, f.Py(t), f.left + f.w, f.Py(t), kGridGrey);
  }
  svg.Line(f.Px(0), f.top, f.Px(0), f.top + f.h, kAxisGrey);
  svg.Line(f.left, f.Py(0), f.left + f.w, f.Py(0), kAxisGrey);
  svg.Text(f.left + f.w - 8, f.top + 20, "HH", "end", "quadrant", kAxisGrey);
  svg.Text(f.left + 8, f.top + 20, "LH", "start", "quadrant", kAxisGrey);
  svg.Text(f.left + 8, f.top + f.h - 8, "LL", "start", "quadrant", kAxisGrey);
  svg.Text(f.left + f.w - 8, f.top + f.h - 8, "HL", "end", "quadrant", kAxisGrey);
  std::string dots = "<g stroke=\"#222222\" stroke-width=\"0.6\">";
  for (std::size_t i = 0; i < z.size() && i < lag_z.size(); i += std::max<std::size_t>(1, z.size() / 20000)) {
    const int k = i < clusters.size() ? clusters[i] : 0;
    dots += fmt::format("<circle cx=\"{}\" cy=\"{}\" r=\"2.6\" fill=\"{}\"/>", F(f.Px(z[i])), F(f.Py(lag_z[i])),
                        clusters.empty() ? kAxisGrey : HexOf(LisaColour(k)));
  }
  svg.Raw(dots + "</g>\n");
  const double x_end = std::abs(moran_i) > 1 ? range / std::abs(moran_i) : range;
  svg.Line(f.Px(-x_end), f.Py(-x_end * moran_i), f.Px(x_end), f.Py(x_end * moran_i), kLimitRed, 2);
  Axes(svg, f, "z (standardised deviation)", "spatial lag of z");
  return svg.Str();
}

std::string SvgBars(const std::vector<std::string>& labels, const std::vector<double>& values, double limit,
                    const std::string& limit_label, const std::string& y_label, const std::string& title) {
  const bool has_limit = std::isfinite(limit);
  double top_value = has_limit ? std::max(limit, 0.0) : 0.0;
  for (double v : values) top_value = std::max(top_value, v);
  const Frame f{70, 40, 460, 260, 0, 1, 0, top_value > 0 ? top_value * 1.2 : 1};
  Svg svg(560, f.top + f.h + 50, title);
  const std::vector<double> yt = NiceTicks(f.y_lo, f.y_hi, 5);
  const double step = yt.size() > 1 ? yt[1] - yt[0] : 1;
  for (double t : yt) {
    svg.Line(f.left, f.Py(t), f.left + f.w, f.Py(t), kGridGrey);
    svg.Line(f.left - 5, f.Py(t), f.left, f.Py(t), kInk);
    svg.Text(f.left - 8, f.Py(t) + 4, TickLabel(t, step), "end");
  }
  const double slot = f.w / std::max<std::size_t>(values.size(), 1);
  for (std::size_t i = 0; i < values.size(); ++i) {
    const double x0 = f.left + (i + 0.2) * slot, w = 0.6 * slot, y0 = f.Py(std::max(values[i], 0.0));
    svg.Rect(x0, y0, w, f.top + f.h - y0, !has_limit || values[i] <= limit ? "#4daf4a" : "#ff7f00");
    svg.Text(x0 + w / 2, y0 - 5, FormatFixed(values[i], 1), "middle");
    svg.Text(x0 + w / 2, f.top + f.h + 18, Esc(i < labels.size() ? labels[i] : ""), "middle");
  }
  if (has_limit) {
    svg.Line(f.left, f.Py(limit), f.left + f.w, f.Py(limit), kLimitRed, 1.5, true);
    svg.Text(f.left + f.w - 4, f.Py(limit) - 6, Esc(limit_label), "end", "", kLimitRed);
  }
  svg.Raw(fmt::format("<rect x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"{}\"/>\n", F(f.left),
                      F(f.top), F(f.w), F(f.h), kInk));
  svg.VerticalText(16, f.top + f.h / 2, Esc(y_label));
  return svg.Str();
}

}  // namespace formloop::app::report

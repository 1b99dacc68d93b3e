#include "app/report_charts.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/number_text.h"

namespace formloop::app {
namespace {

constexpr Rgb kInk = HexColour(0x222222);
constexpr Rgb kAxisGrey = HexColour(0x888888);
constexpr Rgb kGridGrey = HexColour(0xe6e6e6);
constexpr Rgb kMaskGrey = HexColour(0xf2f2f2);
constexpr Rgb kLimitRed = HexColour(0xd7191c);
constexpr int kTitleScale = 2;
constexpr int kLabelScale = 1;

// A rectangle of the canvas showing [x_lo, x_hi] × [y_lo, y_hi] in data units, y up.
struct Frame {
  int left = 0;
  int top = 0;
  int width = 1;
  int height = 1;
  double x_lo = 0, x_hi = 1, y_lo = 0, y_hi = 1;
  double Px(double x) const { return left + (x - x_lo) / (x_hi - x_lo) * width; }
  double Py(double y) const { return top + height - (y - y_lo) / (y_hi - y_lo) * height; }
  double X(double px) const { return x_lo + (px - left) / width * (x_hi - x_lo); }
  double Y(double py) const { return y_lo + (top + height - py) / height * (y_hi - y_lo); }
};

struct Bounds {
  double x_lo = 0, x_hi = 1, y_lo = 0, y_hi = 1;
};

Bounds BoundsOf(const std::vector<double>& x, const std::vector<double>& y) {
  if (x.empty()) return {};
  Bounds b{*std::min_element(x.begin(), x.end()), *std::max_element(x.begin(), x.end()),
           *std::min_element(y.begin(), y.end()), *std::max_element(y.begin(), y.end())};
  // A line of points still gets a visible frame.
  const double span = std::max({b.x_hi - b.x_lo, b.y_hi - b.y_lo, 1e-3});
  if (b.x_hi - b.x_lo < 1e-9 * span + 1e-12) b.x_lo -= span / 2, b.x_hi += span / 2;
  if (b.y_hi - b.y_lo < 1e-9 * span + 1e-12) b.y_lo -= span / 2, b.y_hi += span / 2;
  return b;
}

// The plot frame of a map: equal mm per pixel on both axes, at most max_w × max_h pixels.
Frame MapFrame(const Bounds& b, int left, int top, int max_w, int max_h) {
  const double px_per_mm = std::min(max_w / (b.x_hi - b.x_lo), max_h / (b.y_hi - b.y_lo));
  Frame f{left,
          top,
          std::max(1, static_cast<int>(std::lround((b.x_hi - b.x_lo) * px_per_mm))),
          std::max(1, static_cast<int>(std::lround((b.y_hi - b.y_lo) * px_per_mm))),
          b.x_lo,
          b.x_hi,
          b.y_lo,
          b.y_hi};
  return f;
}

// Frame outline, ticks with labels on the left and bottom, axis names.
void DrawAxes(Canvas& c, const Frame& f, const std::string& x_label, const std::string& y_label, int x_target = 6,
              int y_target = 5) {
  const std::vector<double> xt = NiceTicks(f.x_lo, f.x_hi, x_target);
  const std::vector<double> yt = NiceTicks(f.y_lo, f.y_hi, y_target);
  const double x_step = xt.size() > 1 ? xt[1] - xt[0] : 1;
  const double y_step = yt.size() > 1 ? yt[1] - yt[0] : 1;
  const int bottom = f.top + f.height;
  for (double t : xt) {
    const int px = static_cast<int>(std::lround(f.Px(t)));
    c.FillRect(px, bottom, px + 1, bottom + 5, kInk);
    c.Text(px, bottom + 8, TickLabel(t, x_step), kInk, kLabelScale, TextAlign::kCentre);
  }
  for (double t : yt) {
    const int py = static_cast<int>(std::lround(f.Py(t)));
    c.FillRect(f.left - 5, py, f.left, py + 1, kInk);
    c.Text(f.left - 8, py - 3, TickLabel(t, y_step), kInk, kLabelScale, TextAlign::kRight);
  }
  c.StrokeRect(f.left - 1, f.top - 1, f.left + f.width + 1, bottom + 1, kInk);
  c.Text(f.left + f.width / 2, bottom + 22, x_label, kInk, kLabelScale, TextAlign::kCentre);
  c.TextVertical(6, f.top + f.height / 2, y_label, kInk, kLabelScale);
}

// Median nearest-neighbour distance over (up to) 500 evenly chosen points: the probe spacing.
double PointSpacing(const std::vector<double>& x, const std::vector<double>& y) {
  const std::size_t n = x.size();
  if (n < 2) return 1;
  const std::size_t stride = std::max<std::size_t>(1, n / 500);
  std::vector<double> nearest;
  for (std::size_t i = 0; i < n; i += stride) {
    double best = std::numeric_limits<double>::infinity();
    for (std::size_t j = 0; j < n; ++j) {
      const double d = std::hypot(x[i] - x[j], y[i] - y[j]);
      if (j != i && d > 0) best = std::min(best, d);
    }
    if (std::isfinite(best)) nearest.push_back(best);
  }
  if (nearest.empty()) return 1;
  std::nth_element(nearest.begin(), nearest.begin() + static_cast<std::ptrdiff_t>(nearest.size() / 2), nearest.end());
  return nearest[nearest.size() / 2];
}

// Points bucketed on a square grid of cell `cell_mm`, for the radius queries of the map fill.
class PointGrid {
 public:
  PointGrid(const std::vector<double>& x, const std::vector<double>& y, const Bounds& b, double cell_mm)
      : x_(x), y_(y), b_(b), cell_(cell_mm) {
    nx_ = std::max(1, static_cast<int>(std::ceil((b.x_hi - b.x_lo) / cell_)) + 1);
    ny_ = std::max(1, static_cast<int>(std::ceil((b.y_hi - b.y_lo) / cell_)) + 1);
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
  int CellX(double x) const { return std::clamp(static_cast<int>(std::floor((x - b_.x_lo) / cell_)), 0, nx_ - 1); }
  int CellY(double y) const { return std::clamp(static_cast<int>(std::floor((y - b_.y_lo) / cell_)), 0, ny_ - 1); }
  std::size_t Cell(int i, int j) const { return static_cast<std::size_t>(j) * static_cast<std::size_t>(nx_) + i; }
  const std::vector<double>& x_;
  const std::vector<double>& y_;
  Bounds b_;
  double cell_;
  int nx_ = 1, ny_ = 1;
  std::vector<std::vector<std::size_t>> cells_;
};

void FillField(Canvas& c, const Frame& f, const std::vector<double>& x, const std::vector<double>& y,
               const std::vector<double>& values, double max_abs, const MapMask& inside) {
  // The cell is also kept above 1/1000 of the frame so that a few nearly coincident points cannot
  // make the bucket grid huge.
  const double cell_mm = std::max(1.5 * PointSpacing(x, y), std::max(f.x_hi - f.x_lo, f.y_hi - f.y_lo) / 1000);
  const PointGrid grid(x, y, Bounds{f.x_lo, f.x_hi, f.y_lo, f.y_hi}, cell_mm);
  for (int py = f.top; py < f.top + f.height; ++py) {
    for (int px = f.left; px < f.left + f.width; ++px) {
      const double dx = f.X(px + 0.5), dy = f.Y(py + 0.5);
      if (inside && !inside(dx, dy)) {
        c.Set(px, py, kMaskGrey);
        continue;
      }
      double sum_w = 0, sum_wv = 0;
      grid.ForNear(dx, dy, [&](std::size_t i, double d) {
        const double w = 1.0 / (d * d + 1e-12);  // the epsilon keeps a pixel on a point finite
        sum_w += w;
        sum_wv += w * values[i];
      });
      c.Set(px, py, sum_w > 0 ? DivergingColour(sum_wv / sum_w, max_abs) : kMaskGrey);
    }
  }
  const double dot_px = x.size() > 2000 ? 0.6 : 1.2;
  for (std::size_t i = 0; i < x.size(); ++i) c.Disc(f.Px(x[i]), f.Py(y[i]), dot_px, kInk);
}

// Horizontal colour bar centred at centre_x, ticks at nice values within ±max_abs.
void DrawColourBar(Canvas& c, int centre_x, int top, int width, double max_abs, const std::string& label) {
  const int left = centre_x - width / 2;
  const double range = max_abs > 0 ? max_abs : 1;
  for (int i = 0; i < width; ++i) {
    const double v = -range + 2 * range * (i + 0.5) / width;
    c.FillRect(left + i, top, left + i + 1, top + 14, DivergingColour(v, range));
  }
  c.StrokeRect(left - 1, top - 1, left + width + 1, top + 15, kInk);
  const std::vector<double> ticks = NiceTicks(-range, range, 5);
  const double step = ticks.size() > 1 ? ticks[1] - ticks[0] : 1;
  for (double t : ticks) {
    const int px = left + static_cast<int>(std::lround((t + range) / (2 * range) * width));
    c.FillRect(px, top + 14, px + 1, top + 19, kInk);
    c.Text(px, top + 22, TickLabel(t, step), kInk, kLabelScale, TextAlign::kCentre);
  }
  c.Text(centre_x, top + 36, label, kInk, kLabelScale, TextAlign::kCentre);
}

void DrawTitle(Canvas& c, const std::string& title) {
  c.Text(c.width() / 2, 8, title, kInk, kTitleScale, TextAlign::kCentre);
}

void NoData(Canvas& c, const Frame& f) {
  c.Text(f.left + f.width / 2, f.top + f.height / 2, "NO POINTS", kAxisGrey, 2, TextAlign::kCentre);
}

}  // namespace

std::vector<double> NiceTicks(double lo, double hi, int target) {
  if (!(hi > lo) || !std::isfinite(lo) || !std::isfinite(hi)) return {lo};
  const double raw = (hi - lo) / std::max(target, 1);
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  double step = magnitude;
  for (double m : {1.0, 2.0, 5.0, 10.0}) {
    step = m * magnitude;
    if (step >= raw) break;
  }
  std::vector<double> ticks;
  for (double t = std::ceil(lo / step - 1e-9) * step; t <= hi + 1e-9 * step; t += step) {
    ticks.push_back(std::abs(t) < 1e-9 * step ? 0.0 : t);
  }
  return ticks;
}

std::string TickLabel(double value, double step) {
  const int decimals = step > 0 ? std::max(0, static_cast<int>(std::ceil(-std::log10(step) - 1e-9))) : 2;
  return FormatFixed(value, decimals);
}

Canvas DrawFieldMap(const std::vector<double>& x_mm, const std::vector<double>& y_mm,
                    const std::vector<double>& values_um, double max_abs_um, const std::string& title,
                    const std::string& bar_label, const MapMask& inside) {
  const Frame f = MapFrame(BoundsOf(x_mm, y_mm), 70, 40, 480, 360);
  Canvas c(f.left + f.width + 40 < 600 ? 600 : f.left + f.width + 40, f.top + f.height + 110);
  DrawTitle(c, title);
  if (x_mm.empty()) {
    NoData(c, f);
  } else {
    FillField(c, f, x_mm, y_mm, values_um, max_abs_um, inside);
  }
  DrawAxes(c, f, "x (mm)", "y (mm)");
  DrawColourBar(c, c.width() / 2, f.top + f.height + 40, 360, max_abs_um, bar_label);
  return c;
}

Canvas DrawClusterMap(const std::vector<double>& x_mm, const std::vector<double>& y_mm,
                      const std::vector<int>& clusters, const std::string& title) {
  const Frame f = MapFrame(BoundsOf(x_mm, y_mm), 70, 40, 480, 360);
  Canvas c(f.left + f.width + 40 < 600 ? 600 : f.left + f.width + 40, f.top + f.height + 90);
  DrawTitle(c, title);
  if (x_mm.empty()) NoData(c, f);
  const double spacing_px = PointSpacing(x_mm, y_mm) * f.width / (f.x_hi - f.x_lo);
  const double radius_px = std::clamp(0.4 * spacing_px, 1.5, 8.0);
  std::vector<int> counts(kLisaClusterCount, 0);
  for (std::size_t i = 0; i < x_mm.size(); ++i) {
    const int k = i < clusters.size() ? clusters[i] : 0;
    if (k >= 0 && k < kLisaClusterCount) ++counts[static_cast<std::size_t>(k)];
    c.Disc(f.Px(x_mm[i]), f.Py(y_mm[i]), radius_px, LisaColour(k));
  }
  DrawAxes(c, f, "x (mm)", "y (mm)");
  // Legend: one swatch per cluster with its count, in one row under the axis name.
  int x = 20;
  const int y = f.top + f.height + 45;
  for (int k = 0; k < kLisaClusterCount; ++k) {
    const std::string text = std::string(LisaName(k)) + " " + std::to_string(counts[static_cast<std::size_t>(k)]);
    c.FillRect(x, y, x + 12, y + 12, LisaColour(k));
    c.StrokeRect(x, y, x + 12, y + 12, kAxisGrey);
    c.Text(x + 16, y + 3, text, kInk);
    x += 16 + Canvas::TextWidth(text) + 14;
  }
  return c;
}

Canvas DrawHistogram(const std::vector<HistogramSeries>& series, double tolerance_um, const std::string& title) {
  const bool has_tolerance = std::isfinite(tolerance_um);
  double lo = has_tolerance ? -std::abs(tolerance_um) : std::numeric_limits<double>::infinity();
  double hi = has_tolerance ? std::abs(tolerance_um) : -std::numeric_limits<double>::infinity();
  for (const HistogramSeries& s : series) {
    for (double v : s.values_um) lo = std::min(lo, v), hi = std::max(hi, v);
  }
  if (!(hi > lo)) lo = -1, hi = 1;
  const double pad = 0.05 * (hi - lo);
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
  Frame f{70, 40, 480, 300, lo, hi, 0, max_count * 1.1};
  Canvas c(600, f.top + f.height + 70);
  DrawTitle(c, title);
  const double bin_px = static_cast<double>(f.width) / kBins;
  const double bar_px = bin_px / std::max<std::size_t>(series.size(), 1);
  for (std::size_t s = 0; s < series.size(); ++s) {
    for (int b = 0; b < kBins; ++b) {
      const int x0 = static_cast<int>(std::lround(f.left + b * bin_px + s * bar_px));
      const int x1 = static_cast<int>(std::lround(f.left + b * bin_px + (s + 1) * bar_px));
      const int y0 = static_cast<int>(std::lround(f.Py(counts[s][static_cast<std::size_t>(b)])));
      c.FillRect(x0, y0, std::max(x0 + 1, x1 - 1), f.top + f.height, series[s].colour);
    }
  }
  for (double t : {-std::abs(tolerance_um), std::abs(tolerance_um)}) {
    if (!has_tolerance) break;
    c.Line(f.Px(t), f.top, f.Px(t), f.top + f.height, kLimitRed, 2, 5);
    c.Text(static_cast<int>(f.Px(t)) + (t < 0 ? -4 : 4), f.top + 4, t < 0 ? "-TOL" : "+TOL", kLimitRed, 1,
           t < 0 ? TextAlign::kRight : TextAlign::kLeft);
  }
  DrawAxes(c, f, "DEVIATION (µm)", "POINTS");
  for (std::size_t s = 0; s < series.size(); ++s) {       // legend, top right inside the frame
    const int y = f.top + 24 + static_cast<int>(s) * 14;  // below the ±TOL labels
    c.FillRect(f.left + f.width - 80, y, f.left + f.width - 70, y + 10, series[s].colour);
    c.Text(f.left + f.width - 64, y + 2, series[s].label, kInk);
  }
  return c;
}

Canvas DrawMoranScatter(const std::vector<double>& z, const std::vector<double>& lag_z,
                        const std::vector<int>& clusters, double moran_i, const std::string& title) {
  double range = 1;
  for (std::size_t i = 0; i < z.size(); ++i) range = std::max({range, std::abs(z[i]), std::abs(lag_z[i])});
  range *= 1.1;
  Frame f{70, 40, 400, 400, -range, range, -range, range};
  Canvas c(520, f.top + f.height + 60);
  DrawTitle(c, title);
  for (double t : NiceTicks(-range, range, 6)) {  // light grid
    c.Line(f.Px(t), f.top, f.Px(t), f.top + f.height, kGridGrey);
    c.Line(f.left, f.Py(t), f.left + f.width, f.Py(t), kGridGrey);
  }
  c.Line(f.Px(0), f.top, f.Px(0), f.top + f.height, kAxisGrey);
  c.Line(f.left, f.Py(0), f.left + f.width, f.Py(0), kAxisGrey);
  c.Text(f.left + f.width - 6, f.top + 6, "HH", kAxisGrey, 2, TextAlign::kRight);
  c.Text(f.left + 6, f.top + 6, "LH", kAxisGrey, 2);
  c.Text(f.left + 6, f.top + f.height - 20, "LL", kAxisGrey, 2);
  c.Text(f.left + f.width - 6, f.top + f.height - 20, "HL", kAxisGrey, 2, TextAlign::kRight);
  for (std::size_t i = 0; i < z.size(); ++i) {
    const int k = i < clusters.size() ? clusters[i] : 0;
    const Rgb fill = clusters.empty() ? kAxisGrey : LisaColour(k);
    c.Disc(f.Px(z[i]), f.Py(lag_z[i]), 3.2, kInk);
    c.Disc(f.Px(z[i]), f.Py(lag_z[i]), 2.2, fill);
  }
  // The line y = I x, clipped to the square.
  const double x_end = std::abs(moran_i) > 1 ? range / std::abs(moran_i) : range;
  c.Line(f.Px(-x_end), f.Py(-x_end * moran_i), f.Px(x_end), f.Py(x_end * moran_i), kLimitRed, 2);
  DrawAxes(c, f, "z = STANDARDISED DEVIATION", "SPATIAL LAG OF z");
  return c;
}

Canvas DrawBars(const std::vector<std::string>& labels, const std::vector<double>& values, double limit,
                const std::string& limit_label, const std::string& y_label, const std::string& title) {
  const bool has_limit = std::isfinite(limit);
  double top_value = has_limit ? std::max(limit, 0.0) : 0.0;
  for (double v : values) top_value = std::max(top_value, v);
  Frame f{70, 40, 480, 280, 0, 1, 0, top_value > 0 ? top_value * 1.15 : 1};
  Canvas c(600, f.top + f.height + 50);
  DrawTitle(c, title);
  const std::vector<double> yt = NiceTicks(f.y_lo, f.y_hi, 5);
  for (double t : yt) c.Line(f.left, f.Py(t), f.left + f.width, f.Py(t), kGridGrey);
  const double slot_px = static_cast<double>(f.width) / std::max<std::size_t>(values.size(), 1);
  const double step = yt.size() > 1 ? yt[1] - yt[0] : 1;
  for (std::size_t i = 0; i < values.size(); ++i) {
    const int x0 = static_cast<int>(std::lround(f.left + (i + 0.2) * slot_px));
    const int x1 = static_cast<int>(std::lround(f.left + (i + 0.8) * slot_px));
    const int y0 = static_cast<int>(std::lround(f.Py(std::max(values[i], 0.0))));
    c.FillRect(x0, y0, x1, f.top + f.height,
               !has_limit || values[i] <= limit ? HexColour(0x4daf4a) : HexColour(0xff7f00));
    c.Text((x0 + x1) / 2, y0 - 11, FormatFixed(values[i], 1), kInk, 1, TextAlign::kCentre);
    c.Text((x0 + x1) / 2, f.top + f.height + 8, i < labels.size() ? labels[i] : "", kInk, 1, TextAlign::kCentre);
  }
  if (has_limit) {
    c.Line(f.left, f.Py(limit), f.left + f.width, f.Py(limit), kLimitRed, 2, 6);
    c.Text(f.left + f.width - 4, static_cast<int>(f.Py(limit)) - 11, limit_label, kLimitRed, 1, TextAlign::kRight);
  }
  // Left axis only: the categories are labelled under the bars.
  for (double t : yt) {
    const int py = static_cast<int>(std::lround(f.Py(t)));
    c.FillRect(f.left - 5, py, f.left, py + 1, kInk);
    c.Text(f.left - 8, py - 3, TickLabel(t, step), kInk, 1, TextAlign::kRight);
  }
  c.StrokeRect(f.left - 1, f.top - 1, f.left + f.width + 1, f.top + f.height + 1, kInk);
  c.TextVertical(6, f.top + f.height / 2, y_label, kInk);
  return c;
}

Canvas DrawTimePanels(const std::vector<TimePanel>& panels, const std::string& title) {
  constexpr int kLeft = 80, kWidth = 820, kPanelHeight = 220, kGap = 60, kTop = 40;
  const int count = static_cast<int>(panels.size());
  Canvas c(kLeft + kWidth + 30, kTop + count * (kPanelHeight + kGap));
  DrawTitle(c, title);
  double t_hi = 0;
  for (const TimePanel& p : panels) {
    for (const TimeSeries& s : p.series) {
      if (!s.t_s.empty()) t_hi = std::max(t_hi, *std::max_element(s.t_s.begin(), s.t_s.end()));
    }
  }
  if (t_hi <= 0) t_hi = 1;
  for (int k = 0; k < count; ++k) {
    const TimePanel& p = panels[static_cast<std::size_t>(k)];
    double y_hi = 0;
    for (const TimeSeries& s : p.series) {
      for (double v : s.values) y_hi = std::max(y_hi, v);
    }
    for (const LevelLine& l : p.levels) y_hi = std::max(y_hi, l.value);
    const Frame f{kLeft, kTop + k * (kPanelHeight + kGap), kWidth, kPanelHeight, 0, t_hi, 0, y_hi > 0 ? y_hi * 1.1 : 1};
    for (double t : NiceTicks(f.y_lo, f.y_hi, 5)) c.Line(f.left, f.Py(t), f.left + f.width, f.Py(t), kGridGrey);
    for (const TimeSeries& s : p.series) {
      for (std::size_t i = 1; i < s.t_s.size() && i < s.values.size(); ++i) {
        c.Line(f.Px(s.t_s[i - 1]), f.Py(s.values[i - 1]), f.Px(s.t_s[i]), f.Py(s.values[i]), s.colour);
      }
    }
    for (const LevelLine& l : p.levels) {
      c.Line(f.left, f.Py(l.value), f.left + f.width, f.Py(l.value), l.colour, 1, 6);
      c.Text(f.left + f.width - 4, static_cast<int>(f.Py(l.value)) - 10, l.label, l.colour, 1, TextAlign::kRight);
    }
    int legend_x = f.left + 6;
    for (const TimeSeries& s : p.series) {
      c.FillRect(legend_x, f.top + 6, legend_x + 14, f.top + 9, s.colour);
      c.Text(legend_x + 18, f.top + 4, s.label, kInk);
      legend_x += 18 + Canvas::TextWidth(s.label) + 16;
    }
    DrawAxes(c, f, "time (s)", p.y_label, 10, 5);
  }
  return c;
}

}  // namespace formloop::app

#include "app/report_charts.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/number_text.h"

namespace formloop::app {
namespace {

constexpr Rgb kInk = HexColour(0x222222);
constexpr Rgb kGridGrey = HexColour(0xe6e6e6);
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

void DrawTitle(Canvas& c, const std::string& title) {
  c.Text(c.width() / 2, 8, title, kInk, kTitleScale, TextAlign::kCentre);
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

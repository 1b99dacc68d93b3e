#pragma once
// A small RGB raster for the pictures of the run report (app/report.h), with an embedded 5 × 7
// bitmap font, the report's colour maps, PNG encoding (libpng) and base64 for data: URIs.
//
// The report must be one self-contained HTML file that opens without a network and looks the same
// on every machine, so pictures are drawn here pixel by pixel (no plotting library, no system
// fonts) and every label is part of the picture. Coordinates are pixels, origin top-left, x to the
// right, y down.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "core/status.h"

namespace formloop::app {

struct Rgb {
  std::uint8_t r = 0;
  std::uint8_t g = 0;
  std::uint8_t b = 0;
  bool operator==(const Rgb&) const = default;
};

// 0xRRGGBB -> Rgb.
constexpr Rgb HexColour(std::uint32_t hex) {
  return Rgb{static_cast<std::uint8_t>(hex >> 16), static_cast<std::uint8_t>(hex >> 8), static_cast<std::uint8_t>(hex)};
}

enum class TextAlign { kLeft, kCentre, kRight };

class Canvas {
 public:
  Canvas(int width_px, int height_px, Rgb background = HexColour(0xffffff));

  int width() const { return width_; }
  int height() const { return height_; }
  // Row-major RGB bytes, 3 × width × height.
  const std::vector<std::uint8_t>& pixels() const { return pixels_; }

  // Pixels outside the canvas are ignored by every drawing call.
  void Set(int x, int y, Rgb colour);
  Rgb Get(int x, int y) const;
  // Fills [x0, x1) × [y0, y1).
  void FillRect(int x0, int y0, int x1, int y1, Rgb colour);
  // Outline of [x0, x1) × [y0, y1), one pixel wide.
  void StrokeRect(int x0, int y0, int x1, int y1, Rgb colour);
  // A straight line of `thickness_px` square pen; dash_px > 0 draws dash_px on, dash_px off.
  void Line(double x0, double y0, double x1, double y1, Rgb colour, int thickness_px = 1, int dash_px = 0);
  // A filled disc centred on (cx, cy).
  void Disc(double cx, double cy, double radius_px, Rgb colour);
  // Text in the 5 × 7 font, each font pixel a scale × scale block; y is the top of the text. Upper-case
  // letters, digits, "- . + : / ( ) = , % | < >", space, lower-case m x y z and "µ" (UTF-8) have glyphs;
  // other lower-case letters are drawn upper-case, anything else as a box.
  void Text(int x, int y, std::string_view text, Rgb colour, int scale = 1, TextAlign align = TextAlign::kLeft);
  // Text turned 90° anticlockwise (reads bottom to top), centred vertically on y, left edge at x.
  void TextVertical(int x, int y, std::string_view text, Rgb colour, int scale = 1);
  // Width in pixels of Text(text, scale): 6 × scale per character minus the last gap.
  static int TextWidth(std::string_view text, int scale = 1);
  static int TextHeight(int scale = 1) { return 7 * scale; }

 private:
  int width_;
  int height_;
  std::vector<std::uint8_t> pixels_;
};

// Diverging blue–white–red map symmetric about 0: -max_abs is blue (#2166ac), 0 white, +max_abs red
// (#b2182b); values beyond ±max_abs are clamped. A deviation is positive where material is left
// (docs/ARCHITECTURE.md), so red means "too much material".
Rgb DivergingColour(double value, double max_abs);

// LISA clusters (Anselin 1995) as written in deviations.csv's `lisa` column: 0 not significant, 1 HH,
// 2 LH, 3 LL, 4 HL, 5 island. Colours follow the usual GeoDa palette.
inline constexpr int kLisaClusterCount = 6;
Rgb LisaColour(int cluster);
// "not significant", "HH", "LH", "LL", "HL", "island"; "unknown" outside 0..5.
const char* LisaName(int cluster);

// PNG (8-bit RGB, no ancillary chunks, so the bytes depend only on the pixels). Internal error when
// libpng fails.
Result<std::string> EncodePng(const Canvas& canvas);
// RFC 4648 base64 with padding, no line breaks.
std::string Base64(std::string_view bytes);

}  // namespace formloop::app

#include "app/report_image.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <csetjmp>

#include <png.h>

namespace formloop::app {
namespace {

// One glyph: 7 rows of 5 bits, the most significant of the 5 is the leftmost pixel.
using Glyph = std::array<std::uint8_t, 7>;

struct FontEntry {
  char32_t code;
  Glyph rows;
};

// Drawn for this file; shapes follow the classic 5 × 7 dot-matrix character sets.
constexpr FontEntry kFont[] = {
    {U'0', {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E}}, {U'1', {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E}},
    {U'2', {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F}}, {U'3', {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E}},
    {U'4', {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02}}, {U'5', {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E}},
    {U'6', {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E}}, {U'7', {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08}},
    {U'8', {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E}}, {U'9', {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C}},
    {U'A', {0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11}}, {U'B', {0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E}},
    {U'C', {0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E}}, {U'D', {0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C}},
    {U'E', {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F}}, {U'F', {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10}},
    {U'G', {0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F}}, {U'H', {0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11}},
    {U'I', {0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E}}, {U'J', {0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C}},
    {U'K', {0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11}}, {U'L', {0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F}},
    {U'M', {0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11}}, {U'N', {0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11}},
    {U'O', {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}}, {U'P', {0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10}},
    {U'Q', {0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D}}, {U'R', {0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11}},
    {U'S', {0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E}}, {U'T', {0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04}},
    {U'U', {0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}}, {U'V', {0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04}},
    {U'W', {0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A}}, {U'X', {0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11}},
    {U'Y', {0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04}}, {U'Z', {0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F}},
    {U'm', {0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11}}, {U'x', {0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11}},
    {U'y', {0x00, 0x00, 0x11, 0x11, 0x0F, 0x01, 0x0E}}, {U'z', {0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F}},
    {U'µ', {0x00, 0x11, 0x11, 0x11, 0x13, 0x1D, 0x10}}, {U' ', {0, 0, 0, 0, 0, 0, 0}},
    {U'-', {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00}}, {U'.', {0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C}},
    {U'+', {0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00}}, {U':', {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00}},
    {U'/', {0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00}}, {U'(', {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02}},
    {U')', {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08}}, {U'=', {0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00}},
    {U',', {0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08}}, {U'%', {0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03}},
    {U'|', {0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04}}, {U'<', {0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02}},
    {U'>', {0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08}},
};

constexpr Glyph kUnknownGlyph = {0x1F, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1F};

const Glyph& GlyphFor(char32_t code) {
  for (const FontEntry& e : kFont) {
    if (e.code == code) return e.rows;
  }
  if (code >= U'a' && code <= U'z') return GlyphFor(code - U'a' + U'A');
  return kUnknownGlyph;
}

// Decodes the UTF-8 the report uses (ASCII and two-byte sequences such as "µ"); a stray byte is
// returned as itself and drawn as the unknown box.
std::vector<char32_t> DecodeUtf8(std::string_view text) {
  std::vector<char32_t> codes;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    if ((c & 0xE0) == 0xC0 && i + 1 < text.size()) {
      codes.push_back(static_cast<char32_t>(((c & 0x1F) << 6) | (static_cast<unsigned char>(text[i + 1]) & 0x3F)));
      ++i;
    } else {
      codes.push_back(c);
    }
  }
  return codes;
}

Rgb Mix(Rgb a, Rgb b, double t) {
  auto channel = [t](std::uint8_t x, std::uint8_t y) {
    return static_cast<std::uint8_t>(std::lround(x + (static_cast<double>(y) - x) * t));
  };
  return Rgb{channel(a.r, b.r), channel(a.g, b.g), channel(a.b, b.b)};
}

void AppendPngBytes(png_structp png, png_bytep data, png_size_t length) {
  auto* out = static_cast<std::string*>(png_get_io_ptr(png));
  out->append(reinterpret_cast<const char*>(data), length);
}

}  // namespace

Canvas::Canvas(int width_px, int height_px, Rgb background)
    : width_(std::max(width_px, 1)), height_(std::max(height_px, 1)) {
  pixels_.resize(static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_) * 3);
  FillRect(0, 0, width_, height_, background);
}

void Canvas::Set(int x, int y, Rgb colour) {
  if (x < 0 || y < 0 || x >= width_ || y >= height_) return;
  const std::size_t at =
      (static_cast<std::size_t>(y) * static_cast<std::size_t>(width_) + static_cast<std::size_t>(x)) * 3;
  pixels_[at] = colour.r;
  pixels_[at + 1] = colour.g;
  pixels_[at + 2] = colour.b;
}

Rgb Canvas::Get(int x, int y) const {
  if (x < 0 || y < 0 || x >= width_ || y >= height_) return {};
  const std::size_t at =
      (static_cast<std::size_t>(y) * static_cast<std::size_t>(width_) + static_cast<std::size_t>(x)) * 3;
  return Rgb{pixels_[at], pixels_[at + 1], pixels_[at + 2]};
}

void Canvas::FillRect(int x0, int y0, int x1, int y1, Rgb colour) {
  for (int y = std::max(y0, 0); y < std::min(y1, height_); ++y) {
    for (int x = std::max(x0, 0); x < std::min(x1, width_); ++x) Set(x, y, colour);
  }
}

void Canvas::StrokeRect(int x0, int y0, int x1, int y1, Rgb colour) {
  FillRect(x0, y0, x1, y0 + 1, colour);
  FillRect(x0, y1 - 1, x1, y1, colour);
  FillRect(x0, y0, x0 + 1, y1, colour);
  FillRect(x1 - 1, y0, x1, y1, colour);
}

void Canvas::Line(double x0, double y0, double x1, double y1, Rgb colour, int thickness_px, int dash_px) {
  // Sampling at half-pixel steps is plenty for report graphics and keeps dashes simple.
  const double length = std::hypot(x1 - x0, y1 - y0);
  const int steps = std::max(1, static_cast<int>(std::ceil(length * 2)));
  const int half = (std::max(thickness_px, 1) - 1) / 2;
  for (int s = 0; s <= steps; ++s) {
    const double t = static_cast<double>(s) / steps;
    if (dash_px > 0 && static_cast<int>(t * length / dash_px) % 2 == 1) continue;
    const int x = static_cast<int>(std::lround(x0 + (x1 - x0) * t));
    const int y = static_cast<int>(std::lround(y0 + (y1 - y0) * t));
    FillRect(x - half, y - half, x - half + std::max(thickness_px, 1), y - half + std::max(thickness_px, 1), colour);
  }
}

void Canvas::Disc(double cx, double cy, double radius_px, Rgb colour) {
  const int r = static_cast<int>(std::ceil(radius_px));
  const int x_c = static_cast<int>(std::lround(cx));
  const int y_c = static_cast<int>(std::lround(cy));
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx) {
      if (dx * dx + dy * dy <= radius_px * radius_px + 0.25) Set(x_c + dx, y_c + dy, colour);
    }
  }
}

int Canvas::TextWidth(std::string_view text, int scale) {
  const int n = static_cast<int>(DecodeUtf8(text).size());
  return n == 0 ? 0 : (6 * n - 1) * scale;
}

void Canvas::Text(int x, int y, std::string_view text, Rgb colour, int scale, TextAlign align) {
  if (align == TextAlign::kCentre) x -= TextWidth(text, scale) / 2;
  if (align == TextAlign::kRight) x -= TextWidth(text, scale);
  for (char32_t code : DecodeUtf8(text)) {
    const Glyph& glyph = GlyphFor(code);
    for (int row = 0; row < 7; ++row) {
      for (int col = 0; col < 5; ++col) {
        if ((glyph[static_cast<std::size_t>(row)] >> (4 - col)) & 1) {
          FillRect(x + col * scale, y + row * scale, x + (col + 1) * scale, y + (row + 1) * scale, colour);
        }
      }
    }
    x += 6 * scale;
  }
}

void Canvas::TextVertical(int x, int y, std::string_view text, Rgb colour, int scale) {
  // Font row r becomes column x + r; font column c of character k runs upwards from the bottom end.
  int bottom = y + TextWidth(text, scale) / 2;
  for (char32_t code : DecodeUtf8(text)) {
    const Glyph& glyph = GlyphFor(code);
    for (int row = 0; row < 7; ++row) {
      for (int col = 0; col < 5; ++col) {
        if ((glyph[static_cast<std::size_t>(row)] >> (4 - col)) & 1) {
          FillRect(x + row * scale, bottom - (col + 1) * scale, x + (row + 1) * scale, bottom - col * scale, colour);
        }
      }
    }
    bottom -= 6 * scale;
  }
}

Rgb DivergingColour(double value, double max_abs) {
  constexpr Rgb kBlue = HexColour(0x2166ac);
  constexpr Rgb kWhite = HexColour(0xf7f7f7);
  constexpr Rgb kRed = HexColour(0xb2182b);
  if (!(max_abs > 0) || !std::isfinite(value)) return kWhite;
  const double t = std::clamp(value / max_abs, -1.0, 1.0);
  return t < 0 ? Mix(kWhite, kBlue, -t) : Mix(kWhite, kRed, t);
}

Rgb LisaColour(int cluster) {
  switch (cluster) {
    case 1:
      return HexColour(0xd7191c);  // HH
    case 2:
      return HexColour(0xabd9e9);  // LH
    case 3:
      return HexColour(0x2c7bb6);  // LL
    case 4:
      return HexColour(0xfdae61);  // HL
    case 5:
      return HexColour(0x555555);  // island (no neighbours)
    default:
      return HexColour(0xd9d9d9);  // not significant
  }
}

const char* LisaName(int cluster) {
  static constexpr const char* kNames[] = {"not significant", "HH", "LH", "LL", "HL", "island"};
  return cluster >= 0 && cluster < kLisaClusterCount ? kNames[cluster] : "unknown";
}

Result<std::string> EncodePng(const Canvas& canvas) {
  std::string out;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  if (png == nullptr) return Status::Internal("png: png_create_write_struct failed");
  png_infop info = png_create_info_struct(png);
  if (info == nullptr) {
    png_destroy_write_struct(&png, nullptr);
    return Status::Internal("png: png_create_info_struct failed");
  }
  // libpng reports errors by longjmp; nothing with a destructor is created between here and the end.
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return Status::Internal("png: libpng failed while encoding the image");
  }
  png_set_write_fn(png, &out, AppendPngBytes, nullptr);
  png_set_IHDR(png, info, static_cast<png_uint_32>(canvas.width()), static_cast<png_uint_32>(canvas.height()), 8,
               PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  const auto stride = static_cast<std::size_t>(canvas.width()) * 3;
  for (int y = 0; y < canvas.height(); ++y) {
    // libpng's row pointer is non-const but the write path does not modify it.
    auto* row = const_cast<png_bytep>(canvas.pixels().data() + static_cast<std::size_t>(y) * stride);
    png_write_row(png, row);
  }
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return out;
}

std::string Base64(std::string_view bytes) {
  static constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  for (std::size_t i = 0; i < bytes.size(); i += 3) {
    const std::size_t n = std::min<std::size_t>(3, bytes.size() - i);
    std::uint32_t group = 0;
    for (std::size_t k = 0; k < 3; ++k) {
      group = (group << 8) | (k < n ? static_cast<unsigned char>(bytes[i + k]) : 0u);
    }
    for (std::size_t k = 0; k < 4; ++k) {
      out.push_back(k <= n ? kAlphabet[(group >> (18 - 6 * k)) & 0x3F] : '=');
    }
  }
  return out;
}

}  // namespace formloop::app

#include "cnc/transport.h"

#include <charconv>

namespace formloop::cnc {

std::string OffsetAddress::ToString() const {
  switch (kind) {
    case OffsetKind::kToolRadiusWear:
      return "T" + std::to_string(tool) + ".radius_wear";
    case OffsetKind::kToolLengthWear:
      return "T" + std::to_string(tool) + ".length_wear";
    case OffsetKind::kWorkOffset:
      return wcs + "." + std::string(1, "XYZ"[axis < 0 || axis > 2 ? 0 : axis]);
  }
  return "?";
}

Result<OffsetAddress> ParseOffsetAddress(const std::string& text) {
  const auto dot = text.find('.');
  const auto bad = [&] {
    return Status::BadInput("offset '" + text +
                            "' is not T<tool>.radius_wear, T<tool>.length_wear or G54..G59.<X|Y|Z>");
  };
  if (dot == std::string::npos) return bad();
  const std::string head = text.substr(0, dot), tail = text.substr(dot + 1);
  OffsetAddress a;
  if (head.size() >= 2 && head[0] == 'T') {
    int tool = 0;
    const auto [p, ec] = std::from_chars(head.data() + 1, head.data() + head.size(), tool);
    if (ec != std::errc() || p != head.data() + head.size() || tool < 1 || tool > 9999) return bad();
    a.tool = tool;
    if (tail == "radius_wear") {
      a.kind = OffsetKind::kToolRadiusWear;
    } else if (tail == "length_wear") {
      a.kind = OffsetKind::kToolLengthWear;
    } else {
      return bad();
    }
    return a;
  }
  if (head.size() == 3 && head[0] == 'G' && head[1] == '5' && head[2] >= '4' && head[2] <= '9' && tail.size() == 1 &&
      tail[0] >= 'X' && tail[0] <= 'Z') {
    a.kind = OffsetKind::kWorkOffset;
    a.wcs = head;
    a.axis = tail[0] - 'X';
    return a;
  }
  return bad();
}

}  // namespace formloop::cnc

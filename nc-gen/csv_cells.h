#pragma once
// Internal to nc-gen: the cells of one line of formloop's small CSV files (side files, deviation
// fields), trimmed; a trailing comma gives a last empty cell so column counts stay honest.

#include <sstream>
#include <string>
#include <vector>

namespace formloop::nc::internal {

inline std::string TrimCell(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r");
  return s.substr(b, e - b + 1);
}

inline std::vector<std::string> SplitComma(const std::string& line) {
  std::vector<std::string> cells;
  std::string cell;
  std::istringstream in(line);
  while (std::getline(in, cell, ',')) cells.push_back(TrimCell(cell));
  if (!line.empty() && line.back() == ',') cells.emplace_back();
  return cells;
}

}  // namespace formloop::nc::internal

#include "core/csv.h"

#include <algorithm>
#include <cmath>

#include "core/atomic_file.h"
#include "core/number_text.h"

namespace formloop {

std::string_view TrimBlanks(std::string_view text) {
  const auto begin = text.find_first_not_of(" \t\r");
  if (begin == std::string_view::npos) return {};
  const auto end = text.find_last_not_of(" \t\r");
  return text.substr(begin, end - begin + 1);
}

bool TextLines::Next(std::string_view* line) {
  if (pos_ == 0 && line_number_ == 0 && text_.substr(0, 3) == "\xEF\xBB\xBF") pos_ = 3;  // UTF-8 byte-order mark
  if (pos_ >= text_.size()) return false;
  const std::size_t end = text_.find('\n', pos_);
  const std::size_t stop = end == std::string_view::npos ? text_.size() : end;
  std::string_view out = text_.substr(pos_, stop - pos_);
  if (!out.empty() && out.back() == '\r') out.remove_suffix(1);
  pos_ = end == std::string_view::npos ? text_.size() : end + 1;
  ++line_number_;
  *line = out;
  return true;
}

bool TextLines::NextContent(std::string_view* line) {
  while (Next(line)) {
    const std::string_view trimmed = TrimBlanks(*line);
    if (!trimmed.empty() && trimmed.front() != '#') return true;
  }
  return false;
}

void SplitCsvCells(std::string_view line, std::vector<std::string_view>* cells, char separator) {
  cells->clear();
  std::size_t start = 0;
  while (true) {
    const std::size_t end = line.find(separator, start);
    std::string_view cell = TrimBlanks(line.substr(start, end == std::string_view::npos ? end : end - start));
    if (cell.size() >= 2 && cell.front() == '"' && cell.back() == '"') cell = cell.substr(1, cell.size() - 2);
    cells->push_back(cell);
    if (end == std::string_view::npos) return;
    start = end + 1;
  }
}

Status CheckText(std::string_view text, const std::string& source) {
  const std::size_t nul = text.find('\0');
  if (nul == std::string_view::npos) return Status::Ok();
  std::string encoding = "binary data, not text";
  if (text.substr(0, 4) == std::string_view("\xFF\xFE\0\0", 4) ||
      text.substr(0, 4) == std::string_view("\0\0\xFE\xFF", 4)) {
    encoding = "UTF-32 text";
  } else if (text.substr(0, 2) == "\xFF\xFE" || text.substr(0, 2) == "\xFE\xFF" ||
             (text.size() >= 2 && (text[0] == '\0' || text[1] == '\0'))) {
    encoding = "UTF-16 text (\"Unicode text\" in spreadsheets)";
  }
  const long line = 1 + static_cast<long>(std::count(text.begin(), text.begin() + static_cast<long>(nul), '\n'));
  return Status::BadInput(Where{.file = source, .line = line}, "the file is " + encoding + ": it holds NUL bytes",
                          "save it as \"CSV UTF-8\" (or plain ASCII text)");
}

Result<std::string> ReadTextFile(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(std::string text, ReadFile(path));
  FL_RETURN_IF_ERROR(CheckText(text, path.string()));
  return text;
}

std::string RaggedRowFix(char separator, std::size_t cells, std::size_t header_cells) {
  std::string fix = std::string("give every row one cell per header column, separated by '") + separator + "'";
  if (separator == ',' && cells > header_cells) {
    fix += "; if the numbers are written with a decimal comma, separate the cells with ';' (header included)";
  }
  return fix;
}

bool CsvReader::Next() {
  std::string_view raw;
  while (lines_.Next(&raw)) {
    const std::string_view trimmed = TrimBlanks(raw);
    if (trimmed.empty()) continue;
    comment_ = trimmed.front() == '#';
    if (comment_ && !comments_) continue;
    line_ = trimmed;
    if (comment_) {
      cells_.clear();
      return true;
    }
    if (!header_seen_) {
      header_seen_ = true;
      if (trimmed.find(';') != std::string_view::npos && trimmed.find(',') == std::string_view::npos) separator_ = ';';
    }
    SplitCsvCells(trimmed, &cells_, separator_);
    if (separator_ == ';') {
      // Decimal commas become points; the cells then view into decimal_points_ (filled before any view).
      decimal_points_.assign(cells_.begin(), cells_.end());
      for (std::size_t c = 0; c < cells_.size(); ++c) {
        std::string& cell = decimal_points_[c];
        if (cell.find(',') == std::string::npos) continue;
        std::replace(cell.begin(), cell.end(), ',', '.');
      }
      for (std::size_t c = 0; c < cells_.size(); ++c) cells_[c] = decimal_points_[c];
    }
    return true;
  }
  return false;
}

int CsvTable::Find(std::string_view name) const {
  for (std::size_t c = 0; c < header.size(); ++c) {
    if (header[c] == name) return static_cast<int>(c);
  }
  return -1;
}

Result<int> CsvTable::Column(std::string_view name, const std::string& field) const {
  const int c = Find(name);
  if (c >= 0) return c;
  std::string names;
  for (std::size_t k = 0; k < header.size(); ++k) names += (k ? ", " : "") + header[k];
  return Status::BadInput(Where{.file = source, .line = header_line, .field = field},
                          "no column '" + std::string(name) + "' in the header (columns: " + names + ")",
                          "name one of the columns, spelled as in the header");
}

Status CsvTable::Number(std::size_t row, int column, double* value) const {
  const std::string& cell = rows[row][static_cast<std::size_t>(column)];
  if (ParseDouble(cell, value) && std::isfinite(*value)) return Status::Ok();
  if (NumberBeyondDoubleRange(cell)) {
    return Status::BadInput(
        Where{.file = source, .line = lines[row], .field = header[static_cast<std::size_t>(column)]},
        "'" + cell + "' is beyond the range of a double (1e-308 to 1e308)", "check the value and its unit");
  }
  return Status::BadInput(Where{.file = source, .line = lines[row], .field = header[static_cast<std::size_t>(column)]},
                          "'" + cell + "' is not a finite number",
                          "write a decimal number such as 1.25 (no empty cells, NaN or units)");
}

Result<CsvTable> ParseCsvTable(std::string_view text, const std::string& source, bool require_rows) {
  CsvTable t;
  t.source = source;
  CsvReader reader(text, /*comments=*/true);
  while (reader.Next()) {
    const long line = reader.line_number();
    if (reader.is_comment()) {
      t.comments.emplace_back(line, std::string(reader.line()));
      continue;
    }
    const std::vector<std::string_view>& cells = reader.cells();
    if (t.header_line == 0) {
      t.header_line = line;
      t.header_text = std::string(reader.line());
      for (std::size_t c = 0; c < cells.size(); ++c) {
        if (cells[c].empty()) {
          return Status::BadInput(Where{.file = source, .line = line},
                                  "header column " + std::to_string(c + 1) + " has no name",
                                  "name every column in the first row");
        }
        t.header.emplace_back(cells[c]);
      }
      continue;
    }
    if (cells.size() != t.header.size()) {
      return Status::BadInput(
          Where{.file = source, .line = line},
          "row has " + std::to_string(cells.size()) + " cells, the header " + std::to_string(t.header.size()),
          RaggedRowFix(reader.separator(), cells.size(), t.header.size()));
    }
    t.rows.emplace_back(cells.begin(), cells.end());
    t.lines.push_back(line);
  }
  if (require_rows && (t.header.empty() || t.rows.empty())) {
    return Status::BadInput(Where{.file = source}, "no header row or no data rows",
                            "write a header row naming the columns, then one row per point");
  }
  return t;
}

Result<CsvTable> ReadCsvTable(const std::filesystem::path& path, bool require_rows) {
  FL_ASSIGN_OR_RETURN(const std::string text, ReadTextFile(path));
  return ParseCsvTable(text, path.string(), require_rows);
}

}  // namespace formloop

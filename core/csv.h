#pragma once
// The one reader of formloop's text tables: point files (core/point_io.h), probe logs, tool-path files,
// compensation side files, deviation fields, `analyse moran` tables. Every comma-separated file goes
// through CsvReader (streaming, no copies: the point-file reader) or CsvTable (a small table held as
// strings), so the rules below hold everywhere and a new rule is added in one place:
//
//   - the text is UTF-8 (or ASCII); a UTF-8 byte-order mark at the start (Excel's "CSV UTF-8") is skipped;
//     text with NUL bytes (UTF-16/32, binary) is refused by CheckText with the encoding named;
//   - lines end at '\n'; a '\r' before it is dropped; lines are numbered from 1, blank lines included;
//   - a blank line (spaces, tabs, '\r' only) is skipped;
//   - a line whose first non-blank character is '#' is a comment: skipped, or handed to a reader that
//     wants it (the "# options:" line of a tool-path file);
//   - the first other line is the header; cells are separated by ',' and trimmed of spaces, tabs and
//     '\r'; a cell wrapped in double quotes loses them (a quoted cell holds no ','); a trailing ',' gives
//     a last empty cell, so column counts stay honest;
//   - a header with ';' and no ',' makes the whole table semicolon-separated (the CSV of a spreadsheet in a
//     decimal-comma locale): cells are split at ';' and a ',' inside a cell is its decimal comma, read as
//     '.' ("1,25" is 1.25). A comma-separated row with more cells than its header gets a hint about
//     decimal commas (RaggedRowFix).
//
// Numbers in cells are read without the locale (core/number_text.h: ParseDouble).

#include <cstddef>
#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "core/status.h"

namespace formloop {

// The lines of a text, numbered from 1 (a '\r' before '\n' is dropped). Also the line walker of the
// XYZ and ASCII PLY readers.
class TextLines {
 public:
  explicit TextLines(std::string_view text) : text_(text) {}
  // The next line, blank or not.
  bool Next(std::string_view* line);
  // The next line that is neither blank nor a '#' comment.
  bool NextContent(std::string_view* line);
  long line_number() const { return line_number_; }
  // Byte offset of the first character not yet returned.
  std::size_t position() const { return pos_; }

 private:
  std::string_view text_;
  std::size_t pos_ = 0;
  long line_number_ = 0;
};

// Trimmed of spaces, tabs and '\r' at both ends.
std::string_view TrimBlanks(std::string_view text);

// Splits one line into trimmed cells at `separator` (rules above); `cells` views into `line`.
void SplitCsvCells(std::string_view line, std::vector<std::string_view>* cells, char separator = ',');

// Refuses text that is not UTF-8/ASCII (NUL bytes: UTF-16 or UTF-32 with or without a byte-order mark,
// or a binary file), naming `source` and the encoding, with the fix (save as "CSV UTF-8").
Status CheckText(std::string_view text, const std::string& source);

// ReadFile, then CheckText: the whole text of a CSV/XYZ/text file, refused when it is not UTF-8 or ASCII.
Result<std::string> ReadTextFile(const std::filesystem::path& path);

// The fix for a row whose cell count differs from the header's: with ',' separators and more cells
// than the header, it mentions decimal commas.
std::string RaggedRowFix(char separator, std::size_t cells, std::size_t header_cells);

// Streams the rows (and, when asked, the comments) of a comma-separated text.
class CsvReader {
 public:
  // `text` must outlive the reader. With `comments`, '#' lines are returned as rows with is_comment().
  explicit CsvReader(std::string_view text, bool comments = false) : lines_(text), comments_(comments) {}
  // Advances to the next content line (or comment); false at the end.
  bool Next();
  bool is_comment() const { return comment_; }
  // ',' or ';', decided by the header (the first row that is not a comment).
  char separator() const { return separator_; }
  long line_number() const { return lines_.line_number(); }
  std::string_view line() const { return line_; }  // trimmed
  // The cells of the current line (empty for a comment).
  const std::vector<std::string_view>& cells() const { return cells_; }

 private:
  TextLines lines_;
  bool comments_ = false;
  bool comment_ = false;
  bool header_seen_ = false;
  char separator_ = ',';
  std::string_view line_;
  std::vector<std::string_view> cells_;
  std::vector<std::string> decimal_points_;  // semicolon tables: cells with their decimal comma made a point
};

// A whole small table: header, rows as strings, line numbers, comments. `source` names it in messages.
struct CsvTable {
  std::string source;
  long header_line = 0;     // 0: no header
  std::string header_text;  // the header line as written (trimmed)
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;          // every row has header.size() cells
  std::vector<long> lines;                             // file line of each row
  std::vector<std::pair<long, std::string>> comments;  // '#' lines (trimmed) with their line numbers

  // Index of a header column, or -1.
  int Find(std::string_view name) const;
  // Index of a header column; BadInput naming the file, the header line, `field` and the columns there are.
  Result<int> Column(std::string_view name, const std::string& field) const;
  // The cell as a finite number; BadInput naming the file, the row's line and the column.
  Status Number(std::size_t row, int column, double* value) const;
};

// Rows must have as many cells as the header; a header cell must not be empty. An empty text (no header)
// gives a table with header_line 0; `require_rows` refuses a table without a header or without rows.
Result<CsvTable> ParseCsvTable(std::string_view text, const std::string& source, bool require_rows = true);
// The same for a file (NotFound / IoError name the path).
Result<CsvTable> ReadCsvTable(const std::filesystem::path& path, bool require_rows = true);

}  // namespace formloop

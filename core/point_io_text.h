#pragma once
// Internal to core's point readers and writers (point_io.cc: CSV and XYZ; point_io_ply.cc: PLY): the
// text helpers they share (number and id fields with messages naming file, line and column, the column
// plan of a file's names, appending a point). Not part of the public API: use core/point_io.h.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "core/point_set.h"
#include "core/status.h"

namespace formloop::point_io_text {

// Quotes a value for a message, shortened so that a binary blob does not flood the terminal.
std::string Quote(std::string_view text);
// Splits at blanks (space, tab, CR, FF, VT) into *tokens (cleared first).
void SplitWhitespace(std::string_view line, std::vector<std::string_view>* tokens);
// "a, b, c".
std::string JoinNames(const std::vector<std::string>& names);
// A numeric field of a text file; refuses non-numbers and NaN/inf, naming file, line and field.
Status ParseNumberField(std::string_view text, const std::string& file, long line, const std::string& field,
                        double* value);
// An integer id (64 bits, optional '+').
Status ParseIdField(std::string_view text, const std::string& file, long line, const std::string& field,
                    std::int64_t* id);
// A double read from a binary or float-typed field that is a whole number usable as an id.
bool DoubleToId(double value, std::int64_t* id);

enum class Role { kX, kY, kZ, kNx, kNy, kNz, kId, kT, kScalar };

// Roles of a file's columns / properties and the checks shared by CSV and PLY: x, y, z present and
// the normals complete.
struct ColumnPlan {
  std::vector<Role> roles;
  std::vector<int> scalar_index;  // per column: index into PointSet::scalars, -1 otherwise
  std::vector<std::string> scalar_names;
  bool has_normals = false;
  bool has_id = false;
  bool has_t = false;
};

// The plan of a file's column / property names: x, y, z present, names unique, normals complete.
Status MakeColumnPlan(const std::vector<std::string>& names, const Where& where, const std::string& what_columns,
                      ColumnPlan* plan);
// An empty point set with the plan's attributes, `reserve` points reserved.
PointSet EmptySetFor(const ColumnPlan& plan, std::size_t reserve);
// Appends one point; `values` holds one number per column (ids already checked to be integral).
void AppendRow(const ColumnPlan& plan, const double* values, std::int64_t id, PointSet* points);
// Text of one number for the text writers: fixed decimals, or shortest round-trip when precision < 0.
void AppendNumber(double value, int precision, std::string* out);
void AppendInt(std::int64_t value, std::string* out);
// Scalar names a text format can hold: no separator, no whitespace at either end (CSV) or anywhere.
Status CheckScalarNames(const std::string& file, const PointSet& points, bool allow_inner_space,
                        const std::string& format);

}  // namespace formloop::point_io_text

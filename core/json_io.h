#pragma once
// JSON files and typed field access with errors that name the file and the key path.
//
//   FL_ASSIGN_OR_RETURN(nlohmann::json part, ReadJsonFile("part.json"));
//   JsonFields f(part, "part.json");
//   double tol_mm = 0;
//   FL_RETURN_IF_ERROR(f.Number("tolerance_mm", &tol_mm, {.min = 0, .exclusive_min = true}));
//   -> "part.json: field 'tolerance_mm': must be > 0, got -1. Fix: ..."

#include <cstdint>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"

namespace formloop {

using Json = nlohmann::json;

// Parse errors name the file, line and column.
Result<Json> ReadJsonFile(const std::filesystem::path& path);
Result<Json> ParseJson(const std::string& text, const std::string& source);
// Pretty-printed (2 spaces), newline-terminated, written atomically. Doubles print in their shortest
// exact form, independent of the locale.
Status WriteJsonFile(const std::filesystem::path& path, const Json& value);

struct NumberRange {
  double min = -std::numeric_limits<double>::infinity();
  double max = std::numeric_limits<double>::infinity();
  bool exclusive_min = false;
};

// A JSON value that must be an array of finite numbers in `range` (of length `size` when given); the
// messages name `source` and `field` (and "field[i]" for an element). JsonFields::NumberArray for members.
Status ReadNumberArray(const Json& value, const std::string& source, const std::string& field, std::vector<double>* out,
                       std::optional<std::size_t> size = {}, const NumberRange& range = {});

// The same for an array of integers in [min, max].
Status ReadIntegerArray(const Json& value, const std::string& source, const std::string& field,
                        std::vector<long long>* out, long long min = std::numeric_limits<long long>::min(),
                        long long max = std::numeric_limits<long long>::max());

// Typed access to the members of one JSON object. `source` is the file (or stage) and `prefix` the
// key path of this object inside it ("tool."), both used in messages. Unknown keys are reported by
// CheckKnown so typos do not silently fall back to defaults.
class JsonFields {
 public:
  JsonFields(const Json& object, std::string source, std::string prefix = "");

  bool Has(const std::string& key) const;
  // Required members: missing or wrong type is an error.
  Status Number(const std::string& key, double* out, const NumberRange& range = {}) const;
  Status Integer(const std::string& key, long long* out, long long min = std::numeric_limits<long long>::min(),
                 long long max = std::numeric_limits<long long>::max()) const;
  Status String(const std::string& key, std::string* out) const;
  Status Bool(const std::string& key, bool* out) const;
  // Optional members: keep *out (the default) when absent; a present member of the wrong type is an error.
  Status OptionalNumber(const std::string& key, double* out, const NumberRange& range = {}) const;
  Status OptionalInteger(const std::string& key, long long* out, long long min = std::numeric_limits<long long>::min(),
                         long long max = std::numeric_limits<long long>::max()) const;
  Status OptionalString(const std::string& key, std::string* out) const;
  Status OptionalBool(const std::string& key, bool* out) const;
  // A non-negative integer that may exceed long long (seeds).
  Status Unsigned(const std::string& key, std::uint64_t* out) const;
  // Arrays of finite numbers / integers; `size` (when given) is the required length.
  Status NumberArray(const std::string& key, std::vector<double>* out, std::optional<std::size_t> size = {},
                     const NumberRange& range = {}) const;
  Status IntegerArray(const std::string& key, std::vector<long long>* out,
                      long long min = std::numeric_limits<long long>::min(),
                      long long max = std::numeric_limits<long long>::max()) const;
  Status OptionalNumberArray(const std::string& key, std::vector<double>* out, std::optional<std::size_t> size = {},
                             const NumberRange& range = {}) const;
  Status StringArray(const std::string& key, std::vector<std::string>* out) const;
  // A nested object (required / optional). Returns its fields accessor via *out; the optional form
  // leaves *out empty when the member is absent.
  Status RequiredObject(const std::string& key, std::optional<JsonFields>* out) const;
  Status Object(const std::string& key, std::optional<JsonFields>* out) const;
  // An array of objects (required), one accessor per element with the prefix "key[i].".
  Status ObjectArray(const std::string& key, std::vector<JsonFields>* out) const;
  // Reports the first member whose key is not in `known`.
  Status CheckKnown(const std::vector<std::string>& known) const;

  const Json& json() const { return object_; }
  const std::string& source() const { return source_; }
  std::string Path(const std::string& key) const { return prefix_ + key; }

 private:
  Status TypeError(const std::string& key, const char* expected) const;
  Status Missing(const std::string& key, const char* what) const;
  Status CheckNumber(const Json& value, const std::string& field, const NumberRange& range, double* out) const;
  Status CheckInteger(const Json& value, const std::string& field, long long min, long long max, long long* out) const;
  Status CheckNumberArray(const Json& value, const std::string& field, std::optional<std::size_t> size,
                          const NumberRange& range, std::vector<double>* out) const;
  Status CheckIntegerArray(const Json& value, const std::string& field, long long min, long long max,
                           std::vector<long long>* out) const;
  friend Status ReadIntegerArray(const Json& value, const std::string& source, const std::string& field,
                                 std::vector<long long>* out, long long min, long long max);
  friend Status ReadNumberArray(const Json& value, const std::string& source, const std::string& field,
                                std::vector<double>* out, std::optional<std::size_t> size, const NumberRange& range);
  const Json& object_;
  std::string source_;
  std::string prefix_;
};

}  // namespace formloop

#pragma once
// JSON files and typed field access with errors that name the file and the key path.
//
//   FL_ASSIGN_OR_RETURN(nlohmann::json part, ReadJsonFile("part.json"));
//   JsonFields f(part, "part.json");
//   double tol_mm = 0;
//   FL_RETURN_IF_ERROR(f.Number("tolerance_mm", &tol_mm, {.min = 0, .exclusive_min = true}));
//   -> "part.json: field 'tolerance_mm': must be > 0, got -1. Fix: ..."

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
  // A nested object (required / optional). Returns its fields accessor via *out.
  Status Object(const std::string& key, std::optional<JsonFields>* out) const;
  // Reports the first member whose key is not in `known`.
  Status CheckKnown(const std::vector<std::string>& known) const;

  const Json& json() const { return object_; }
  const std::string& source() const { return source_; }
  std::string Path(const std::string& key) const { return prefix_ + key; }

 private:
  Status TypeError(const std::string& key, const char* expected) const;
  const Json& object_;
  std::string source_;
  std::string prefix_;
};

}  // namespace formloop

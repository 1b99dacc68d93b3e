#include "core/json_io.h"

#include <cmath>

#include "core/atomic_file.h"

namespace formloop {

Result<Json> ParseJson(const std::string& text, const std::string& source) {
  try {
    return Json::parse(text);
  } catch (const Json::parse_error& e) {
    // Convert the byte offset to line and column.
    long line = 1, column = 1;
    const std::size_t limit = std::min<std::size_t>(e.byte == 0 ? 0 : e.byte - 1, text.size());
    for (std::size_t i = 0; i < limit; ++i) {
      if (text[i] == '\n') {
        ++line;
        column = 1;
      } else {
        ++column;
      }
    }
    std::string what = e.what();
    // nlohmann's message starts with "[json.exception.parse_error.101] parse error at line ..."; keep
    // the part after the last ": " which says what was expected.
    const auto pos = what.rfind(": ");
    if (pos != std::string::npos) what = what.substr(pos + 2);
    return Status::BadInput(Where{.file = source, .line = line},
                            "invalid JSON at column " + std::to_string(column) + ": " + what,
                            "correct the JSON syntax at that place");
  }
}

Result<Json> ReadJsonFile(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(std::string text, ReadFile(path));
  if (text.find_first_not_of(" \t\r\n") == std::string::npos) {
    return Status::BadInput(Where{.file = path.string()}, "the file is empty", "write a JSON object");
  }
  return ParseJson(text, path.string());
}

Status WriteJsonFile(const std::filesystem::path& path, const Json& value) {
  std::string text;
  try {
    text = value.dump(2) + "\n";
  } catch (const Json::exception& e) {
    return Status::Internal("cannot serialise JSON for '" + path.string() + "': " + e.what());
  }
  return WriteFileAtomic(path, text);
}

JsonFields::JsonFields(const Json& object, std::string source, std::string prefix)
    : object_(object), source_(std::move(source)), prefix_(std::move(prefix)) {}

bool JsonFields::Has(const std::string& key) const { return object_.is_object() && object_.contains(key); }

Status JsonFields::TypeError(const std::string& key, const char* expected) const {
  const Json& value = object_.at(key);
  return Status::BadInput(Where{.file = source_, .field = Path(key)},
                          std::string("expected ") + expected + ", got " + value.type_name() + " " + value.dump(),
                          std::string("write ") + expected);
}

Status JsonFields::Number(const std::string& key, double* out, const NumberRange& range) const {
  if (!Has(key)) {
    return Status::BadInput(Where{.file = source_, .field = Path(key)}, "required field is missing",
                            "add \"" + key + "\": <number>");
  }
  const Json& value = object_.at(key);
  if (!value.is_number()) return TypeError(key, "a number");
  const double x = value.get<double>();
  if (!std::isfinite(x)) return TypeError(key, "a finite number");
  const bool below = range.exclusive_min ? !(x > range.min) : x < range.min;
  if (below || x > range.max) {
    std::string allowed = range.exclusive_min ? "> " : ">= ";
    allowed += nlohmann::json(range.min).dump();
    if (std::isfinite(range.max)) allowed += " and <= " + nlohmann::json(range.max).dump();
    return Status::BadInput(Where{.file = source_, .field = Path(key)},
                            "value " + value.dump() + " is out of range", "use a value " + allowed);
  }
  *out = x;
  return Status::Ok();
}

Status JsonFields::Integer(const std::string& key, long long* out, long long min, long long max) const {
  if (!Has(key)) {
    return Status::BadInput(Where{.file = source_, .field = Path(key)}, "required field is missing",
                            "add \"" + key + "\": <integer>");
  }
  const Json& value = object_.at(key);
  if (!value.is_number_integer()) return TypeError(key, "an integer");
  const long long x = value.get<long long>();
  if (x < min || x > max) {
    return Status::BadInput(Where{.file = source_, .field = Path(key)}, "value " + value.dump() + " is out of range",
                            "use an integer from " + std::to_string(min) + " to " + std::to_string(max));
  }
  *out = x;
  return Status::Ok();
}

Status JsonFields::String(const std::string& key, std::string* out) const {
  if (!Has(key)) {
    return Status::BadInput(Where{.file = source_, .field = Path(key)}, "required field is missing",
                            "add \"" + key + "\": \"...\"");
  }
  const Json& value = object_.at(key);
  if (!value.is_string()) return TypeError(key, "a string");
  *out = value.get<std::string>();
  return Status::Ok();
}

Status JsonFields::Bool(const std::string& key, bool* out) const {
  if (!Has(key)) {
    return Status::BadInput(Where{.file = source_, .field = Path(key)}, "required field is missing",
                            "add \"" + key + "\": true|false");
  }
  const Json& value = object_.at(key);
  if (!value.is_boolean()) return TypeError(key, "true or false");
  *out = value.get<bool>();
  return Status::Ok();
}

Status JsonFields::OptionalNumber(const std::string& key, double* out, const NumberRange& range) const {
  return Has(key) ? Number(key, out, range) : Status::Ok();
}
Status JsonFields::OptionalInteger(const std::string& key, long long* out, long long min, long long max) const {
  return Has(key) ? Integer(key, out, min, max) : Status::Ok();
}
Status JsonFields::OptionalString(const std::string& key, std::string* out) const {
  return Has(key) ? String(key, out) : Status::Ok();
}
Status JsonFields::OptionalBool(const std::string& key, bool* out) const {
  return Has(key) ? Bool(key, out) : Status::Ok();
}

Status JsonFields::Object(const std::string& key, std::optional<JsonFields>* out) const {
  if (!Has(key)) {
    out->reset();
    return Status::Ok();
  }
  const Json& value = object_.at(key);
  if (!value.is_object()) return TypeError(key, "an object");
  out->emplace(value, source_, Path(key) + ".");
  return Status::Ok();
}

Status JsonFields::CheckKnown(const std::vector<std::string>& known) const {
  if (!object_.is_object()) {
    return Status::BadInput(Where{.file = source_, .field = prefix_.empty() ? "(top level)" : prefix_},
                            std::string("expected an object, got ") + object_.type_name(), "write a JSON object {...}");
  }
  for (const auto& [key, value] : object_.items()) {
    bool found = false;
    for (const auto& k : known) found = found || (k == key);
    if (!found) {
      std::string list;
      for (const auto& k : known) list += (list.empty() ? "" : ", ") + k;
      return Status::BadInput(Where{.file = source_, .field = Path(key)}, "unknown field",
                              "check the spelling; known fields here are: " + list);
    }
  }
  return Status::Ok();
}

}  // namespace formloop

#include "core/json_io.h"

#include <algorithm>
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
  } catch (const Json::exception& e) {
    // Not a syntax error: a number beyond a double's range ("1e400": out_of_range 406, which gives no position).
    // The message quotes the number; its first occurrence in the text gives the line.
    std::string what = e.what();
    const auto prefix = what.find("] ");
    if (prefix != std::string::npos) what = what.substr(prefix + 2);
    long line = 0;
    const auto open = what.find('\''), close = what.rfind('\'');
    if (open != std::string::npos && close > open + 1) {
      const auto at = text.find(what.substr(open + 1, close - open - 1));
      if (at != std::string::npos) line = 1 + static_cast<long>(std::count(text.begin(), text.begin() + at, '\n'));
    }
    return Status::BadInput(Where{.file = source, .line = line}, "invalid JSON: " + what,
                            "write numbers within a double's range (magnitude below 1.8e308)");
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
  if (!Has(key)) return Missing(key, "<number>");
  return CheckNumber(object_.at(key), Path(key), range, out);
}

Status JsonFields::CheckNumber(const Json& value, const std::string& field, const NumberRange& range,
                               double* out) const {
  if (!value.is_number() || !std::isfinite(value.get<double>())) {
    const char* expected = value.is_number() ? "a finite number" : "a number";
    return Status::BadInput(Where{.file = source_, .field = field},
                            std::string("expected ") + expected + ", got " + value.type_name() + " " + value.dump(),
                            std::string("write ") + expected);
  }
  const double x = value.get<double>();
  const bool below = range.exclusive_min ? !(x > range.min) : x < range.min;
  if (below || x > range.max) {
    std::string allowed = range.exclusive_min ? "> " : ">= ";
    allowed += nlohmann::json(range.min).dump();
    if (std::isfinite(range.max)) allowed += " and <= " + nlohmann::json(range.max).dump();
    return Status::BadInput(Where{.file = source_, .field = field}, "value " + value.dump() + " is out of range",
                            "use a value " + allowed);
  }
  *out = x;
  return Status::Ok();
}

Status JsonFields::Integer(const std::string& key, long long* out, long long min, long long max) const {
  if (!Has(key)) return Missing(key, "<integer>");
  return CheckInteger(object_.at(key), Path(key), min, max, out);
}

Status JsonFields::CheckInteger(const Json& value, const std::string& field, long long min, long long max,
                                long long* out) const {
  if (!value.is_number_integer()) {
    return Status::BadInput(Where{.file = source_, .field = field},
                            std::string("expected an integer, got ") + value.type_name() + " " + value.dump(),
                            "write an integer");
  }
  const long long x = value.get<long long>();
  if (x < min || x > max) {
    return Status::BadInput(Where{.file = source_, .field = field}, "value " + value.dump() + " is out of range",
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

Status JsonFields::Missing(const std::string& key, const char* what) const {
  return Status::BadInput(Where{.file = source_, .field = Path(key)}, "required field is missing",
                          "add \"" + key + "\": " + what);
}

Status JsonFields::Unsigned(const std::string& key, std::uint64_t* out) const {
  if (!Has(key)) return Missing(key, "<non-negative integer>");
  const Json& value = object_.at(key);
  if (!value.is_number_unsigned() && !(value.is_number_integer() && value.get<long long>() >= 0)) {
    return TypeError(key, "a non-negative integer");
  }
  *out = value.get<std::uint64_t>();
  return Status::Ok();
}

Status ReadNumberArray(const Json& value, const std::string& source, const std::string& field, std::vector<double>* out,
                       std::optional<std::size_t> size, const NumberRange& range) {
  const JsonFields wrapper(value, source);
  return wrapper.CheckNumberArray(value, field, size, range, out);
}

Status JsonFields::NumberArray(const std::string& key, std::vector<double>* out, std::optional<std::size_t> size,
                               const NumberRange& range) const {
  if (!Has(key)) return Missing(key, "[<number>, ...]");
  return CheckNumberArray(object_.at(key), Path(key), size, range, out);
}

Status JsonFields::CheckNumberArray(const Json& value, const std::string& field, std::optional<std::size_t> size,
                                    const NumberRange& range, std::vector<double>* out) const {
  if (!value.is_array()) {
    return Status::BadInput(Where{.file = source_, .field = field},
                            std::string("expected an array of numbers, got ") + value.type_name(),
                            "write [<number>, ...]");
  }
  if (size && value.size() != *size) {
    return Status::BadInput(Where{.file = source_, .field = field},
                            "expected " + std::to_string(*size) + " numbers, got " + std::to_string(value.size()),
                            "write an array of " + std::to_string(*size) + " numbers");
  }
  std::vector<double> result(value.size());
  for (std::size_t k = 0; k < value.size(); ++k) {
    FL_RETURN_IF_ERROR(CheckNumber(value[k], field + "[" + std::to_string(k) + "]", range, &result[k]));
  }
  *out = std::move(result);
  return Status::Ok();
}

Status JsonFields::OptionalNumberArray(const std::string& key, std::vector<double>* out,
                                       std::optional<std::size_t> size, const NumberRange& range) const {
  return Has(key) ? NumberArray(key, out, size, range) : Status::Ok();
}

Status ReadIntegerArray(const Json& value, const std::string& source, const std::string& field,
                        std::vector<long long>* out, long long min, long long max) {
  const JsonFields wrapper(value, source);
  return wrapper.CheckIntegerArray(value, field, min, max, out);
}

Status JsonFields::IntegerArray(const std::string& key, std::vector<long long>* out, long long min,
                                long long max) const {
  if (!Has(key)) return Missing(key, "[<integer>, ...]");
  return CheckIntegerArray(object_.at(key), Path(key), min, max, out);
}

Status JsonFields::CheckIntegerArray(const Json& value, const std::string& field, long long min, long long max,
                                     std::vector<long long>* out) const {
  if (!value.is_array()) {
    return Status::BadInput(Where{.file = source_, .field = field},
                            std::string("expected an array of integers, got ") + value.type_name(),
                            "write [<integer>, ...]");
  }
  std::vector<long long> result(value.size());
  for (std::size_t k = 0; k < value.size(); ++k) {
    FL_RETURN_IF_ERROR(CheckInteger(value[k], field + "[" + std::to_string(k) + "]", min, max, &result[k]));
  }
  *out = std::move(result);
  return Status::Ok();
}

Status JsonFields::StringArray(const std::string& key, std::vector<std::string>* out) const {
  if (!Has(key)) return Missing(key, "[\"...\", ...]");
  const Json& value = object_.at(key);
  if (!value.is_array()) return TypeError(key, "an array of strings");
  std::vector<std::string> result;
  for (std::size_t k = 0; k < value.size(); ++k) {
    if (!value[k].is_string()) {
      return Status::BadInput(Where{.file = source_, .field = Path(key) + "[" + std::to_string(k) + "]"},
                              std::string("expected a string, got ") + value[k].type_name() + " " + value[k].dump(),
                              "write a string");
    }
    result.push_back(value[k].get<std::string>());
  }
  *out = std::move(result);
  return Status::Ok();
}

Status JsonFields::RequiredObject(const std::string& key, std::optional<JsonFields>* out) const {
  if (!Has(key)) return Missing(key, "{...}");
  return Object(key, out);
}

Status JsonFields::ObjectArray(const std::string& key, std::vector<JsonFields>* out) const {
  if (!Has(key)) return Missing(key, "[{...}, ...]");
  const Json& value = object_.at(key);
  if (!value.is_array()) return TypeError(key, "an array of objects");
  out->clear();
  for (std::size_t k = 0; k < value.size(); ++k) {
    const std::string element = Path(key) + "[" + std::to_string(k) + "]";
    if (!value[k].is_object()) {
      return Status::BadInput(Where{.file = source_, .field = element},
                              std::string("expected an object, got ") + value[k].type_name(), "write {...}");
    }
    out->emplace_back(value[k], source_, element + ".");
  }
  return Status::Ok();
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

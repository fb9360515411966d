#include "common/json_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <locale>
#include <sstream>

#include "common/file_beneath.h"

namespace alacs {

namespace {

// Thrown by the parser callback to stop at the first level too deep; caught in parseJson.
struct TooDeep {};

// 1-based line and column of byte `offset` in `text`, and that line, cut to 120 characters
// with control characters replaced so that the message stays one line.
struct Where {
  size_t line = 1;
  size_t column = 1;
  std::string quote;
};

Where locate(std::string_view text, size_t offset) {
  offset = std::min(offset, text.size());
  Where w;
  size_t lineStart = 0;
  for (size_t i = 0; i < offset; ++i) {
    if (text[i] == '\n') {
      ++w.line;
      lineStart = i + 1;
    }
  }
  w.column = offset - lineStart + 1;
  constexpr size_t kQuoteChars = 120;
  // Centre a long line's quote on the error.
  size_t from = lineStart;
  if (offset - lineStart > kQuoteChars / 2) from = offset - kQuoteChars / 2;
  for (size_t i = from; i < text.size() && text[i] != '\n' && w.quote.size() < kQuoteChars; ++i) {
    const auto c = static_cast<unsigned char>(text[i]);
    w.quote += (c < 0x20 || c >= 0x7f) ? '?' : static_cast<char>(c);
  }
  return w;
}

// The byte at which nesting first exceeds `maxDepth` (brackets outside strings), for the
// message of a TooDeep.
size_t firstTooDeep(std::string_view text, int maxDepth) {
  int depth = 0;
  bool inString = false;
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (inString) {
      if (c == '\\') ++i;
      else if (c == '"') inString = false;
    } else if (c == '"') {
      inString = true;
    } else if (c == '[' || c == '{') {
      if (++depth > maxDepth) return i;
    } else if (c == ']' || c == '}') {
      --depth;
    }
  }
  return text.size();
}

// nlohmann's parse_error text without its prefix and without the "last read" token, which
// can be as long as the file.
std::string parseProblem(const std::string& message) {
  std::string p = message;
  if (const size_t colon = p.find(": "); colon != std::string::npos && p.rfind("[json.exception", 0) == 0)
    p = p.substr(colon + 2);
  if (const size_t last = p.find("; last read: "); last != std::string::npos) {
    const size_t expected = p.rfind("; expected ");
    p = p.substr(0, last) + (expected != std::string::npos && expected > last ? p.substr(expected) : "");
  }
  if (p.size() > 160) p.resize(160);
  for (char& c : p)
    if (static_cast<unsigned char>(c) < 0x20) c = ' ';
  return p;
}

size_t editDistance(std::string_view a, std::string_view b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diagonal = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

std::string shown(std::string_view key) {
  std::string s(key.substr(0, 80));
  for (char& c : s)
    if (static_cast<unsigned char>(c) < 0x20) c = '?';
  return s;
}

}  // namespace

Result<Json> parseJson(std::string_view text, const std::string& what, int maxDepth) {
  const Json::parser_callback_t limitDepth = [maxDepth](int depth, Json::parse_event_t event, Json&) {
    // `depth` is that of the container being opened, 0 for the root's parent.
    if ((event == Json::parse_event_t::object_start || event == Json::parse_event_t::array_start) &&
        depth >= maxDepth)
      throw TooDeep{};
    return true;
  };
  try {
    return Json::parse(text.begin(), text.end(), limitDepth, /*allow_exceptions=*/true, /*ignore_comments=*/false);
  } catch (const TooDeep&) {
    const Where w = locate(text, firstTooDeep(text, maxDepth));
    return Status(Error::kBadInput, what + " nests deeper than " + std::to_string(maxDepth) + " levels at line " +
                                        std::to_string(w.line) + ", column " + std::to_string(w.column));
  } catch (const Json::parse_error& e) {
    // e.byte is 1-based: the byte after the one that failed.
    const Where w = locate(text, e.byte > 0 ? e.byte - 1 : 0);
    return Status(Error::kBadInput, what + " is not valid JSON: line " + std::to_string(w.line) + ", column " +
                                        std::to_string(w.column) + ": " + parseProblem(e.what()) + ": `" + w.quote +
                                        "`");
  } catch (const Json::exception& e) {
    return Status(Error::kBadInput, what + " is not valid JSON: " + parseProblem(e.what()));
  } catch (const std::bad_alloc&) {
    return Status(Error::kBadInput, what + " is too large to parse");
  }
}

Result<Json> readJsonFile(const std::string& path, const std::string& what, size_t maxBytes) {
  const std::string name = what + " '" + path + "'";
  // O_NONBLOCK: opening a FIFO must not wait for a writer; readAllBounded refuses it.
  const UniqueFd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOCTTY));
  if (fd.get() < 0) return Status(Error::kNotFound, name + " cannot be opened: " + std::strerror(errno));
  Result<std::string> text = readAllBounded(fd.get(), name, maxBytes);
  if (!text) return text.status();
  return parseJson(*text, name);
}

Result<Json> readJsonFileBeneath(const std::string& dir, const std::string& relPath, const std::string& what,
                                 size_t maxBytes) {
  Result<UniqueFd> fd = openBeneath(dir, relPath, what);
  if (!fd) return fd.status();
  const std::string name = what + " '" + dir + "/" + relPath + "'";
  Result<std::string> text = readAllBounded(fd->get(), name, maxBytes);
  if (!text) return text.status();
  return parseJson(*text, name);
}

std::string jsonText(const OrderedJson& value) {
  return value.dump(2, ' ', false, OrderedJson::error_handler_t::replace) + "\n";
}

const char* jsonTypeName(const Json& v) {
  switch (v.type()) {
    case Json::value_t::object: return "object";
    case Json::value_t::array: return "array";
    case Json::value_t::string: return "string";
    case Json::value_t::boolean: return "boolean";
    case Json::value_t::number_integer:
    case Json::value_t::number_unsigned:
    case Json::value_t::number_float: return "number";
    case Json::value_t::binary: return "binary";
    case Json::value_t::discarded:
    case Json::value_t::null: return "null";
  }
  return "null";
}

void JsonErrors::field(const std::string& path, const std::string& problem) {
  if (status_.isOk()) status_ = Status(Error::kBadInput, what_ + " field '" + path + "' " + problem);
}

void JsonErrors::other(const std::string& message) {
  if (status_.isOk()) status_ = Status(Error::kBadInput, what_ + ": " + message);
}

namespace {
// An array element that must be a finite number; else the error is recorded at `where`.
bool finiteNumberAt(JsonErrors& errors, const std::string& where, const Json& e) {
  if (!e.is_number()) {
    errors.field(where, std::string("wrong type (expected number, got ") + jsonTypeName(e) + ")");
    return false;
  }
  if (!std::isfinite(e.get<double>())) {
    errors.field(where, "must be finite");
    return false;
  }
  return true;
}
}  // namespace

JsonObjectReader::JsonObjectReader(JsonErrors& errors, const Json* value, std::string path)
    : errors_(errors), object_(value), path_(std::move(path)) {
  if (object_ != nullptr && !object_->is_object()) {
    errors_.field(path_.empty() ? "(root)" : path_,
                  std::string("wrong type (expected object, got ") + jsonTypeName(*object_) + ")");
    object_ = nullptr;
  }
}

std::string JsonObjectReader::pathOf(std::string_view key) const {
  return path_.empty() ? std::string(key) : path_ + "." + std::string(key);
}

void JsonObjectReader::allow(std::string_view key) { known_.emplace_back(key); }

bool JsonObjectReader::has(std::string_view key) {
  allow(key);
  return object_ != nullptr && object_->contains(key);
}

const Json* JsonObjectReader::find(std::string_view key, Need need) {
  allow(key);
  if (!ok()) return nullptr;
  const auto it = object_->find(key);
  if (it == object_->end()) {
    if (need == Need::kRequired) errors_.field(pathOf(key), "is missing");
    return nullptr;
  }
  return &*it;
}

void JsonObjectReader::wrongType(std::string_view key, const char* expected, const Json& got) {
  errors_.field(pathOf(key), std::string("wrong type (expected ") + expected + ", got " + jsonTypeName(got) + ")");
}

namespace {
std::string rangeText(double lo, double hi) {
  std::ostringstream s;
  s.imbue(std::locale::classic());
  s.precision(10);
  s << lo << ".." << hi;
  return s.str();
}
std::string valueText(double v) {
  std::ostringstream s;
  s.imbue(std::locale::classic());
  s.precision(10);
  s << v;
  return s.str();
}
}  // namespace

bool JsonObjectReader::number(std::string_view key, double& out, Need need, double lo, double hi) {
  const Json* v = find(key, need);
  if (v == nullptr) return false;
  if (!v->is_number()) {
    wrongType(key, "number", *v);
    return false;
  }
  const double x = v->get<double>();
  if (!std::isfinite(x)) {
    errors_.field(pathOf(key), "must be finite");
    return false;
  }
  if (!(x >= lo && x <= hi)) {
    errors_.field(pathOf(key), "must be in " + rangeText(lo, hi) + " (got " + valueText(x) + ")");
    return false;
  }
  out = x;
  return true;
}

bool JsonObjectReader::toInteger(const Json& v, const std::string& where, int64_t lo, int64_t hi, int64_t& out) {
  const std::string range = std::to_string(lo) + ".." + std::to_string(hi);
  if (!v.is_number()) {
    errors_.field(where, std::string("wrong type (expected integer, got ") + jsonTypeName(v) + ")");
    return false;
  }
  int64_t x = 0;
  if (v.is_number_unsigned()) {
    const uint64_t u = v.get<uint64_t>();
    if (u > static_cast<uint64_t>(hi)) {
      errors_.field(where, "must be in " + range + " (got " + std::to_string(u) + ")");
      return false;
    }
    x = static_cast<int64_t>(u);
  } else if (v.is_number_integer()) {
    x = v.get<int64_t>();
  } else {
    const double d = v.get<double>();
    if (!(d == std::floor(d))) {
      errors_.field(where, "must be an integer (got " + valueText(d) + ")");
      return false;
    }
    // Range before the conversion: a double beyond int64 must not be converted.
    // 2^63 itself passes `d <= double(INT64_MAX)` (the bound rounds up), hence the strict test.
    constexpr double kTwo63 = 9223372036854775808.0;
    if (!(d >= static_cast<double>(lo) && d <= static_cast<double>(hi) && d < kTwo63)) {
      errors_.field(where, "must be in " + range + " (got " + valueText(d) + ")");
      return false;
    }
    x = static_cast<int64_t>(d);
  }
  if (x < lo || x > hi) {
    errors_.field(where, "must be in " + range + " (got " + std::to_string(x) + ")");
    return false;
  }
  out = x;
  return true;
}

bool JsonObjectReader::integer(std::string_view key, int64_t& out, Need need, int64_t lo, int64_t hi) {
  const Json* v = find(key, need);
  return v != nullptr && toInteger(*v, pathOf(key), lo, hi, out);
}

bool JsonObjectReader::integer(std::string_view key, int& out, Need need, int lo, int hi) {
  int64_t x = out;
  if (!integer(key, x, need, lo, hi)) return false;
  out = static_cast<int>(x);
  return true;
}

bool JsonObjectReader::unsignedInteger(std::string_view key, uint64_t& out, Need need) {
  const Json* v = find(key, need);
  if (v == nullptr) return false;
  if (v->is_number_unsigned()) {
    out = v->get<uint64_t>();
    return true;
  }
  int64_t x = 0;
  if (!toInteger(*v, pathOf(key), 0, std::numeric_limits<int64_t>::max(), x)) return false;
  out = static_cast<uint64_t>(x);
  return true;
}

bool JsonObjectReader::boolean(std::string_view key, bool& out, Need need) {
  const Json* v = find(key, need);
  if (v == nullptr) return false;
  if (!v->is_boolean()) {
    wrongType(key, "boolean", *v);
    return false;
  }
  out = v->get<bool>();
  return true;
}

bool JsonObjectReader::flag(std::string_view key, bool& out, Need need) {
  const Json* v = find(key, need);
  if (v == nullptr) return false;
  if (v->is_boolean()) {
    out = v->get<bool>();
    return true;
  }
  if (v->is_number() && (v->get<double>() == 0.0 || v->get<double>() == 1.0)) {
    out = v->get<double>() != 0.0;
    return true;
  }
  if (v->is_number()) {
    errors_.field(pathOf(key), "must be true, false, 0 or 1");
  } else {
    wrongType(key, "boolean", *v);
  }
  return false;
}

bool JsonObjectReader::text(std::string_view key, std::string& out, Need need, size_t maxChars) {
  const Json* v = find(key, need);
  if (v == nullptr) return false;
  if (!v->is_string()) {
    wrongType(key, "string", *v);
    return false;
  }
  const auto& s = v->get_ref<const std::string&>();
  if (s.size() > maxChars) {
    errors_.field(pathOf(key), "is longer than " + std::to_string(maxChars) + " characters");
    return false;
  }
  out = s;
  return true;
}

namespace {
// `v` (may be null: absent) as an array of exactly `count` elements, else null with the
// error recorded: wrong type through `wrongType`, a wrong length at `path`.
template <typename WrongType>
const Json* fixedArray(JsonErrors& errors, const std::string& path, const Json* v,
                       size_t count, const char* elements, WrongType&& wrongType) {
  if (v == nullptr) return nullptr;
  const std::string shape = "an array of " + std::to_string(count) + " " + elements;
  if (!v->is_array()) {
    wrongType(shape.c_str(), *v);
    return nullptr;
  }
  if (v->size() != count) {
    errors.field(path, "must be " + shape + " (got " + std::to_string(v->size()) + " elements)");
    return nullptr;
  }
  return v;
}
}  // namespace

bool JsonObjectReader::numbers(std::string_view key, std::span<double> out, Need need) {
  const Json* v = fixedArray(errors_, pathOf(key), find(key, need), out.size(), "numbers", [&](const char* shape, const Json& got) {
    wrongType(key, shape, got);
  });
  if (v == nullptr) return false;
  for (size_t i = 0; i < out.size(); ++i) {
    if (!finiteNumberAt(errors_, pathOf(key) + "[" + std::to_string(i) + "]", (*v)[i])) return false;
  }
  for (size_t i = 0; i < out.size(); ++i) out[i] = (*v)[i].get<double>();
  return true;
}

bool JsonObjectReader::numberList(std::string_view key, std::vector<double>& out, size_t maxCount, Need need) {
  const Json* v = array(key, maxCount, need);
  if (v == nullptr) return false;
  std::vector<double> values;
  values.reserve(v->size());
  for (size_t i = 0; i < v->size(); ++i) {
    if (!finiteNumberAt(errors_, pathOf(key) + "[" + std::to_string(i) + "]", (*v)[i])) return false;
    values.push_back((*v)[i].get<double>());
  }
  out = std::move(values);
  return true;
}

bool JsonObjectReader::integers(std::string_view key, std::span<int64_t> out, int64_t lo, int64_t hi, Need need) {
  const Json* v = fixedArray(errors_, pathOf(key), find(key, need), out.size(), "integers", [&](const char* shape, const Json& got) {
    wrongType(key, shape, got);
  });
  if (v == nullptr) return false;
  std::vector<int64_t> values(out.size());
  for (size_t i = 0; i < out.size(); ++i)
    if (!toInteger((*v)[i], pathOf(key) + "[" + std::to_string(i) + "]", lo, hi, values[i])) return false;
  std::copy(values.begin(), values.end(), out.begin());
  return true;
}

std::optional<JsonObjectReader> JsonObjectReader::object(std::string_view key, Need need) {
  const Json* v = find(key, need);
  if (v == nullptr) return std::nullopt;
  if (!v->is_object()) {
    wrongType(key, "object", *v);
    return std::nullopt;
  }
  return JsonObjectReader(errors_, v, pathOf(key));
}

const Json* JsonObjectReader::array(std::string_view key, size_t maxCount, Need need) {
  const Json* v = find(key, need);
  if (v == nullptr) return nullptr;
  if (!v->is_array()) {
    wrongType(key, "array", *v);
    return nullptr;
  }
  if (v->size() > maxCount) {
    errors_.field(pathOf(key), "holds " + std::to_string(v->size()) + " elements, more than " +
                                   std::to_string(maxCount));
    return nullptr;
  }
  return v;
}

JsonObjectReader JsonObjectReader::element(std::string_view key, const Json& array, size_t index) {
  return JsonObjectReader(errors_, &array[index], pathOf(key) + "[" + std::to_string(index) + "]");
}

bool JsonObjectReader::finish() {
  if (!ok()) return false;
  for (const auto& [key, value] : object_->items()) {
    (void)value;
    if (std::find(known_.begin(), known_.end(), key) != known_.end()) continue;
    std::string message = "unknown key '" + shown(pathOf(key)) + "'";
    const std::string* best = nullptr;
    size_t bestDistance = std::numeric_limits<size_t>::max();
    for (const std::string& k : known_) {
      const size_t d = editDistance(key.substr(0, 200), k);
      if (d < bestDistance) {
        bestDistance = d;
        best = &k;
      }
    }
    // A suggestion only when it is plausibly a typo or a shortened key ('crop' for
    // 'crop_px'), not any key at all.
    const bool prefix = best != nullptr && key.size() >= 3 && best->compare(0, key.size(), key) == 0;
    if (best != nullptr && (prefix || bestDistance <= std::max<size_t>(2, best->size() / 3)))
      message += " (did you mean '" + pathOf(*best) + "'?)";
    errors_.other(message);
    return false;
  }
  return true;
}

}  // namespace alacs

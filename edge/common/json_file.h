// JSON files read and written through nlohmann-json, for the configuration, the
// calibration, the scene and the scan manifest.
//
// Reading is defensive because every one of those files is external input: a file is read
// only when it is a regular file no larger than a cap (so /dev/zero or a FIFO is refused,
// not read forever), nesting is limited while parsing (so a 120 KB deep array cannot
// exhaust the stack later), and a parse error is one line naming the line and column with
// at most one line (120 characters) of the input quoted, never the file.
//
// JsonObjectReader is the typed accessor over one object: every error names the field by
// its full path (`laser.plane_normal`) and says whether it is missing or of the wrong type;
// keys the reader did not ask for are refused with the nearest known key suggested; arrays
// are bounded before anything is allocated. No exception leaves this header's functions.
#pragma once

#include <nlohmann/json.hpp>

#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/result.h"

namespace alacs {

using Json = nlohmann::json;
// Key order as inserted: the files we write keep the order the docs show.
using OrderedJson = nlohmann::ordered_json;

inline constexpr size_t kJsonMaxBytes = size_t{16} << 20;  // the largest file any reader accepts
inline constexpr int kJsonMaxDepth = 32;                   // no file of ours nests deeper than 4

// Parses `text`. `what` names the input in errors ("config file '/etc/alacs/alacsd.json'").
// Errors: kBadInput with line, column and the offending line (≤ 120 characters) quoted,
// or the depth at which nesting exceeded `maxDepth`.
Result<Json> parseJson(std::string_view text, const std::string& what, int maxDepth = kJsonMaxDepth);

// Reads and parses the regular file `path`. `what` names the file's role in errors
// ("config file"). Errors: kNotFound when it cannot be opened; kBadInput when it is not a
// regular file, is larger than `maxBytes` or is not JSON; kIo when reading fails.
Result<Json> readJsonFile(const std::string& path, const std::string& what, size_t maxBytes = kJsonMaxBytes);
// The same for a file named by a manifest: `relPath` inside `dir`, never leaving it
// (common/file_beneath.h: no "..", no symlink, a regular file only).
Result<Json> readJsonFileBeneath(const std::string& dir, const std::string& relPath, const std::string& what,
                                 size_t maxBytes = kJsonMaxBytes);

// Pretty-printed text of `value` (two spaces, a final newline). Invalid UTF-8 in strings is
// replaced, never thrown.
std::string jsonText(const OrderedJson& value);

// "object", "array", "string", "number", "boolean" or "null".
const char* jsonTypeName(const Json& value);

// The first error of a whole read, shared by the readers of its objects.
// Messages read "<what> field '<path>' <problem>", e.g.
// "config field 'camera.exposure_us' wrong type (expected number, got string)".
class JsonErrors {
 public:
  explicit JsonErrors(std::string what) : what_(std::move(what)) {}
  bool ok() const { return status_.isOk(); }
  const Status& status() const { return status_; }
  // Records a problem with the field at `path` unless an error is already recorded.
  void field(const std::string& path, const std::string& problem);
  // Records a message that is not about one field (an unknown key).
  void other(const std::string& message);

 private:
  std::string what_;
  Status status_;
};

enum class Need { kOptional, kRequired };

// Reads the fields of one JSON object. A present field of the wrong type, out of range or
// (for kRequired) absent records an error in `errors` and leaves the output unchanged;
// an absent kOptional field leaves it unchanged silently. After the first error the
// accessors still note their key (for finish()) but read nothing. Not thread-safe; the
// JSON value must outlive the reader.
class JsonObjectReader {
 public:
  // `value` null or not an object: "wrong type (expected object, got ...)" is recorded at
  // `path` (the root's path is empty and reads as "(root)").
  JsonObjectReader(JsonErrors& errors, const Json* value, std::string path);

  // Whether the value is an object and no error has been recorded yet.
  bool ok() const { return object_ != nullptr && errors_.ok(); }
  const std::string& path() const { return path_; }
  // The full path of `key` under this object ("laser.plane_normal").
  std::string pathOf(std::string_view key) const;

  // Whether `key` is present; notes the key as known.
  bool has(std::string_view key);
  // Notes `key` as known without reading it (a field written for people, not read back).
  void allow(std::string_view key);

  // A number in [lo, hi] (finite).
  bool number(std::string_view key, double& out, Need need = Need::kOptional,
              double lo = std::numeric_limits<double>::lowest(), double hi = std::numeric_limits<double>::max());
  // An integral number in [lo, hi] ("2.0" is accepted, "2.5" is not).
  bool integer(std::string_view key, int64_t& out, Need need = Need::kOptional,
               int64_t lo = std::numeric_limits<int32_t>::min(), int64_t hi = std::numeric_limits<int32_t>::max());
  bool integer(std::string_view key, int& out, Need need = Need::kOptional, int lo = std::numeric_limits<int>::min(),
               int hi = std::numeric_limits<int>::max());
  // A non-negative integer up to 2^64 - 1 (seeds).
  bool unsignedInteger(std::string_view key, uint64_t& out, Need need = Need::kOptional);
  bool boolean(std::string_view key, bool& out, Need need = Need::kOptional);
  // true/false, or the numbers 0 and 1 (older files wrote flags as numbers).
  bool flag(std::string_view key, bool& out, Need need = Need::kOptional);
  bool text(std::string_view key, std::string& out, Need need = Need::kOptional, size_t maxChars = 4096);
  // An array of exactly out.size() finite numbers.
  bool numbers(std::string_view key, std::span<double> out, Need need = Need::kOptional);
  // An array of at most `maxCount` finite numbers; `out` is replaced.
  bool numberList(std::string_view key, std::vector<double>& out, size_t maxCount, Need need = Need::kOptional);
  // An array of exactly out.size() integers in [lo, hi].
  bool integers(std::string_view key, std::span<int64_t> out, int64_t lo, int64_t hi, Need need = Need::kOptional);
  // The object at `key`: nullopt when absent (an error if kRequired) or of the wrong type.
  std::optional<JsonObjectReader> object(std::string_view key, Need need = Need::kOptional);
  // The array at `key`, refused (before its elements are touched) when it holds more than
  // `maxCount` elements: null when absent, of the wrong type or too long.
  const Json* array(std::string_view key, size_t maxCount, Need need = Need::kOptional);
  // A reader of element `index` of `array` (from array()), at path "key[index]".
  JsonObjectReader element(std::string_view key, const Json& array, size_t index);

  // Records `problem` with the field `key` (a value the accessors cannot judge).
  void fail(std::string_view key, const std::string& problem) { errors_.field(pathOf(key), problem); }

  // Refuses the first key that no accessor asked for: "unknown key 'laser.max_on_msec'
  // (did you mean 'laser.max_on_ms'?)". Call after every accessor. Returns ok().
  bool finish();

 private:
  const Json* find(std::string_view key, Need need);
  void wrongType(std::string_view key, const char* expected, const Json& got);
  bool toInteger(const Json& v, const std::string& where, int64_t lo, int64_t hi, int64_t& out);

  JsonErrors& errors_;
  const Json* object_;
  std::string path_;
  std::vector<std::string> known_;
};

}  // namespace alacs

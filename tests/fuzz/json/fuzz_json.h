// Shared by the JSON fuzz targets: the text is parsed as the loaders parse it, and every
// error must stay a one-line message of bounded size (no echo of the input).
#pragma once

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string_view>

#include "common/json_file.h"

namespace alacs::fuzz {

inline void check(bool ok, const char* what) {
  if (!ok) {
    std::fprintf(stderr, "invariant broken: %s\n", what);
    std::abort();
  }
}

inline void checkMessage(const Status& s) {
  if (s.isOk()) return;
  check(s.code() == Error::kBadInput, "an error on input is kBadInput");
  check(s.reason().find('\n') == std::string::npos, "an error is one line");
  check(s.reason().size() < 1000, "an error is short");
}

// The parsed input, or null after checking the parse error.
inline Result<Json> parse(const uint8_t* data, size_t size) {
  Result<Json> json = parseJson(std::string_view(reinterpret_cast<const char*>(data), size), "fuzz input");
  if (!json) checkMessage(json.status());
  return json;
}

}  // namespace alacs::fuzz

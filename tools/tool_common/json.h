// The host tools' JSON, through nlohmann-json: documents keep their keys in the order
// written (ordered_json), numbers keep the precision their consumers have always read.
#pragma once

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <nlohmann/json.hpp>
#include <string>

namespace alacs::tools {

using Json = nlohmann::ordered_json;

// `v` as printf's `fmt` prints it ("%.6f", "%.0f", "%g"), null when not finite: a reader
// parses the value, and the type (an integer when the text has no fraction or exponent,
// as "%.0f" gives), that the tools printed before they used nlohmann.
inline Json jsonNumber(double v, const char* fmt = "%.6f") {
  if (!std::isfinite(v)) return nullptr;
  char buf[64];
  std::snprintf(buf, sizeof buf, fmt, v);
  if (std::strpbrk(buf, ".eE") == nullptr) return std::strtoll(buf, nullptr, 10);
  return std::strtod(buf, nullptr);
}

// A document's text and a newline: `indent` as nlohmann's dump (-1: one line, as a JSONL
// record). Bytes that are not UTF-8 (a file name) are replaced, never thrown on.
inline std::string jsonText(const Json& doc, int indent = -1) {
  return doc.dump(indent, ' ', false, Json::error_handler_t::replace) + "\n";
}

}  // namespace alacs::tools

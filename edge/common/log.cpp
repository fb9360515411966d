#include "common/log.h"

#include <unistd.h>

#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace alacs::log {
namespace {
std::atomic<int> gLevel{static_cast<int>(Level::kInfo)};

const char* levelName(Level level) {
  switch (level) {
    case Level::kError: return "E";
    case Level::kWarning: return "W";
    case Level::kInfo: return "I";
    case Level::kDebug: return "D";
  }
  return "?";
}
}  // namespace

void setLevel(Level level) { gLevel.store(static_cast<int>(level)); }

bool parseLevel(const char* text, Level* out) {
  struct Entry { const char* name; Level level; };
  static const Entry kEntries[] = {{"error", Level::kError},
                                   {"warning", Level::kWarning},
                                   {"info", Level::kInfo},
                                   {"debug", Level::kDebug}};
  for (const auto& e : kEntries) {
    if (std::strcmp(text, e.name) == 0) {
      *out = e.level;
      return true;
    }
  }
  return false;
}

void write(Level level, const char* component, const char* fmt, ...) {
  if (static_cast<int>(level) > gLevel.load()) return;
  static const bool kJournal = std::getenv("JOURNAL_STREAM") != nullptr;
  char line[1024];
  int n = kJournal ? std::snprintf(line, sizeof line, "<%d>%s: ", static_cast<int>(level), component)
                   : std::snprintf(line, sizeof line, "alacsd %s %s: ", levelName(level), component);
  if (n < 0) return;
  va_list args;
  va_start(args, fmt);
  const int m = std::vsnprintf(line + n, sizeof line - static_cast<size_t>(n), fmt, args);
  va_end(args);
  if (m < 0) return;
  size_t len = static_cast<size_t>(n) + static_cast<size_t>(m);
  if (len > sizeof line - 2) len = sizeof line - 2;
  line[len++] = '\n';
  // One write(2) per line keeps lines whole when threads log at once.
  [[maybe_unused]] ssize_t w = ::write(2, line, len);
}

}  // namespace alacs::log

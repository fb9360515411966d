// Levelled logging to stderr, in the journal's `<N>` prefix format when run under
// systemd (JOURNAL_STREAM set), so `journalctl -p warning -u alacsd` works.
// Thread-safe: one line per call, written with a single write(2).
#pragma once

#include <cstdarg>

namespace alacs::log {

enum class Level { kError = 3, kWarning = 4, kInfo = 6, kDebug = 7 };

void setLevel(Level level);
bool parseLevel(const char* text, Level* out);
void write(Level level, const char* component, const char* fmt, ...)
    __attribute__((format(printf, 3, 4)));

}  // namespace alacs::log

#define ALACS_LOG_ERROR(c, ...) ::alacs::log::write(::alacs::log::Level::kError, c, __VA_ARGS__)
#define ALACS_LOG_WARN(c, ...) ::alacs::log::write(::alacs::log::Level::kWarning, c, __VA_ARGS__)
#define ALACS_LOG_INFO(c, ...) ::alacs::log::write(::alacs::log::Level::kInfo, c, __VA_ARGS__)
#define ALACS_LOG_DEBUG(c, ...) ::alacs::log::write(::alacs::log::Level::kDebug, c, __VA_ARGS__)

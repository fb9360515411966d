#include "app/process_memory.h"

#include <malloc.h>

#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>

namespace alacs::app {

namespace {
double statusMb(const char* key) {
  std::ifstream f("/proc/self/status");
  std::string line;
  const size_t n = std::strlen(key);
  while (std::getline(f, line))
    if (line.compare(0, n, key) == 0 && line.size() > n && line[n] == ':') return std::atof(line.c_str() + n + 1) / 1024.0;
  return 0.0;
}
}  // namespace

void mapLargeBlocks() { (void)mallopt(M_MMAP_THRESHOLD, 1 << 20); }

double peakResidentMb() { return statusMb("VmHWM"); }

double residentMb() { return statusMb("VmRSS"); }

}  // namespace alacs::app

// The daemon's memory policy and its measurement (docs/daemon.md, "Memory").
#pragma once

namespace alacs::app {

// Blocks of 1 MiB and more (frames: 15 MB at 5 MP) are mapped and unmapped by malloc
// itself rather than kept in a heap after free. Without it glibc raises its mmap
// threshold after the first frame is freed, serves later frames from the heap of the
// thread that asks, and keeps them resident there after free (measured with
// alacs_cycle --replay: +14 MB for every new worker thread). Call first thing in main().
void mapLargeBlocks();

// This process's peak and current resident set (VmHWM, VmRSS), MB; 0 without /proc.
double peakResidentMb();
double residentMb();

}  // namespace alacs::app

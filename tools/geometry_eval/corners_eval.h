// alacs_geometry_eval corners: every corner detector on the board views of a twin
// calibration set, against the twin's exact corners (truth/corners.csv).
#pragma once

#include <string>
#include <vector>

namespace alacs::eval {

struct CornersEvalOptions {
  std::string scansDir;              // a directory of scan directories (alacs-twin calib)
  std::vector<double> windowShares;  // cv::cornerSubPix windows to compare (CornerOptions)
  bool verbose = false;              // one line per view and detector, with the reason of a miss
  bool defaultOnly = false;          // only the default detector (CornerOptions{}): fast, for CI
  int minDetected = 0;               // exit 4 when the default detector finds fewer views
  double maxRmsPx = 0.0;             // exit 4 when its corner RMS is above this (0: no limit)
};

// Prints per detector: views detected, corner RMS, median per-view RMS, max and mean
// offset (px) against the truth. Returns the exit status (0, 1 on error, 4 on a limit).
int cornersEval(const CornersEvalOptions& options);

}  // namespace alacs::eval

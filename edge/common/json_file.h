// Reads a JSON file into OpenCV's FileStorage (the JSON reader we already depend on),
// for the configuration, the calibration and scene files.
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "common/result.h"

namespace alacs {

// `what` names the file's role in errors ("config file", "calibration file").
// Errors: kNotFound when it cannot be opened, kBadInput when it is not JSON.
Result<cv::FileStorage> openJsonFile(const std::string& path, const std::string& what);

}  // namespace alacs

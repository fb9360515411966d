// libcamera adapter: a FrameSource on the first (or the named) camera, RGB888 frames
// with manual exposure. Kept thin because libcamera's API is not stable before 1.0:
// version differences are confined to libcamera_source.cpp (ALACS_LIBCAMERA_VERSION_NUM).
#pragma once

#include <memory>
#include <string>

#include "ports/frame_source.h"

namespace alacs::drivers {

struct LibcameraConfig {
  std::string cameraId;  // empty: the first camera
  int widthPx = 2048;
  int heightPx = 1536;
  int retries = 2;       // re-queues after a timeout or a failed request before giving up
};

class LibcameraSource : public ports::FrameSource {
 public:
  // Errors: kNotFound when no camera is present, kIo when it cannot be configured.
  static Result<std::unique_ptr<LibcameraSource>> open(const LibcameraConfig& config);
  // The number of cameras libcamera sees (diagnostics; 0 on a PC without one).
  static Result<int> countCameras();
};

}  // namespace alacs::drivers

// libFuzzer: calibration.json (geometry/calibration). A calibration that validates writes
// back to the same calibration.
#include "fuzz_json.h"
#include "geometry/calibration.h"

using namespace alacs;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  Result<Json> json = fuzz::parse(data, size);
  if (!json) return 0;
  geometry::Calibration cal;
  const Status s = geometry::calibrationFromJson(*json, cal);
  fuzz::checkMessage(s);
  if (!s) return 0;
  const Status valid = geometry::validateCalibration(cal);
  fuzz::checkMessage(valid);
  if (!valid) return 0;
  const OrderedJson written = geometry::calibrationToJson(cal);
  geometry::Calibration again;
  fuzz::check(geometry::calibrationFromJson(Json(written), again).isOk(), "a written calibration reads back");
  fuzz::check(geometry::calibrationToJson(again) == written, "a written calibration reads back the same");
  return 0;
}

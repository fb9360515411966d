// libFuzzer: the calibration gate's limits file (geometry/calibration_gate). Limits that
// load write back to the same limits.
#include "fuzz_json.h"
#include "geometry/calibration_gate.h"

using namespace alacs;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  Result<Json> json = fuzz::parse(data, size);
  if (!json) return 0;
  geometry::CalibrationLimits limits;
  const Status s = geometry::CalibrationLimits::fromJson(*json, limits);
  fuzz::checkMessage(s);
  if (!s) return 0;
  const OrderedJson written = limits.toJson();
  geometry::CalibrationLimits again;
  fuzz::check(geometry::CalibrationLimits::fromJson(Json(written), again).isOk(), "written limits read back");
  fuzz::check(again.toJson() == written, "written limits read back the same");
  return 0;
}

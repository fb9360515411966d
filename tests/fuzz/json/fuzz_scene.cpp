// libFuzzer: the simulator's scene file (sim/scene), over the default scene as loadScene
// does. A scene that validates writes back to the same scene.
#include "fuzz_json.h"
#include "sim/scene.h"

using namespace alacs;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  Result<Json> json = fuzz::parse(data, size);
  if (!json) return 0;
  sim::SimScene scene = sim::defaultScene();
  const Status s = sim::sceneFromJson(*json, scene);
  fuzz::checkMessage(s);
  if (!s) return 0;
  const Status valid = scene.validate();
  fuzz::checkMessage(valid);
  if (!valid) return 0;
  const OrderedJson written = sim::sceneToJson(scene);
  sim::SimScene again = sim::defaultScene();
  fuzz::check(sim::sceneFromJson(Json(written), again).isOk(), "a written scene reads back");
  fuzz::check(again.validate().isOk(), "a written scene validates");
  return 0;
}

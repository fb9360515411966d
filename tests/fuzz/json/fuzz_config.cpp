// libFuzzer: alacsd's configuration (app/config). A config that loads writes back to the
// same config.
#include "app/config.h"
#include "fuzz_json.h"

using namespace alacs;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  Result<Json> json = fuzz::parse(data, size);
  if (!json) return 0;
  app::DaemonConfig c;
  const Status s = app::configFromJson(*json, c);
  fuzz::checkMessage(s);
  if (!s) return 0;
  fuzz::checkMessage(app::validateConfig(c));
  const OrderedJson written = app::configToJson(c);
  app::DaemonConfig again;
  fuzz::check(app::configFromJson(Json(written), again).isOk(), "a written config reads back");
  fuzz::check(app::configToJson(again) == written, "a written config reads back the same");
  return 0;
}

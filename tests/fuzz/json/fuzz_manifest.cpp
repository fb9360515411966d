// libFuzzer: a scan directory's manifest.json (replay/scan_dir). A manifest that loads
// writes back to the same manifest; every crop it accepts lies inside the frame.
#include "fuzz_json.h"
#include "replay/scan_dir.h"

using namespace alacs;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  Result<Json> json = fuzz::parse(data, size);
  if (!json) return 0;
  replay::ScanManifest m;
  const Status s = replay::manifestFromJson(*json, m);
  fuzz::checkMessage(s);
  if (!s) return 0;
  for (const replay::FrameRecord& f : m.frames) {
    if (!f.cropPx) continue;
    const image::Roi& r = *f.cropPx;
    fuzz::check(r.x >= 0 && r.y >= 0 && r.width > 0 && r.height > 0 &&
                    int64_t{r.x} + r.width <= m.scan.widthPx && int64_t{r.y} + r.height <= m.scan.heightPx,
                "an accepted crop lies inside the frame");
  }
  const OrderedJson written = replay::manifestToJson(m);
  replay::ScanManifest again;
  fuzz::check(replay::manifestFromJson(Json(written), again).isOk(), "a written manifest reads back");
  fuzz::check(replay::manifestToJson(again) == written, "a written manifest reads back the same");
  return 0;
}

// The JSON readers of every file edge/ reads: the shared machinery (edge/common/json_file)
// and each loader's behaviour on hostile input (config, calibration, scene, manifest,
// calibration limits).
#include <sys/stat.h>
#include <unistd.h>

#include <catch2/catch.hpp>
#include <fstream>
#include <set>

#include "app/config.h"
#include "common/json_file.h"
#include "geometry/calibration.h"
#include "geometry/calibration_gate.h"
#include "replay/scan_dir.h"
#include "sim/scene.h"
#include "temp_dir.h"

using namespace alacs;

namespace {

const test::TempDir& dir() {
  static const test::TempDir d("alacs_json");  // removed when the test program ends
  return d;
}
std::string write(const std::string& text) {
  static int n = 0;
  return dir().write("f" + std::to_string(n++) + ".json", text);
}
std::string nested(size_t depth) { return std::string(depth, '[') + std::string(depth, ']'); }

geometry::Calibration goodCalibration() {
  geometry::Calibration cal;
  cal.camera.distortion = {-0.08, 0.12, 0.0005, -0.0003, 0.0};
  cal.laser.planeNormal = Eigen::Vector3d(0.98, -0.02, 0.16).normalized();
  cal.laser.slideAxis = Eigen::Vector3d(1.0, 0.012, 0.004).normalized();
  cal.laser.planeOffsetMm = 95.0;
  return cal;
}

bool has(const Status& s, const std::string& text) { return s.reason().find(text) != std::string::npos; }

}  // namespace

TEST_CASE("JSON: nesting is limited while parsing", "[json]") {
  CHECK(parseJson(nested(kJsonMaxDepth), "t").isOk());
  const Result<Json> deep = parseJson(nested(kJsonMaxDepth + 1), "t");
  REQUIRE_FALSE(deep.isOk());
  CHECK(deep.status().code() == Error::kBadInput);
  CHECK(has(deep.status(), "deeper than 32"));
  CHECK(has(deep.status(), "column 33"));
  // 120 KB deep: refused, not a stack overflow.
  CHECK(parseJson(nested(120000), "t").status().code() == Error::kBadInput);
  CHECK(parseJson("{\"a\": " + nested(120000) + "}", "t").status().code() == Error::kBadInput);
}

TEST_CASE("JSON: a parse error is one line with line, column and at most 120 characters of input", "[json]") {
  // A long file whose last line is broken: the message quotes that line's part, not the file.
  std::string text = "{\n";
  for (int i = 0; i < 100000; ++i) text += "  \"k" + std::to_string(i) + "\": " + std::string(10, '7') + ",\n";
  text += "  \"bad\": " + std::string(1000, 'x') + "\n}\n";
  const Result<Json> r = parseJson(text, "config file 'x'");
  REQUIRE_FALSE(r.isOk());
  const std::string& reason = r.status().reason();
  CHECK(reason.find("line 100002") != std::string::npos);
  CHECK(reason.find("column 10") != std::string::npos);
  CHECK(reason.find('\n') == std::string::npos);
  CHECK(reason.size() < 400);
  CHECK(reason.find("xxxxxxxxxx") != std::string::npos);
  CHECK(reason.find("k99999") == std::string::npos);
}

TEST_CASE("JSON: only regular files, and not too large ones", "[json]") {
  CHECK(readJsonFile("/nonexistent/x.json", "t").status().code() == Error::kNotFound);
  const Result<Json> zero = readJsonFile("/dev/zero", "t");
  CHECK(zero.status().code() == Error::kBadInput);
  CHECK(has(zero.status(), "not a regular file"));
  CHECK(readJsonFile(dir().path(), "t").status().code() == Error::kBadInput);
  const std::string fifo = dir().file("fifo");
  REQUIRE(::mkfifo(fifo.c_str(), 0600) == 0);
  // Returns at once: the open does not wait for a writer.
  CHECK(has(readJsonFile(fifo, "t").status(), "not a regular file"));
  const std::string big = write("[" + std::string(2000, ' ') + "]");
  CHECK(readJsonFile(big, "t", 2002).isOk());
  CHECK(has(readJsonFile(big, "t", 1000).status(), "larger than 1000 bytes"));
  CHECK(app::loadConfig("/dev/zero").status().code() == Error::kBadInput);
}

TEST_CASE("JSON: typed accessors name the field, tell wrong type from missing, refuse unknown keys", "[json]") {
  const Json j = Json::parse(R"({"laser": {"plane_normal": "up", "max_on_msec": 5}, "n": 2.5, "big": 9.3e18})");
  {
    JsonErrors e("t");
    JsonObjectReader root(e, &j, "");
    auto laser = root.object("laser");
    REQUIRE(laser);
    std::array<double, 3> v{};
    CHECK_FALSE(laser->numbers("plane_normal", v));
    CHECK(e.status().reason() ==
          "t field 'laser.plane_normal' wrong type (expected an array of 3 numbers, got string)");
  }
  {
    JsonErrors e("t");
    JsonObjectReader root(e, &j, "");
    double x = 0;
    CHECK_FALSE(root.number("absent", x, Need::kRequired));
    CHECK(e.status().reason() == "t field 'absent' is missing");
  }
  {
    JsonErrors e("t");
    JsonObjectReader root(e, &j, "");
    auto laser = root.object("laser");
    int64_t ms = 0;
    laser->integer("max_on_ms", ms);
    laser->allow("plane_normal");
    CHECK_FALSE(laser->finish());
    CHECK(e.status().reason() == "t: unknown key 'laser.max_on_msec' (did you mean 'laser.max_on_ms'?)");
  }
  {
    JsonErrors e("t");
    JsonObjectReader root(e, &j, "");
    int n = 0;
    CHECK_FALSE(root.integer("n", n));
    CHECK(has(e.status(), "must be an integer"));
  }
  {
    // 2^63 and beyond: refused, never converted.
    JsonErrors e("t");
    JsonObjectReader root(e, &j, "");
    int64_t big = 0;
    CHECK_FALSE(root.integer("big", big, Need::kOptional, 0, std::numeric_limits<int64_t>::max()));
    CHECK(has(e.status(), "big"));
  }
  {
    // An array is bounded before its elements are read.
    const Json a = Json::parse(R"({"xs": [1, 2, 3, 4]})");
    JsonErrors e("t");
    JsonObjectReader root(e, &a, "");
    std::vector<double> xs;
    CHECK_FALSE(root.numberList("xs", xs, 3));
    CHECK(has(e.status(), "'xs' holds 4 elements, more than 3"));
  }
}

TEST_CASE("Config: a section that is not an object is refused, naming it", "[config]") {
  const auto can = app::loadConfig(write(R"({"can": 5})"));
  REQUIRE_FALSE(can.isOk());
  CHECK(has(can.status(), "'can' wrong type (expected object, got number)"));
  const auto gpio = app::loadConfig(write(R"({"gpio": "x"})"));
  REQUIRE_FALSE(gpio.isOk());
  CHECK(has(gpio.status(), "'gpio' wrong type (expected object, got string)"));
  CHECK(has(app::loadConfig(write("[1, 2]")).status(), "(root)"));
  CHECK(app::loadConfig(write(nested(120000))).status().code() == Error::kBadInput);
}

TEST_CASE("Config: wrong type is not 'missing', unknown keys are refused with a suggestion", "[config]") {
  const auto type = app::loadConfig(write(R"({"camera": {"exposure_us": "3000"}})"));
  CHECK(has(type.status(), "'camera.exposure_us' wrong type (expected integer, got string)"));
  const auto unknown = app::loadConfig(write(R"({"laser": {"max_on_msec": 99999}})"));
  REQUIRE_FALSE(unknown.isOk());
  CHECK(has(unknown.status(), "unknown key 'laser.max_on_msec' (did you mean 'laser.max_on_ms'?)"));
  CHECK(has(app::loadConfig(write(R"({"camra": {}})")).status(), "did you mean 'camera'?"));
  const auto parse = app::loadConfig(write("{\n  \"can\": {\"node_id\": 5,}\n}\n"));
  CHECK(has(parse.status(), "line 2"));
  CHECK(parse.status().reason().find("cv::") == std::string::npos);
}

TEST_CASE("Config: can.auto_start decides whether the node waits for NMT START", "[config]") {
  const auto defaults = app::loadConfig(write("{}"));
  REQUIRE(defaults.isOk());
  CHECK(defaults->nmtAutoStart);
  const auto wait = app::loadConfig(write(R"({"can": {"auto_start": false}})"));
  REQUIRE(wait.isOk());
  CHECK_FALSE(wait->nmtAutoStart);
  CHECK(has(app::loadConfig(write(R"({"can": {"auto_start": 0}})")).status(), "can.auto_start"));
}

TEST_CASE("Config: the frame timeout cannot hide behind the laser's on-time limit", "[config]") {
  const auto defaults = app::loadConfig(write("{}"));
  REQUIRE(defaults.isOk());
  CHECK(defaults->frameTimeoutMs == 150);
  const auto longTimeout = app::loadConfig(write(R"({"camera": {"frame_timeout_ms": 1000}})"));
  REQUIRE_FALSE(longTimeout.isOk());
  CHECK(has(longTimeout.status(), "'camera.frame_timeout_ms' (1000)"));
  CHECK(has(longTimeout.status(), "laser.max_on_ms (250)"));
  // 240 ms + 3 ms of exposure fits in 250; 248 + 3 does not.
  CHECK(app::loadConfig(write(R"({"camera": {"frame_timeout_ms": 240}})")).isOk());
  CHECK_FALSE(app::loadConfig(write(R"({"camera": {"frame_timeout_ms": 248}})")).isOk());
  // The shipped file passes, and writing the defaults and reading them back is the identity.
  const auto shipped = app::loadConfig(std::string(ALACS_SOURCE_DIR) + "/firmware/config/alacsd.json");
  INFO(shipped.status().toString());
  REQUIRE(shipped.isOk());
  CHECK(shipped->frameTimeoutMs == 150);
  const auto round = app::loadConfig(write(app::configToJson(app::DaemonConfig{}).dump()));
  REQUIRE(round.isOk());
  CHECK(app::configToJson(*round) == app::configToJson(app::DaemonConfig{}));
}

namespace {
// Values near `v` of its own type to set a config key to: one of them is within the key's
// range and passes the rules between fields.
std::vector<Json> besides(const Json& v) {
  if (v.is_boolean()) return {!v.get<bool>()};
  if (v.is_number_integer()) return {v.get<int64_t>() + 1, v.get<int64_t>() - 1, v.get<int64_t>() * 2};
  if (v.is_number_float()) {
    const double d = v.get<double>();
    return {d * 1.25 + 0.125, d * 0.8, d + 1.0, d - 0.125};
  }
  if (v.is_string()) return {v.get<std::string>() + "1", "x"};
  return {};
}

void leaves(const Json& j, const Json::json_pointer& at, std::vector<Json::json_pointer>& out) {
  if (!j.is_object()) {
    out.push_back(at);
    return;
  }
  for (const auto& [key, value] : j.items()) leaves(value, at / key, out);
}
}  // namespace

TEST_CASE("Config: every key written is read back, each set away from its default", "[config]") {
  // The round trip of the defaults alone cannot see a key the loader ignores (it starts from
  // the defaults) or one configToJson forgets to write: here each key in turn is set to
  // another value, loaded, and written out again.
  const Json defaults = Json::parse(app::configToJson(app::DaemonConfig{}).dump());
  std::vector<Json::json_pointer> keys;
  leaves(defaults, Json::json_pointer(), keys);
  CHECK(keys.size() >= 40);
  // ... and it writes every key the shipped file has, no more (a key it forgot would never
  // be set below).
  std::ifstream shippedFile(std::string(ALACS_SOURCE_DIR) + "/firmware/config/alacsd.json");
  std::vector<Json::json_pointer> shippedKeys;
  leaves(Json::parse(shippedFile), Json::json_pointer(), shippedKeys);
  const auto names = [](const std::vector<Json::json_pointer>& ps) {
    std::set<std::string> out;
    for (const auto& p : ps) out.insert(p.to_string());
    return out;
  };
  CHECK(names(keys) == names(shippedKeys));
  std::vector<std::string> neverSet;
  for (const Json::json_pointer& key : keys) {
    bool set = false;
    for (const Json& value : besides(defaults[key])) {
      Json doc = defaults;
      doc[key] = value;
      const auto loaded = app::loadConfig(write(doc.dump()));
      if (!loaded) continue;  // out of its range, or against a rule between fields
      const Json back = Json::parse(app::configToJson(*loaded).dump());
      INFO(key.to_string() << " set to " << value.dump() << ", written back as " << back[key].dump());
      if (value.is_number_float())
        CHECK(back[key].get<double>() == Approx(value.get<double>()).epsilon(1e-9));
      else
        CHECK(back[key] == value);
      set = true;
      break;
    }
    if (!set) neverSet.push_back(key.to_string());
  }
  std::string list;
  for (const std::string& k : neverSet) list += k + " ";
  INFO("keys no nearby value could be set to: " << list);
  CHECK(neverSet.empty());
}

TEST_CASE("Calibration: JSON round trip, deep nesting and typed errors", "[calibration]") {
  const geometry::Calibration cal = goodCalibration();
  const std::string path = dir().file("cal.json");
  REQUIRE(geometry::saveCalibration(cal, path).isOk());
  const auto back = geometry::loadCalibration(path);
  REQUIRE(back.isOk());
  CHECK(back->laser.planeNormal == cal.laser.planeNormal);
  CHECK(back->camera.distortion == cal.camera.distortion);
  CHECK(geometry::calibrationToJson(*back) == geometry::calibrationToJson(cal));

  CHECK(geometry::loadCalibration(write(nested(120000))).status().code() == Error::kBadInput);
  Json j = geometry::calibrationToJson(cal);
  j["laser"]["plane_normal"] = "x";
  const auto type = geometry::loadCalibration(write(j.dump()));
  CHECK(has(type.status(), "'laser.plane_normal' wrong type"));
  j = geometry::calibrationToJson(cal);
  j["camera"].erase("fx_px");
  CHECK(has(geometry::loadCalibration(write(j.dump())).status(), "'camera.fx_px' is missing"));
  j = geometry::calibrationToJson(cal);
  j["camera"] = 5;
  CHECK(has(geometry::loadCalibration(write(j.dump())).status(), "'camera' wrong type (expected object, got number)"));
  j = geometry::calibrationToJson(cal);
  j["laser"]["slide_scales"] = 1.0;
  CHECK(has(geometry::loadCalibration(write(j.dump())).status(), "did you mean 'laser.slide_scale'?"));
}

TEST_CASE("Calibration: a distortion that folds the frame or is out of the model's range is refused", "[calibration]") {
  geometry::Calibration cal = goodCalibration();
  CHECK(geometry::validateCalibration(cal).isOk());
  // A strong but real wide-angle barrel distortion still passes.
  cal.camera.distortion = {-0.3, 0.1, 0.0, 0.0, 0.0};
  CHECK(geometry::validateCalibration(cal).isOk());

  cal.camera.distortion = {9.9, 0.0, 0.0, 0.0, 0.0};
  const Status k1 = geometry::validateCalibration(cal);
  REQUIRE_FALSE(k1.isOk());
  CHECK(has(k1, "camera.distortion"));

  // Tangential alone, radial zero: the old radial-only check passed this.
  cal.camera.distortion = {0.0, 0.0, 0.6, 0.0, 0.0};
  const Status tangential = geometry::validateCalibration(cal);
  REQUIRE_FALSE(tangential.isOk());
  CHECK(has(tangential, "camera.distortion"));
  CHECK(has(tangential, "% of the frame"));
  cal.camera.distortion = {0.0, 0.0, 0.0, -0.6, 0.0};
  CHECK(has(geometry::validateCalibration(cal), "% of the frame"));
}

TEST_CASE("Calibration limits: unknown keys and wrong types are refused", "[calibration]") {
  CHECK(geometry::CalibrationLimits::load(write(R"({"max_laser_rms_px": 0.7})"))->maxLaserRmsPx == 0.7);
  CHECK(has(geometry::CalibrationLimits::load(write(R"({"max_laser_rms": 0.7})")).status(),
            "did you mean 'max_laser_rms_px'?"));
  CHECK(has(geometry::CalibrationLimits::load(write(R"({"min_camera_views": "8"})")).status(),
            "'min_camera_views' wrong type"));
  CHECK(geometry::CalibrationLimits::load(write(nested(120000))).status().code() == Error::kBadInput);
}

TEST_CASE("Scene: hostile files are refused by field, and the calibration schema is geometry's", "[sim]") {
  const auto apples = sim::loadScene(write(R"({"apples": [5]})"));
  REQUIRE_FALSE(apples.isOk());
  CHECK(has(apples.status(), "'apples[0]' wrong type (expected object, got number)"));
  CHECK(sim::loadScene(write(nested(120000))).status().code() == Error::kBadInput);
  CHECK(has(sim::loadScene(write(R"({"sensor": {"gain": 3}})")).status(), "did you mean 'sensor.gain_db'?"));
  // A partial camera no longer falls back silently to the default's other fields.
  const auto partial = sim::loadScene(write(R"({"camera": {"fx_px": 2000}})"));
  CHECK(has(partial.status(), "'camera.width_px' is missing"));
  CHECK(has(sim::loadScene(write(R"({"laser_plane": {"slide_scale": "1"}})")).status(), "laser_plane."));

  sim::SimScene scene = sim::defaultScene();
  scene.board = sim::SimBoard{};
  const std::string path = dir().file("scene.json");
  REQUIRE(sim::saveScene(scene, path).isOk());
  const auto back = sim::loadScene(path);
  INFO(back.status().toString());
  REQUIRE(back.isOk());
  CHECK(sim::sceneToJson(*back) == sim::sceneToJson(scene));
}

TEST_CASE("Manifest: hostile files are refused by field, and it round-trips", "[replay]") {
  const test::TempDir tmp("alacs_json_scan");
  const std::string head = R"({"format": "alacs-scan/1", "scan": {"width_px": 64, "height_px": 48}, "frames": )";
  tmp.write("manifest.json", head + "[5]}");
  CHECK(has(replay::readManifest(tmp.path()).status(), "'frames[0]' wrong type (expected object, got number)"));
  tmp.write("manifest.json", head + nested(120000) + "}");
  CHECK(replay::readManifest(tmp.path()).status().code() == Error::kBadInput);
  const std::string frame = R"({"file": "a.png", "slide_mm": 1, "timestamp_s": 0, "exposure_us": 10, "laser_on": true, )";
  tmp.write("manifest.json", head + "[" + frame + R"("crop_px": [2147483647, 0, 1, 16]}]})");
  CHECK(has(replay::readManifest(tmp.path()).status(), "frames[0].crop_px"));
  tmp.write("manifest.json", head + "[" + frame + R"("crop": [0, 0, 1, 16]}]})");
  CHECK(has(replay::readManifest(tmp.path()).status(), "did you mean 'frames[0].crop_px'?"));

  replay::ScanManifest m;
  m.scan.widthPx = 64;
  m.scan.heightPx = 48;
  m.scan.roughMm = Eigen::Vector3d(1, 2, 3);
  m.scan.stopsMm = {1.5, 2.5};
  m.scan.note = "a \"quoted\" note";
  replay::FrameRecord f;
  f.file = "frames/frame_0000.png";
  f.slideMm = 1.25;
  f.slideStartMm = 1.0;
  f.exposureUs = 300;
  f.cropPx = image::Roi{1, 2, 3, 4};
  m.frames.push_back(f);
  REQUIRE(replay::writeManifest(tmp.path(), m).isOk());
  const auto back = replay::readManifest(tmp.path());
  INFO(back.status().toString());
  REQUIRE(back.isOk());
  CHECK(replay::manifestToJson(*back) == replay::manifestToJson(m));
}

// Scan directories: the manifest round trip and its errors, the replay source (nearest
// frame, laser state, crops, the recorded position), the recorder, and the property that
// matters: a scan exported by the twin and replayed gives the localizer exactly what the
// live frames gave it.
#include <catch2/catch.hpp>

#include <stdlib.h>
#include <sys/stat.h>

#include <cmath>
#include <opencv2/imgcodecs.hpp>

#include "localize/exposure.h"
#include "localize/localizer.h"
#include "replay/replay_source.h"
#include "replay/scan_dir.h"
#include "replay/scan_recorder.h"
#include "sim/renderer.h"
#include "sim/scan_export.h"
#include "sim/scene.h"
#include "temp_dir.h"

using namespace alacs;

namespace {

// A source that hands out a frame whose every pixel holds its sequence number.
class CountingSource final : public ports::FrameSource {
 public:
  const char* name() const override { return "counting"; }

 private:
  Result<ports::CapturedFrame> doCapture(const ports::CaptureRequest& request,
                                         const ports::ExposureHooks& hooks) override {
    if (Status s = hooks.beginNow(); !s) return s;
    hooks.endNow();
    frame_ = cv::Mat(48, 64, CV_8UC3, cv::Scalar::all(static_cast<double>(10 + sequence_)));
    ports::CapturedFrame f;
    f.view = {frame_.data, frame_.cols, frame_.rows, frame_.step[0], image::PixelFormat::kBgr888};
    f.info.sequence = sequence_++;
    f.info.exposureStartNs = static_cast<TimeNs>(sequence_) * kNsPerMs;
    f.info.exposureUs = request.exposureUs;
    return f;
  }
  cv::Mat frame_;
  uint64_t sequence_ = 0;
};

geometry::Calibration smallCalibration() {
  geometry::Calibration cal = sim::defaultScene().truth;
  cal.camera.widthPx = 64;
  cal.camera.heightPx = 48;
  cal.camera.fxPx = 75.0;
  cal.camera.fyPx = 75.0;
  cal.camera.cxPx = 31.5;
  cal.camera.cyPx = 23.5;
  return cal;
}

}  // namespace

TEST_CASE("A manifest reads back as written", "[replay]") {
  const test::TempDir tmp("alacs_replay");
  const std::string dir = tmp.path();
  replay::ScanManifest m;
  m.scan.kind = "localize";
  m.scan.source = "test";
  m.scan.widthPx = 2048;
  m.scan.heightPx = 1536;
  m.scan.targetId = 7;
  m.scan.roughMm = Eigen::Vector3d(12.5, -30.25, 1234.0);
  m.scan.stopsMm = {60.0, 80.0, 100.0};
  m.scan.roiPx = image::Roi{100, 200, 300, 400};
  m.scan.note = "a \"quoted\" note";
  replay::FrameRecord f;
  f.file = "frames/frame_0000.png";
  f.slideMm = 61.25;
  f.slideStartMm = 60.5;
  f.slideEndMm = 62.0;
  f.timestampS = 12345.000001234;
  f.exposureUs = 2500;
  f.analogueGain = 1.5;
  f.laserOn = false;
  f.cropPx = image::Roi{10, 20, 30, 40};
  f.truthFile = "truth/frame_0000.csv";
  f.tag = "aimed";
  m.frames.push_back(f);
  f.index = 1;
  f.file = "frames/frame_0001.png";
  f.laserOn = true;
  f.cropPx.reset();
  f.analogueGain = 0.0;  // not recorded
  f.slideStartMm = f.slideEndMm = std::nan("");
  m.frames.push_back(f);
  REQUIRE(replay::writeManifest(dir, m).isOk());
  Result<replay::ScanManifest> r = replay::readManifest(dir);
  REQUIRE(r.isOk());
  CHECK(r->scan.kind == "localize");
  CHECK(r->scan.source == "test");
  CHECK(r->scan.targetId == 7);
  REQUIRE(r->scan.roughMm);
  CHECK((*r->scan.roughMm - *m.scan.roughMm).norm() < 1e-9);
  CHECK(r->scan.stopsMm == m.scan.stopsMm);
  REQUIRE(r->scan.roiPx);
  CHECK(r->scan.roiPx->width == 300);
  CHECK(r->scan.note == m.scan.note);
  REQUIRE(r->frames.size() == 2);
  CHECK(r->frames[0].slideMm == 61.25);
  CHECK(r->frames[0].slideStartMm == 60.5);
  CHECK(std::abs(r->frames[0].timestampS - 12345.000001234) < 1e-9);
  CHECK(r->frames[0].exposureUs == 2500);
  CHECK(r->frames[0].analogueGain == 1.5);
  CHECK(r->frames[1].analogueGain == 0.0);
  CHECK_FALSE(r->frames[0].laserOn);
  REQUIRE(r->frames[0].cropPx);
  CHECK(r->frames[0].cropPx->height == 40);
  CHECK(r->frames[0].truthFile == "truth/frame_0000.csv");
  CHECK(r->frames[0].tag == "aimed");
  CHECK(r->frames[1].laserOn);
  CHECK_FALSE(r->frames[1].cropPx);
  CHECK(std::isnan(r->frames[1].slideStartMm));
}

TEST_CASE("A bad manifest is refused with the field named", "[replay]") {
  const test::TempDir tmp("alacs_replay");
  const std::string dir = tmp.path();
  const std::string head = R"({"format": "alacs-scan/1", "scan": {"width_px": 64, "height_px": 48}, "frames": [)";
  struct Case {
    const char* frames;
    const char* field;
  } cases[] = {
      {R"({"file": "frames/a.png", "timestamp_s": 0, "exposure_us": 10, "laser_on": true})", "frames[0].slide_mm"},
      {R"({"file": "frames/a.png", "slide_mm": 1, "timestamp_s": 0, "exposure_us": 0, "laser_on": true})", "frames[0].exposure_us"},
      {R"({"file": "../a.png", "slide_mm": 1, "timestamp_s": 0, "exposure_us": 10, "laser_on": true})", "frames[0].file"},
      {R"({"file": "a.png", "slide_mm": 1, "timestamp_s": 0, "exposure_us": 10, "laser_on": true, "crop_px": [60, 0, 10, 10]})", "frames[0].crop_px"},
      {R"({"file": "a.png", "slide_mm": 1, "timestamp_s": 0, "exposure_us": 10})", "frames[0].laser_on"},
  };
  for (const auto& c : cases) {
    tmp.write("manifest.json", head + c.frames + "]}");
    Result<replay::ScanManifest> r = replay::readManifest(dir);
    INFO(c.field);
    REQUIRE_FALSE(r.isOk());
    CHECK(r.status().code() == Error::kBadInput);
    CHECK(r.status().reason().find(c.field) != std::string::npos);
  }
  tmp.write("manifest.json", R"({"format": "alacs-scan/9", "scan": {}, "frames": []})");
  CHECK(replay::readManifest(dir).status().reason().find("format") != std::string::npos);
  CHECK(replay::readManifest(dir + "/none").status().code() == Error::kNotFound);
}

TEST_CASE("The frame replay serves: laser-off frames by exposure first, then position", "[replay]") {
  // (Laser frames by position, but a stop's second exposure by its exposure first.)
  replay::ScanManifest m;
  const auto add = [&](double slideMm, bool laserOn, int64_t exposureUs) {
    replay::FrameRecord f;
    f.slideMm = slideMm;
    f.laserOn = laserOn;
    f.exposureUs = exposureUs;
    m.frames.push_back(f);
  };
  CHECK(replay::nearestFrame(m, 10.0, false, 500) == -1);  // no frame at all
  add(10.0, true, 500);                                    // 0
  CHECK(replay::nearestFrame(m, 10.0, false, 500) == -1);  // no laser-off frame
  add(40.0, false, 3000);                                  // 1: a metering frame
  add(60.0, false, 500);                                   // 2: the laser frames' exposure
  add(0.0, false, 480);                                    // 3: near it, nearer in position
  add(20.0, true, 500);                                    // 4
  // Laser off: the exposure decides (ratio), the ambient being the same at every position.
  CHECK(replay::nearestFrame(m, 0.0, false, 500) == 2);
  CHECK(replay::nearestFrame(m, 0.0, false, 2500) == 1);
  CHECK(replay::nearestFrame(m, 0.0, false, 470) == 3);
  // Equal ratios (x2 and /2): the position.
  add(5.0, false, 1000);  // 5
  add(50.0, false, 250);  // 6
  CHECK(replay::nearestFrame(m, 0.0, false, 500) == 2);
  m.frames[2].exposureUs = 2000;
  m.frames[3].exposureUs = 2000;
  CHECK(replay::nearestFrame(m, 0.0, false, 500) == 5);
  CHECK(replay::nearestFrame(m, 60.0, false, 500) == 6);
  // No exposure asked: the position alone; laser on: the position alone.
  CHECK(replay::nearestFrame(m, 49.0, false) == 6);
  CHECK(replay::nearestFrame(m, 18.0, true, 99999) == 4);
  CHECK(replay::nearestFrame(m, 11.0, true) == 0);
  // A stop's second exposure (twice the first, at the same position): laser frames 1.25
  // times apart or more are told apart by exposure first; within 20 % they are one.
  add(10.0, true, 1000);  // 7: frame 0's second exposure
  CHECK(replay::nearestFrame(m, 10.0, true, 500) == 0);
  CHECK(replay::nearestFrame(m, 10.0, true, 1000) == 7);
  CHECK(replay::nearestFrame(m, 18.0, true, 1000) == 7);  // the only frame at it, though further
  CHECK(replay::nearestFrame(m, 18.0, true, 550) == 4);   // within 20 %: the position
  CHECK(replay::nearestFrame(m, 18.0, true, 400) == 4);   // nearest 500, and 1000 is not within 20 % of it
  CHECK(replay::nearestFrame(m, 18.0, true) == 4);        // no exposure asked: the position
  // With gains recorded, a frame at the gain asked for: the metering frame at gain 2 and
  // 500 us, the one subtracted at gain 1 and 1000 us. A frame without a gain recorded
  // matches on exposure alone.
  replay::ScanManifest g;
  const auto addGain = [&](int64_t exposureUs, double gain) {
    replay::FrameRecord f;
    f.laserOn = false;
    f.exposureUs = exposureUs;
    f.analogueGain = gain;
    g.frames.push_back(f);
  };
  addGain(500, 2.0);   // 0
  addGain(1000, 1.0);  // 1
  CHECK(replay::nearestFrame(g, 0.0, false, 1000, 1.0) == 1);
  CHECK(replay::nearestFrame(g, 0.0, false, 500, 2.0) == 0);
  CHECK(replay::nearestFrame(g, 0.0, false, 800, 2.0) == 0);  // 800 us alone is nearer 1000
  CHECK(replay::nearestFrame(g, 0.0, false, 800) == 1);
  addGain(600, 0.0);  // 2: no gain recorded
  CHECK(replay::nearestFrame(g, 0.0, false, 600, 1.0) == 2);
}

TEST_CASE("The replay source serves the nearest frame with the laser's state and reports its position", "[replay]") {
  const test::TempDir tmp("alacs_replay");
  const std::string dir = tmp.path();
  const geometry::Calibration cal = smallCalibration();
  replay::ScanInfo info;
  info.widthPx = 64;
  info.heightPx = 48;
  Result<replay::ScanWriter> w = replay::ScanWriter::create(dir, info, cal);
  REQUIRE(w.isOk());
  const double positions[] = {10.0, 20.0, 30.0};
  for (int i = 0; i < 3; ++i) {
    cv::Mat img(48, 64, CV_8UC3, cv::Scalar::all(50.0 + i));
    replay::FrameRecord rec;
    rec.slideMm = positions[i];
    rec.exposureUs = 1000 + i;
    rec.laserOn = true;
    REQUIRE(w->addFrame({img.data, img.cols, img.rows, img.step[0], image::PixelFormat::kBgr888}, rec).isOk());
  }
  // A laser-off frame stored as a crop: the rest of the frame replays as zero.
  cv::Mat crop(10, 20, CV_8UC3, cv::Scalar(1, 2, 3));
  replay::FrameRecord off;
  off.slideMm = 20.0;
  off.exposureUs = 500;
  off.laserOn = false;
  REQUIRE(w->addCrop(crop, image::Roi{5, 6, 20, 10}, off).isOk());
  REQUIRE(w->finish().isOk());

  VirtualClock clock;
  bool laser = true;
  double slide = 0.0;
  Result<std::unique_ptr<replay::ReplaySource>> src =
      replay::ReplaySource::open(dir, clock, [&] { return laser; }, [&] { return slide; });
  REQUIRE(src.isOk());
  ports::FrameSource& cam = **src;
  int ends = 0;
  slide = 21.0;
  Result<ports::CapturedFrame> f = cam.capture({}, ports::ExposureHooks([&] { ++ends; }));
  REQUIRE(f.isOk());
  CHECK(ends == 1);
  CHECK(f->view.width == 64);
  CHECK(f->view.data[0] == 51);  // the frame recorded at 20 mm
  CHECK(f->info.exposureUs == 1001);
  CHECK((*src)->lastSlideMm() == 20.0);
  CHECK(std::abs((*src)->lastPositionErrorMm() - 1.0) < 1e-12);
  slide = 100.0;
  f = cam.capture({}, {});
  REQUIRE(f.isOk());
  CHECK(f->view.data[0] == 52);
  CHECK((*src)->lastSlideMm() == 30.0);
  laser = false;
  f = cam.capture({}, {});
  REQUIRE(f.isOk());
  CHECK((*src)->lastSlideMm() == 20.0);
  CHECK(f->view.data[0] == 0);                                // outside the crop
  CHECK(f->view.row(6)[3 * 5 + 2] == 3);                      // inside it (B, G, R = 1, 2, 3)
  CHECK(f->view.row(15)[3 * 24] == 1);
  CHECK(f->view.row(16)[3 * 24] == 0);

  // A scan without laser-off frames cannot serve a dark frame.
  const test::TempDir tmp2("alacs_replay");
  const std::string dir2 = tmp2.path();
  Result<replay::ScanWriter> w2 = replay::ScanWriter::create(dir2, info, cal);
  REQUIRE(w2.isOk());
  cv::Mat img(48, 64, CV_8UC3, cv::Scalar::all(9));
  replay::FrameRecord rec;
  rec.exposureUs = 10;
  REQUIRE(w2->addFrame({img.data, img.cols, img.rows, img.step[0], image::PixelFormat::kBgr888}, rec).isOk());
  REQUIRE(w2->finish().isOk());
  auto src2 = replay::ReplaySource::open(dir2, clock, [] { return false; }, [] { return 0.0; });
  REQUIRE(src2.isOk());
  CHECK((*src2)->capture({}, {}).status().code() == Error::kNotFound);
}

TEST_CASE("The recorder writes each scan as a replayable scan directory", "[replay]") {
  const test::TempDir tmp("alacs_replay");
  const std::string root = tmp.path();
  replay::ScanRecorder rec(root, smallCalibration());
  double slide = 5.0;
  bool laser = true;
  CountingSource inner;
  replay::RecordingSource cam(inner, rec, [&] { return slide; }, [&] { return laser; });
  // Frames outside a scan are not recorded (and the camera still works).
  REQUIRE(cam.capture({}, {}).isOk());
  REQUIRE(rec.begin(3, Eigen::Vector3d(1, 2, 1000), {5.0, 25.0}, image::Roi{1, 2, 30, 20}).isOk());
  for (double s : {5.0, 25.0}) {
    slide = s;
    REQUIRE(cam.capture({}, {}).isOk());
  }
  Result<std::string> dir = rec.end();
  REQUIRE(dir.isOk());
  CHECK(*dir == root + "/scan_0001");
  Result<replay::ScanManifest> m = replay::readManifest(*dir);
  REQUIRE(m.isOk());
  CHECK(m->scan.source == "alacsd");
  CHECK(m->scan.targetId == 3);
  REQUIRE(m->frames.size() == 2);
  CHECK(m->frames[1].slideMm == 25.0);
  CHECK(m->frames[1].laserOn);
  REQUIRE(replay::loadScanCalibration(*dir, *m).isOk());
  Result<cv::Mat> img = replay::loadFrame(*dir, *m, m->frames[1]);
  REQUIRE(img.isOk());
  CHECK(img->at<cv::Vec3b>(0, 0)[0] == 12);  // the third capture (sequence 2)
  CHECK(rec.end().status().code() == Error::kInvalidArgument);
  // A windowed capture records only its window.
  REQUIRE(rec.begin(3, Eigen::Vector3d(1, 2, 1000), {5.0}, image::Roi{1, 2, 30, 20}).isOk());
  ports::CaptureRequest windowed;
  windowed.window = image::Roi{8, 4, 20, 10};
  REQUIRE(cam.capture(windowed, {}).isOk());
  Result<std::string> dir2 = rec.end();
  REQUIRE(dir2.isOk());
  Result<replay::ScanManifest> m2 = replay::readManifest(*dir2);
  REQUIRE(m2.isOk());
  REQUIRE(m2->frames.size() == 1);
  REQUIRE(m2->frames[0].cropPx);
  CHECK(m2->frames[0].cropPx->x == 8);
  CHECK(m2->frames[0].cropPx->width == 20);
  Result<cv::Mat> img2 = replay::loadFrame(*dir2, *m2, m2->frames[0]);
  REQUIRE(img2.isOk());
  CHECK(img2->at<cv::Vec3b>(0, 0)[0] == 0);    // outside the window: not recorded
  CHECK(img2->at<cv::Vec3b>(5, 9)[0] == 13);   // inside: the fourth capture
}

TEST_CASE("An exported twin scan replays into exactly the live estimate", "[replay][sim][render]") {
  sim::SimScene scene = sim::defaultScene();
  const auto rays = std::make_shared<const sim::RayTable>(scene.truth.camera);
  localize::Localizer loc(scene.truth, image::LleParams{}, localize::ScanParams{});
  const Eigen::Vector3d rough = scene.apples[0].centerMm + Eigen::Vector3d(-9, 7, 14);
  Result<localize::ScanPlan> plan = loc.plan(rough, 200.0);
  REQUIRE(plan.isOk());
  // Live: render each stop (only the plan's ROI and a margin: the localizer reads no more).
  const cv::Rect region(plan->roi.x - 16, plan->roi.y - 16, plan->roi.width + 32, plan->roi.height + 32);
  sim::Renderer renderer(scene, rays);
  image::LleWorkspace ws;
  std::vector<localize::LineObservation> live;
  std::vector<sim::ExportFrame> frames;
  for (size_t i = 0; i < plan->stopsMm.size(); ++i) {
    sim::FrameRequest req;
    req.slideStartMm = req.slideEndMm = plan->stopsMm[i];
    req.frameIndex = i;
    cv::Mat crop;
    renderer.renderRegion(req, region, crop);
    cv::Mat full = cv::Mat::zeros(scene.truth.camera.heightPx, scene.truth.camera.widthPx, CV_8UC3);
    crop.copyTo(full(region));
    auto obs = loc.observe({full.data, full.cols, full.rows, full.step[0], image::PixelFormat::kBgr888}, *plan,
                           plan->stopsMm[i], ws);
    REQUIRE(obs.isOk());
    live.push_back(*obs);
    frames.push_back({plan->stopsMm[i], plan->stopsMm[i], true, 0, 0.1 * static_cast<double>(i), "stop"});
  }
  Result<localize::AppleEstimate> liveEst = loc.estimate(*plan, live);
  REQUIRE(liveEst.isOk());

  // Export the same frames, replay them through the camera port, run the same code.
  const test::TempDir tmp("alacs_replay");
  const std::string dir = tmp.path() + "/scan";
  replay::ScanInfo info;
  info.roughMm = rough;
  info.stopsMm = plan->stopsMm;
  info.roiPx = plan->roi;
  sim::ExportOptions opt;
  opt.renderRegion = region;
  REQUIRE(sim::exportScan(scene, rays, dir, info, frames, opt).isOk());
  VirtualClock clock;
  double slide = 0.0;
  auto src = replay::ReplaySource::open(dir, clock, [] { return true; }, [&] { return slide; });
  REQUIRE(src.isOk());
  Result<geometry::Calibration> cal = replay::loadScanCalibration(dir, (*src)->manifest());
  REQUIRE(cal.isOk());
  localize::Localizer replayLoc(*cal, image::LleParams{}, localize::ScanParams{});
  std::vector<localize::LineObservation> replayed;
  for (double stop : plan->stopsMm) {
    slide = stop + 0.003;  // the slide's step grid: not exactly the planned position
    Result<ports::CapturedFrame> f = (*src)->capture({}, {});
    REQUIRE(f.isOk());
    auto obs = replayLoc.observe(f->view, *plan, (*src)->lastSlideMm(), ws);
    REQUIRE(obs.isOk());
    replayed.push_back(*obs);
  }
  Result<localize::AppleEstimate> est = replayLoc.estimate(*plan, replayed);
  REQUIRE(est.isOk());
  // The calibration file holds 12 significant digits: equal to a tenth of a micrometre.
  CHECK((est->centerMm - liveEst->centerMm).norm() < 1e-4);
  CHECK(est->diameterMm == Approx(liveEst->diameterMm).margin(1e-4));
  CHECK(est->pointsUsed == liveEst->pointsUsed);
  // And the truth travelled with it.
  Result<sim::SimScene> truth = sim::loadScene(dir + "/truth/scene.json");
  REQUIRE(truth.isOk());
  CHECK((truth->apples[0].centerMm - scene.apples[0].centerMm).norm() < 1e-6);
  CHECK((est->centerMm - truth->apples[0].centerMm).norm() < 5.0);
}

// Issue 15, finding 4: frame symlinks were followed out of the directory (to FIFOs and
// /etc/shadow), scan.calibration was not checked, 16384 x 16384 drove a 790 MB allocation.
TEST_CASE("A scan directory is contained: no symlink, no FIFO, no escape, no oversized frame", "[replay]") {
  const test::TempDir tmp("alacs_contained");
  const std::string root = tmp.path();
  replay::ScanRecorder rec(root, smallCalibration());
  bool laser = true;
  CountingSource inner;
  replay::RecordingSource cam(inner, rec, [] { return 5.0; }, [&] { return laser; });
  REQUIRE(rec.begin(1, Eigen::Vector3d(0, 0, 1000), {5.0}, image::Roi{0, 0, 64, 48}).isOk());
  REQUIRE(cam.capture({}, {}).isOk());
  Result<std::string> made = rec.end();
  REQUIRE(made.isOk());
  const std::string dir = *made;
  Result<replay::ScanManifest> m = replay::readManifest(dir);
  REQUIRE(m.isOk());
  REQUIRE(replay::loadFrame(dir, *m, m->frames[0]).isOk());
  const std::string outside = tmp.write("outside.png", "secret");
  const std::string frame = dir + "/" + m->frames[0].file;

  SECTION("a frame that is a symlink, even to a good PNG inside") {
    REQUIRE(::rename(frame.c_str(), (dir + "/frames/real.png").c_str()) == 0);
    REQUIRE(::symlink("real.png", frame.c_str()) == 0);
    const Status s = replay::loadFrame(dir, *m, m->frames[0]).status();
    CHECK(s.code() == Error::kBadInput);
    CHECK(s.reason().find("symlink") != std::string::npos);
  }
  SECTION("a frame that links out of the directory") {
    REQUIRE(::unlink(frame.c_str()) == 0);
    REQUIRE(::symlink(outside.c_str(), frame.c_str()) == 0);
    CHECK(replay::loadFrame(dir, *m, m->frames[0]).status().code() == Error::kBadInput);
  }
  SECTION("a directory on the way that is a symlink") {
    REQUIRE(::rename((dir + "/frames").c_str(), (dir + "/real_frames").c_str()) == 0);
    REQUIRE(::symlink("real_frames", (dir + "/frames").c_str()) == 0);
    CHECK(replay::loadFrame(dir, *m, m->frames[0]).status().code() == Error::kBadInput);
  }
  SECTION("a frame that is a FIFO is refused at once, not waited on") {
    REQUIRE(::unlink(frame.c_str()) == 0);
    REQUIRE(::mkfifo(frame.c_str(), 0600) == 0);
    const Status s = replay::loadFrame(dir, *m, m->frames[0]).status();
    CHECK(s.code() == Error::kBadInput);
    CHECK(s.reason().find("not a regular file") != std::string::npos);
  }
  SECTION("a calibration that links out, or a path that climbs out") {
    const std::string cal = dir + "/" + m->scan.calibrationFile;
    REQUIRE(::rename(cal.c_str(), (root + "/cal_outside.json").c_str()) == 0);
    REQUIRE(::symlink((root + "/cal_outside.json").c_str(), cal.c_str()) == 0);
    CHECK(replay::loadScanCalibration(dir, *m).status().code() == Error::kBadInput);
    replay::ScanManifest climbing = *m;
    climbing.scan.calibrationFile = "../cal_outside.json";
    CHECK(replay::loadScanCalibration(dir, climbing).status().code() == Error::kBadInput);
    climbing.scan.calibrationFile = root + "/cal_outside.json";
    CHECK(replay::loadScanCalibration(dir, climbing).status().code() == Error::kBadInput);
  }
  SECTION("a manifest whose frames would not fit a frame buffer is refused before any") {
    replay::ScanManifest big = *m;
    big.scan.widthPx = 8192;
    big.scan.heightPx = 8192;
    replay::ScanManifest back;
    const Status s = replay::manifestFromJson(Json::parse(replay::manifestJson(big)), back);
    CHECK(s.code() == Error::kBadInput);
    CHECK(s.reason().find("height_px") != std::string::npos);
    big.scan.widthPx = 16384;
    CHECK_FALSE(replay::manifestFromJson(Json::parse(replay::manifestJson(big)), back).isOk());
  }
}

// Issue 15, finding 5: with --record, LOCALIZE commands over CAN could fill the disk.
TEST_CASE("The recorder (--record) keeps to its quota: the oldest scans go, numbering goes on", "[replay]") {
  const test::TempDir tmp("alacs_quota");
  const std::string root = tmp.path();
  auto recordScans = [&](replay::ScanRecorder& rec, int scans, int frames) {
    CountingSource inner;
    replay::RecordingSource cam(inner, rec, [] { return 5.0; }, [] { return true; });
    for (int s = 0; s < scans; ++s) {
      REQUIRE(rec.begin(1, Eigen::Vector3d(0, 0, 1000), {5.0}, image::Roi{0, 0, 64, 48}).isOk());
      for (int f = 0; f < frames; ++f) REQUIRE(cam.capture({}, {}).isOk());
      REQUIRE(rec.end().isOk());
    }
  };
  SECTION("at most maxScans directories") {
    replay::RecordQuota q;
    q.maxScans = 2;
    {
      replay::ScanRecorder rec(root, smallCalibration(), "alacsd", q);
      recordScans(rec, 3, 1);
      CHECK(rec.scansKept() == std::vector<std::string>{root + "/scan_0002", root + "/scan_0003"});
    }
    // A restarted daemon counts what is there and numbers on.
    replay::ScanRecorder again(root, smallCalibration(), "alacsd", q);
    recordScans(again, 1, 1);
    CHECK(again.scansKept() == std::vector<std::string>{root + "/scan_0003", root + "/scan_0004"});
    struct stat st {};
    CHECK(::stat((root + "/scan_0002").c_str(), &st) != 0);
  }
  SECTION("at most maxBytes on disk") {
    replay::RecordQuota q;
    q.maxBytes = 20000;  // a few scans of two 64 x 48 frames (about 4 KB each, the calibration included)
    replay::ScanRecorder rec(root, smallCalibration(), "alacsd", q);
    recordScans(rec, 12, 2);
    CHECK(rec.bytesKept() <= q.maxBytes);
    CHECK(rec.scansKept().size() < 12);
    CHECK(rec.scansKept().back() == root + "/scan_0012");
  }
  SECTION("a scan that alone passes the limit stops being recorded, the camera goes on") {
    replay::RecordQuota q;
    q.maxBytes = 5000;  // less than one raw frame
    replay::ScanRecorder rec(root, smallCalibration(), "alacsd", q);
    REQUIRE(rec.begin(1, Eigen::Vector3d(0, 0, 1000), {5.0}, image::Roi{0, 0, 64, 48}).isOk());
    cv::Mat frame(48, 64, CV_8UC3, cv::Scalar::all(7));
    const image::ImageView view{frame.data, frame.cols, frame.rows, frame.step[0], image::PixelFormat::kBgr888};
    const Status s = rec.frame(view, 5.0, 0, 1000, true);
    CHECK(s.code() == Error::kIo);
    CHECK(s.reason().find("record quota") != std::string::npos);
    CHECK(rec.end().isOk());
  }
}

TEST_CASE("A scan recorded at one gain replays at it: no gain reported, so the metering does not lower it",
          "[replay][exposure]") {
  // Laser-off frames in sun (red 150 DN at 500 us: 300 DN/ms, bright) at the camera's gain 2;
  // the scan with the lower gain in sun also holds the one subtracted, at gain 1 (red 90).
  enum class Gains { kOne, kLowered, kMeteringOnly };
  const auto write = [](const std::string& dir, Gains gains) {
    const bool lowered = gains == Gains::kLowered;
    replay::ScanInfo info;
    info.widthPx = 64;
    info.heightPx = 48;
    Result<replay::ScanWriter> w = replay::ScanWriter::create(dir, info, smallCalibration());
    REQUIRE(w.isOk());
    const auto add = [&](int red, int64_t exposureUs, double gain, bool laserOn) {
      cv::Mat img(48, 64, CV_8UC3, cv::Scalar(0, 0, red));
      replay::FrameRecord rec;
      rec.exposureUs = exposureUs;
      rec.analogueGain = gain;
      rec.laserOn = laserOn;
      REQUIRE(w->addFrame({img.data, img.cols, img.rows, img.step[0], image::PixelFormat::kBgr888}, rec).isOk());
    };
    add(150, 500, 2.0, false);
    if (lowered) add(90, 1000, 1.0, false);
    // The camera's own gain moving between metering frames: no laser frame below it.
    if (gains == Gains::kMeteringOnly) add(150, 500, 1.6, false);
    add(200, lowered ? 1000 : 500, lowered ? 1.0 : 2.0, true);
    REQUIRE(w->finish().isOk());
  };
  const auto meter = [](replay::ReplaySource& src) {
    localize::MeteringParams p;  // the lower gain in sun on: brightAnalogueGain 1
    return localize::runMetering(p, 500, 2000, image::Roi{0, 0, 64, 48},
                                 [&](int64_t us, double gain, localize::LaserOffUse) -> Result<localize::LaserOffFrame> {
                                   ports::CaptureRequest req;
                                   req.exposureUs = us;
                                   req.analogueGain = gain;
                                   Result<ports::CapturedFrame> f = src.capture(req, {});
                                   if (!f) return f.status();
                                   return localize::LaserOffFrame{f->view, f->info.exposureUs, f->info.analogueGain};
                                 });
  };
  VirtualClock clock;
  bool laser = false;

  const test::TempDir one("alacs_replay");
  write(one.path(), Gains::kOne);
  auto src = replay::ReplaySource::open(one.path(), clock, [&] { return laser; }, [] { return 0.0; });
  REQUIRE(src.isOk());
  CHECK_FALSE((*src)->gainLowered());
  Result<ports::CapturedFrame> f = (*src)->capture({}, {});
  REQUIRE(f.isOk());
  CHECK(f->info.analogueGain == 0.0);  // recorded at 2, reported as a camera without the control
  const localize::MeteringRun kept = meter(**src);
  REQUIRE(kept.status);
  CHECK(kept.decision.bright);
  CHECK(kept.decision.analogueGain == 0.0);  // left at the gain it was recorded at
  CHECK(kept.decision.exposureUs == 733);    // 500 us x 220 / 150
  REQUIRE(kept.hasLaserOff);
  CHECK(kept.laserOff.view.data[2] == 150);  // the recorded frame, at its gain

  const test::TempDir agc("alacs_replay");
  write(agc.path(), Gains::kMeteringOnly);
  src = replay::ReplaySource::open(
      agc.path(), clock, [&] { return laser; }, [] { return 0.0; });
  REQUIRE(src.isOk());
  CHECK_FALSE((*src)->gainLowered());
  CHECK(meter(**src).decision.analogueGain == 0.0);

  const test::TempDir two("alacs_replay");
  write(two.path(), Gains::kLowered);
  src = replay::ReplaySource::open(two.path(), clock, [&] { return laser; }, [] { return 0.0; });
  REQUIRE(src.isOk());
  CHECK((*src)->gainLowered());
  const localize::MeteringRun lowered = meter(**src);
  REQUIRE(lowered.status);
  CHECK(lowered.decision.meteredGain == 2.0);
  CHECK(lowered.decision.analogueGain == 1.0);
  CHECK(lowered.decision.exposureUs == 1467);  // 733 us x 2
  REQUIRE(lowered.hasLaserOff);
  CHECK(lowered.laserOff.analogueGain == 1.0);
  CHECK(lowered.laserOff.view.data[2] == 90);  // the one recorded at gain 1
  laser = true;
  f = (*src)->capture({}, {});
  REQUIRE(f.isOk());
  CHECK(f->info.analogueGain == 1.0);
}

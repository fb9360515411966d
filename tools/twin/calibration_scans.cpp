// alacs-twin calib: the scans a calibration needs, from the twin, with their truth.
//   DIR/checkerboard_NN        one laser-off frame of a 10×7 checkerboard (40 mm squares)
//                              in a pose spread over distance, tilt and image position:
//                              the camera's intrinsics and distortion
//   DIR/laser_plane_NNNN       the same board, flat, at 0.8-1.6 m: one laser-off frame (its
//                              pose) and laser-on frames at slide 0, 25, ..., 200 mm: the
//                              laser plane at home, the slide axis and its scale
//   --world tuning|holdout     other boards, blur, noise and tilts (CalibWorld below);
//                              every board scan has the exact corners in truth/corners.csv
// alacs-twin examples: the example frames of docs/simulation.md.
#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "sim/orchard.h"
#include "sim/scan_export.h"
#include "twin.h"

namespace alacs::twin {

namespace {

sim::SimScene boardScene(uint64_t seed) {
  sim::SimScene s = sim::defaultScene();
  s.seed = seed;
  s.apples.clear();
  s.sensor.bayer = true;
  s.background.depthMm = 2600.0;
  return s;
}

Eigen::Matrix3d tilt(double rxDeg, double ryDeg, double rzDeg) {
  const double k = M_PI / 180.0;
  return (Eigen::AngleAxisd(rzDeg * k, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(ryDeg * k, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(rxDeg * k, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

// Places the board so that its centre is at `centre`, with rotation `r`.
void placeBoard(sim::SimBoard& b, const Eigen::Matrix3d& r, const Eigen::Vector3d& centre) {
  b.rotation = r;
  b.originMm = centre - r * Eigen::Vector3d(0.5 * b.squaresX * b.squareMm, 0.5 * b.squaresY * b.squareMm, 0.0);
}

bool allCornersVisible(const sim::SimScene& s) {
  for (const auto& c : sim::boardCorners(s)) {
    if (!c.visible) return false;
    if (c.pixel.x() < 20 || c.pixel.y() < 20 || c.pixel.x() > s.truth.camera.widthPx - 20 ||
        c.pixel.y() > s.truth.camera.heightPx - 20)
      return false;
  }
  return true;
}

// The ray of a pixel (undistorted), scaled to depth z.
Eigen::Vector3d atPixel(const geometry::CameraIntrinsics& cam, double u, double v, double z) {
  // Distortion is small: two fixed-point steps of the inverse are plenty for placement.
  double x = (u - cam.cxPx) / cam.fxPx;
  double y = (v - cam.cyPx) / cam.fyPx;
  const double x0 = x, y0 = y;
  for (int i = 0; i < 10; ++i) {
    const Eigen::Vector2d p = sim::projectPx(cam, Eigen::Vector3d(x, y, 1.0));
    x += x0 - (p.x() - cam.cxPx) / cam.fxPx;
    y += y0 - (p.y() - cam.cyPx) / cam.fyPx;
  }
  return Eigen::Vector3d(x * z, y * z, z);
}

// The conditions of a calibration set (docs/calibration.md, "Worlds"). The benchmark is
// the set the docs' figures were first made on; the tuning set is what the corner
// detector was chosen on; the holdout is only measured, never used to choose a parameter.
struct CalibWorld {
  const char* name;
  sim::SimBoard board;   // squares, size and margin (pose set per view)
  double psfSigmaPx[2];  // optics blur per view, uniform in this range
  double gainDb;         // analogue gain: more of it, more noise at the same exposure
  double readNoiseE;
  double tiltDeg;      // |rx|, |ry| up to this
  double rollDeg;      // |rz| up to this
  bool gridPositions;  // image positions on a 4×3 grid (else uniform over the frame)
  uint64_t salt;       // separates the worlds' random streams
};

CalibWorld calibWorld(const std::string& name) {
  sim::SimBoard board;  // 10×7 squares of 40 mm, 60 mm margin
  if (name == "tuning") {
    sim::SimBoard small = board;
    small.squaresX = 12;
    small.squaresY = 9;
    small.squareMm = 30.0;
    small.marginMm = 45.0;
    return {"tuning", small, {0.7, 1.5}, 12.0, 4.0, 40.0, 20.0, true, 0x7A11ULL};
  }
  if (name == "holdout") return {"holdout", board, {0.8, 1.7}, 18.0, 6.0, 35.0, 15.0, false, 0x40D0ULL};
  return {"benchmark", board, {0.6, 0.6}, 6.0, 2.3, 35.0, 15.0, true, 0};
}

// The world of --world with --board, --margin-mm and --tilt-deg applied; false (and a
// message) for a bad value.
bool worldFromArgs(const Args& args, CalibWorld& world) {
  const std::string name = args.str("world", "benchmark");
  if (name != "benchmark" && name != "tuning" && name != "holdout") {
    std::fprintf(stderr, "alacs-twin calib: --world wants benchmark|tuning|holdout, got '%s'\n", name.c_str());
    return false;
  }
  world = calibWorld(name);
  if (args.has("board")) {
    int sx = 0, sy = 0;
    double mm = 0;
    char tail = 0;
    const std::string b = args.str("board");
    if (std::sscanf(b.c_str(), "%dx%dx%lf%c", &sx, &sy, &mm, &tail) != 3 || sx < 3 || sy < 3 || !(mm > 0)) {
      std::fprintf(stderr, "alacs-twin calib: --board wants SXxSYxMM, e.g. 10x7x40\n");
      return false;
    }
    world.board.squaresX = sx;
    world.board.squaresY = sy;
    world.board.squareMm = mm;
  }
  world.board.marginMm = args.num("margin-mm", world.board.marginMm);
  world.tiltDeg = args.num("tilt-deg", world.tiltDeg);
  return true;
}

}  // namespace

int calibrationMain(const Args& args) {
  const std::string out = args.str("out");
  if (out.empty()) {
    std::fprintf(stderr, "alacs-twin calib: needs --out DIR\n");
    return 2;
  }
  CalibWorld world = calibWorld("benchmark");
  if (!worldFromArgs(args, world)) return 2;
  const bool benchmark = world.salt == 0;
  const uint64_t seed = static_cast<uint64_t>(args.integer("seed", 7));
  const int views = static_cast<int>(args.integer("views", 24));
  const int jobs = static_cast<int>(args.integer("jobs", 2));
  const std::vector<double> positions = args.list("positions", {0, 25, 50, 75, 100, 125, 150, 175, 200});
  const auto rays = std::make_shared<const sim::RayTable>(sim::defaultScene().truth.camera);
  char note[160];
  std::snprintf(note, sizeof note, "%dx%d squares of %g mm (%dx%d inner corners), margin %g mm, world %s",
                world.board.squaresX, world.board.squaresY, world.board.squareMm, world.board.squaresX - 1,
                world.board.squaresY - 1, world.board.marginMm, world.name);

  struct Job {
    std::string dir;
    sim::SimScene scene;
    replay::ScanInfo info;
    std::vector<sim::ExportFrame> frames;
    std::string line;
  };
  std::vector<Job> work;
  // The benchmark keeps its stream (its scans are the docs' reference); the other worlds
  // draw from their own.
  sim::CaseRng rng(benchmark ? seed : seed * 0x9E3779B97F4A7C15ULL + world.salt);
  const uint64_t sceneSeed = benchmark ? seed * 1000 : (seed + world.salt) * 1000;
  auto conditions = [&](sim::SimScene& s) {
    s.sensor.gainDb = world.gainDb;
    s.sensor.readNoiseE = world.readNoiseE;
    s.sensor.psfSigmaPx = rng.uniform(world.psfSigmaPx[0], world.psfSigmaPx[1]);
  };
  // Checkerboard views: image positions on a 4×3 grid (the corners of the frame matter
  // most for the distortion) or anywhere in it, distances 0.7-1.6 m, tilts up to 35°.
  for (int v = 0; v < views; ++v) {
    Job j;
    char name[64];
    std::snprintf(name, sizeof name, "/checkerboard_%02d", v);
    j.dir = out + name;
    for (int attempt = 0;; ++attempt) {
      j.scene = boardScene(sceneSeed + static_cast<uint64_t>(v));
      sim::SimBoard b = world.board;
      const auto& cam = j.scene.truth.camera;
      const double u = world.gridPositions ? cam.widthPx * (0.2 + 0.2 * (v % 4)) + rng.uniform(-80, 80)
                                           : rng.uniform(0.12, 0.88) * cam.widthPx;
      const double w = world.gridPositions ? cam.heightPx * (0.25 + 0.25 * ((v / 4) % 3)) + rng.uniform(-60, 60)
                                           : rng.uniform(0.15, 0.85) * cam.heightPx;
      const double z = rng.uniform(700.0, 1600.0);
      const double t = world.tiltDeg;
      placeBoard(b, tilt(rng.uniform(-t, t), rng.uniform(-t, t), rng.uniform(-world.rollDeg, world.rollDeg)),
                 atPixel(cam, u, w, z));
      j.scene.board = b;
      if (allCornersVisible(j.scene) || attempt > 200) break;
    }
    j.scene.lighting.directDir = Eigen::Vector3d(rng.uniform(-0.4, 0.4), -0.6, -0.8).normalized();
    if (!benchmark) conditions(j.scene);
    j.scene.sensor.exposureUs = sim::autoExposureUs(j.scene);
    j.info.kind = "checkerboard";
    j.info.note = std::string(note) + ", laser off";
    j.frames.push_back({0.0, 0.0, false, 0, 0.0, "board"});
    work.push_back(j);
  }
  // Laser-plane target: the board at five distances, tilted a little, centred where the
  // sheet crosses mid-stroke so that every slide position draws a line on it.
  int d = 0;
  for (double z : {800.0, 1000.0, 1200.0, 1400.0, 1600.0}) {
    Job j;
    char name[64];
    std::snprintf(name, sizeof name, "/laser_plane_%04d", static_cast<int>(z));
    j.dir = out + name;
    j.scene = boardScene(sceneSeed + 500 + static_cast<uint64_t>(d++));
    const auto& las = j.scene.truth.laser;
    const Eigen::Vector3d& n = las.planeNormal;
    const double y = rng.uniform(-60, 60);
    const double x = (las.planeOffsetAt(100.0) - n.y() * y - n.z() * z) / n.x();
    sim::SimBoard b = world.board;
    placeBoard(b, tilt(rng.uniform(-15, 15), rng.uniform(-20, 20), rng.uniform(-5, 5)), Eigen::Vector3d(x, y, z));
    j.scene.board = b;
    if (!benchmark) conditions(j.scene);
    j.scene.sensor.exposureUs = sim::autoExposureUs(j.scene);
    j.info.kind = "laser_plane";
    j.info.note = std::string(note) +
                  "; frame 0: laser off (board pose); then laser on at each slide position, a quarter of the exposure";
    j.info.stopsMm = positions;
    j.frames.push_back({0.0, 0.0, false, 0, 0.0, "pose"});
    double t = 0.25;
    for (double s : positions) {
      j.frames.push_back({s, s, true, std::max<int64_t>(20, j.scene.sensor.exposureUs / 4), t, "stop"});
      t += 0.25;
    }
    work.push_back(j);
  }
  const Status st = parallelFor(
      static_cast<int>(work.size()), jobs,
      [&](int i) -> Status {
        Job& j = work[static_cast<size_t>(i)];
        sim::ExportOptions opt;
        opt.firstFrameIndex = static_cast<uint64_t>(i) * 100;
        if (Status s = sim::exportScan(j.scene, rays, j.dir, j.info, j.frames, opt); !s) return s;
        j.line = tools::jsonText({{"scan", j.dir}, {"kind", j.info.kind}, {"frames", j.frames.size()}});
        return Status::ok();
      },
      [&](int i) {
        std::printf("%s", work[static_cast<size_t>(i)].line.c_str());
        std::fflush(stdout);
      });
  if (!st) {
    std::fprintf(stderr, "alacs-twin calib: %s\n", st.toString().c_str());
    return 1;
  }
  return 0;
}

int examplesMain(const Args& args) {
  const std::string out = args.str("out");
  if (out.empty()) {
    std::fprintf(stderr, "alacs-twin examples: needs --out DIR\n");
    return 2;
  }
  const auto rays = std::make_shared<const sim::RayTable>(sim::defaultScene().truth.camera);
  struct Example {
    const char* name;
    sim::LightingKind light;
    bool occluded;
    double distance;
    uint64_t seed;
    double smearMm;
  };
  const Example examples[] = {
      {"sim_lab", sim::LightingKind::kLab, false, 1200, 11, 0.0},
      {"sim_lab_occluded", sim::LightingKind::kLab, true, 1200, 12, 0.0},
      {"sim_overcast", sim::LightingKind::kOvercast, false, 1200, 13, 0.0},
      {"sim_direct", sim::LightingKind::kDirect, true, 1000, 14, 0.0},
      {"sim_sun", sim::LightingKind::kFullSun, false, 1400, 15, 0.0},
      {"sim_motion", sim::LightingKind::kLab, false, 1200, 16, 4.0},
  };
  for (const auto& ex : examples) {
    sim::CaseSpec spec;
    spec.distanceMm = ex.distance;
    spec.occluded = ex.occluded;
    spec.lighting = ex.light;
    const bool overlay = std::string(ex.name) == "sim_lab_occluded";
    Result<sim::OrchardCase> oc = Status(Error::kInternal, "no case");
    for (uint64_t seed = ex.seed; seed < ex.seed + 200; ++seed) {
      oc = sim::makeOrchardCase(spec, seed);
      if (!oc || !overlay) break;
      // The overlay shows every kind of truth row: visible, hidden and unlit or shadowed.
      const sim::SimApple& a = *oc->scene.apple(oc->targetId);
      const double at = oc->scene.truth.laser.slideForPoint(a.centerMm + 0.2 * a.radiusMm * oc->scene.truth.laser.planeNormal);
      int kinds[3] = {0, 0, 0};
      for (const auto& row : sim::laserLineTruthAll(oc->scene, a, at))
        ++kinds[row.flags == 0 ? 0 : ((row.flags & sim::kTruthHidden) ? 1 : 2)];
      if (kinds[0] > 40 && kinds[1] > 15 && kinds[2] > 5) break;
    }
    if (!oc) {
      std::fprintf(stderr, "alacs-twin examples: %s\n", oc.status().toString().c_str());
      return 1;
    }
    const sim::SimApple& t = *oc->scene.apple(oc->targetId);
    const double s = oc->scene.truth.laser.slideForPoint(t.centerMm + 0.2 * t.radiusMm * oc->scene.truth.laser.planeNormal);
    const Eigen::Vector2d c = sim::projectPx(oc->scene.truth.camera, t.centerMm);
    const int half = static_cast<int>(2.6 * t.radiusMm * oc->scene.truth.camera.fxPx / t.centerMm.z());
    const cv::Rect roi(static_cast<int>(c.x()) - half * 4 / 3, static_cast<int>(c.y()) - half, half * 8 / 3, 2 * half);
    sim::Renderer r(oc->scene, rays);
    sim::FrameRequest req;
    req.slideStartMm = s - 0.5 * ex.smearMm;
    req.slideEndMm = s + 0.5 * ex.smearMm;
    req.exposureUs = oc->scene.sensor.exposureUs;
    cv::Mat img;
    r.renderRegion(req, roi, img);
    const std::string path = out + "/" + ex.name + ".png";
    if (!cv::imwrite(path, img)) {
      std::fprintf(stderr, "alacs-twin examples: cannot write %s\n", path.c_str());
      return 1;
    }
    // The truth of one frame, around the target's line, enlarged 3× and brightened 2.5×
    // for the page: left the frame, right the same with every row's exact column drawn
    // (green visible and lit, orange hidden from the camera, yellow where the laser is
    // shadowed or does not reach).
    if (overlay) {
      const auto rows = sim::laserLineTruthAll(oc->scene, t, s);
      double c0 = 1e9, c1 = -1e9;
      int r0 = 1 << 30, r1 = -(1 << 30);
      for (const auto& row : rows) {
        c0 = std::min(c0, row.column);
        c1 = std::max(c1, row.column);
        r0 = std::min(r0, row.row);
        r1 = std::max(r1, row.row);
      }
      const cv::Rect win = cv::Rect(static_cast<int>(c0) - 70, r0 - 15, static_cast<int>(c1 - c0) + 140, r1 - r0 + 30) &
                           cv::Rect(0, 0, oc->scene.truth.camera.widthPx, oc->scene.truth.camera.heightPx);
      cv::Mat crop2;
      r.renderRegion(req, win, crop2);
      cv::Mat big;
      crop2.convertTo(crop2, -1, 2.5);
      cv::resize(crop2, big, cv::Size(), 3.0, 3.0, cv::INTER_NEAREST);
      cv::Mat marked = big.clone();
      for (const auto& row : rows) {
        const cv::Scalar colour = row.flags == 0 ? cv::Scalar(0, 255, 0)
                                  : (row.flags & sim::kTruthHidden) ? cv::Scalar(0, 128, 255)
                                                                    : cv::Scalar(0, 255, 255);
        const cv::Point p(static_cast<int>(std::lround(3.0 * (row.column - win.x) + 1.0)), 3 * (row.row - win.y) + 1);
        cv::circle(marked, p, 1, colour, cv::FILLED);
      }
      cv::Mat both;
      cv::hconcat(big, marked, both);
      cv::imwrite(out + "/sim_truth_overlay.png", both);
    }
    std::printf("%s: %s, exposure %lld us\n", path.c_str(), oc->description.c_str(),
                static_cast<long long>(oc->scene.sensor.exposureUs));
  }
  // The calibration board with the laser on it.
  sim::SimScene s = boardScene(3);
  sim::SimBoard b;
  placeBoard(b, tilt(8, -15, 3), Eigen::Vector3d(80.0, 0.0, 1200.0));
  s.board = b;
  s.sensor.exposureUs = sim::autoExposureUs(s) / 2;
  sim::Renderer r(s, rays);
  sim::FrameRequest req;
  req.slideStartMm = req.slideEndMm = 110.0;
  cv::Mat img, small;
  r.render(req, img);
  cv::resize(img, small, cv::Size(), 0.35, 0.35, cv::INTER_AREA);
  cv::imwrite(out + "/sim_board.png", small);
  std::printf("%s/sim_board.png\n", out.c_str());
  return 0;
}

}  // namespace alacs::twin

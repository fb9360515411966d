// alacs_calibrate: the sensor's calibration from a directory of calibration scans (from
// the twin here, from the rig in the field), with the quality gate. See --help and
// docs/calibration.md.
#include <Eigen/Core>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "calibrate/calibrate_scans.h"
#include "geometry/calibration.h"
#include "geometry/calibration_gate.h"
#include "geometry/checkerboard_corners.h"
#include "replay/scan_dir.h"
#include "tool_common/cli.h"

using namespace alacs;
namespace fs = std::filesystem;

namespace {

constexpr const char* kDescription =
    "The sensor's calibration from a directory of calibration scans, with the quality gate\n"
    "(docs/calibration.md). Exit status: 0 calibrated and accepted, 3 refused by the quality gate,\n"
    "1 failed, 2 usage.";

bool parseTriple(const std::string& s, Eigen::Vector3d* out) {
  double x = 0, y = 0, z = 0;
  char tail = 0;
  if (std::sscanf(s.c_str(), "%lf,%lf,%lf%c", &x, &y, &z, &tail) != 3) return false;
  *out = Eigen::Vector3d(x, y, z);
  return out->norm() > 0.0;
}

void printQuality(const geometry::CalibrationQuality& q) {
  std::printf("quality:\n");
  std::printf("  camera_views            %d\n", q.cameraViews);
  std::printf("  reprojection_rms_px     %.3f\n", q.reprojectionRmsPx);
  std::printf("  fx/fy_sigma_px          %.3f / %.3f\n", q.fxSigmaPx, q.fySigmaPx);
  std::printf("  cx/cy_sigma_px          %.3f / %.3f\n", q.cxSigmaPx, q.cySigmaPx);
  std::printf("  target_placements       %d\n", q.targetPlacements);
  std::printf("  slide_positions         %d\n", q.slidePositions);
  std::printf("  inlier_share            %.3f\n", q.inlierShare);
  std::printf("  laser_rms_px            %.3f\n", q.laserRmsPx);
  std::printf("  plane_rms_mm            %.3f\n", q.planeRmsMm);
  std::printf("  normal_sigma_mrad       %.4f\n", q.normalSigmaMrad);
  std::printf("  offset_sigma_mm         %.4f\n", q.offsetSigmaMm);
  std::printf("  scale_sigma             %.6f\n", q.scaleSigma);
  std::printf("  depth_sigma_mm_at_1000  %.4f   (laser plane only, intrinsics taken as exact)\n", q.depthSigmaMmAt1000);
  std::printf("  depth_sigma_mm_at_1600  %.4f   (laser plane only)\n", q.depthSigmaMmAt1600);
  std::printf("  depth_sigma_total_mm_at_1000/1200/1400/1600  %.3f / %.3f / %.3f / %.3f\n", q.depthSigmaTotalMmAt1000,
              q.depthSigmaTotalMmAt1200, q.depthSigmaTotalMmAt1400, q.depthSigmaTotalMmAt1600);
  std::printf("  sigma_3d_total_mm_at_1000/1200/1400/1600     %.3f / %.3f / %.3f / %.3f\n", q.sigma3dTotalMmAt1000,
              q.sigma3dTotalMmAt1200, q.sigma3dTotalMmAt1400, q.sigma3dTotalMmAt1600);
}

// Where the total σ comes from, per working distance (the --verbose breakdown).
void printUncertainty(const geometry::CalibrationUncertainty& u) {
  std::printf("total σ by working distance (RMS over the grid; depth = z):\n");
  std::printf("  depth    points  laser-only  intrinsics  total depth  total 3D  [mm]\n");
  for (const auto& d : u.byDepth)
    std::printf("  %4.0f mm  %5d   %8.3f   %9.3f   %10.3f  %8.3f\n", d.depthMm, d.points, d.depthSigmaLaserMm,
                d.depthSigmaIntrinsicsMm, d.depthSigmaTotalMm, d.sigma3dTotalMm);
}

}  // namespace

int main(int argc, char** argv) {
  std::string scansDir;
  std::string outPath;
  std::string limitsPath;
  bool verbose = false;
  calib::CalibrationInput input;
  std::string board, slideAxis;
  CLI::App app(kDescription, "alacs_calibrate");
  app.add_option("--scans", scansDir,
                 "a directory of scan directories (docs/scan-format.md): kind \"checkerboard\": every laser-off "
                 "frame is a camera view; kind \"laser_plane\": one board placement, a laser-off frame and laser-on "
                 "frames at several slide positions")
      ->required();
  app.add_option("--out", outPath,
                 "calibration.json to write (default DIR/calibration.json); written atomically and only when the "
                 "quality gate passes; a refused calibration goes to FILE.refused for diagnosis");
  app.add_option("--limits", limitsPath, "the gate's limits (JSON, docs/calibration.md); default built in");
  app.add_option("--board", board, "checkerboard squares and square size SXxSYxMM (default 10x7x40)");
  app.add_option("--margin-mm", input.board.marginMm, "the board's plain margin around the squares")
      ->capture_default_str();
  app.add_option("--slide-axis", slideAxis,
                 "X,Y,Z: the slide's direction in the camera frame from the drawing (default 1,0,0; only its "
                 "component along the laser normal is observable, see docs/calibration.md)");
  bool freeK3 = false;
  app.add_flag("--free-k3", freeK3, "estimate the sixth-order radial term too");
  app.add_option("--sigma-draws", input.uncertaintyDraws,
                 "total sigma by a Monte Carlo of N intrinsics draws (seeded) instead of the default +-1 sigma per "
                 "direction; for checking, N x slower")
      ->check(CLI::NonNegativeNumber);
  std::string cornerMethod = geometry::cornerMethodName(geometry::kDefaultCornerMethod);
  app.add_option("--corners", cornerMethod,
                 "corner detector: sb, sb-accuracy, classic-subpix or sb-subpix (docs/calibration.md, measured "
                 "against the twin's exact corners)")
      ->capture_default_str();
  app.add_option("--corner-outlier-sigmas", input.cameraOptions.outlierSigmas,
                 "corners whose residual after a first solve exceeds this many robust sigmas (and 1 px) are left "
                 "out and the camera solved again; 0 keeps every corner (docs/calibration.md)")
      ->capture_default_str()
      ->check(CLI::Range(0.0, 100.0));
  app.add_flag("--verbose", verbose, "where the total sigma comes from, per working distance");
  if (const int rc = tools::parseCommandLine(app, argc, argv); rc >= 0) return rc;
  if (!board.empty()) {
    int sx = 0, sy = 0;
    double mm = 0;
    char tail = 0;
    if (std::sscanf(board.c_str(), "%dx%dx%lf%c", &sx, &sy, &mm, &tail) != 3 || sx < 3 || sy < 3 || !(mm > 0))
      return tools::usageError(app, "--board wants SXxSYxMM, e.g. 10x7x40");
    input.board.squaresX = sx;
    input.board.squaresY = sy;
    input.board.squareMm = mm;
  }
  if (!slideAxis.empty()) {
    if (!parseTriple(slideAxis, &input.nominalSlideAxis)) return tools::usageError(app, "--slide-axis wants X,Y,Z");
    input.nominalSlideAxis.normalize();
  }
  if (freeK3) input.cameraOptions.fixK3 = false;
  if (Result<geometry::CornerMethod> m = geometry::parseCornerMethod(cornerMethod); m) {
    input.corners.method = *m;
  } else {
    return tools::usageError(app, "--corners: " + m.status().reason());
  }
  if (outPath.empty()) outPath = (fs::path(scansDir) / "calibration.json").string();
  geometry::CalibrationLimits limits;
  if (!limitsPath.empty()) {
    Result<geometry::CalibrationLimits> l = geometry::CalibrationLimits::load(limitsPath);
    if (!l) {
      std::fprintf(stderr, "alacs_calibrate: %s\n", l.status().toString().c_str());
      return 1;
    }
    limits = *l;
  }

  // The scans: every sub-directory with a manifest, in name order.
  std::vector<fs::path> dirs;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(scansDir, ec))
    if (e.is_directory() && fs::exists(e.path() / "manifest.json")) dirs.push_back(e.path());
  if (ec) {
    std::fprintf(stderr, "alacs_calibrate: cannot read %s: %s\n", scansDir.c_str(), ec.message().c_str());
    return 1;
  }
  std::sort(dirs.begin(), dirs.end());
  // Frames are named "<scan dir>#<frame index>" and loaded on demand.
  std::map<std::string, std::pair<std::string, replay::ScanManifest>> manifests;
  std::map<std::string, std::pair<std::string, size_t>> frames;
  for (const auto& d : dirs) {
    Result<replay::ScanManifest> m = replay::readManifest(d.string());
    if (!m) {
      std::fprintf(stderr, "alacs_calibrate: %s: %s\n", d.c_str(), m.status().toString().c_str());
      return 1;
    }
    const std::string key = d.filename().string();
    if (input.widthPx == 0) {
      input.widthPx = m->scan.widthPx;
      input.heightPx = m->scan.heightPx;
    } else if (input.widthPx != m->scan.widthPx || input.heightPx != m->scan.heightPx) {
      std::fprintf(stderr, "alacs_calibrate: %s: frame size differs from the other scans\n", d.c_str());
      return 1;
    }
    auto name = [&](size_t i) {
      const std::string n = key + "#" + std::to_string(i);
      frames[n] = {key, i};
      return n;
    };
    if (m->scan.kind == "checkerboard") {
      for (size_t i = 0; i < m->frames.size(); ++i)
        if (!m->frames[i].laserOn) input.cameraViews.push_back(name(i));
    } else if (m->scan.kind == "laser_plane") {
      calib::PlacementRef p;
      p.name = key;
      for (size_t i = 0; i < m->frames.size(); ++i) {
        if (!m->frames[i].laserOn) {
          if (p.boardImage.empty()) p.boardImage = name(i);
        } else {
          p.laserFrames.push_back({m->frames[i].slideMm, name(i)});
        }
      }
      if (p.boardImage.empty()) {
        std::fprintf(stderr, "alacs_calibrate: %s: a laser_plane scan needs a frame with the laser off\n", d.c_str());
        return 1;
      }
      input.placements.push_back(std::move(p));
    } else {
      if (verbose) std::printf("%s: kind \"%s\" is not a calibration scan, skipped\n", key.c_str(), m->scan.kind.c_str());
      continue;
    }
    manifests[key] = {d.string(), std::move(*m)};
  }
  if (manifests.empty()) {
    std::fprintf(stderr, "alacs_calibrate: no calibration scans (kind checkerboard or laser_plane) in %s\n",
                 scansDir.c_str());
    return 1;
  }
  const calib::ImageLoader load = [&](const std::string& n) -> Result<cv::Mat> {
    const auto it = frames.find(n);
    if (it == frames.end()) return Status(Error::kNotFound, "no frame " + n);
    const auto& [dir, manifest] = manifests.at(it->second.first);
    return replay::loadFrame(dir, manifest, manifest.frames[it->second.second]);
  };
  std::printf("alacs_calibrate: %zu camera views, %zu board placements from %s\n", input.cameraViews.size(),
              input.placements.size(), scansDir.c_str());
  // Every skipped view or placement with its reason, as it happens: the person at the rig
  // learns which views to redo even when a later stage fails.
  int skipped = 0;
  input.onSkipped = [&skipped](const std::string& name, const std::string& why) {
    std::printf("  skipped %s: %s\n", name.c_str(), why.c_str());
    std::fflush(stdout);
    ++skipped;
  };
  Result<calib::CalibrationRun> run = calib::runCalibration(input, load);
  if (skipped > 0) std::printf("alacs_calibrate: %d views or placements skipped (reasons above)\n", skipped);
  if (!run) {
    // No calibration to judge: the gate's verdict says where the run stopped.
    std::fprintf(stderr, "alacs_calibrate: %s\n", run.status().toString().c_str());
    std::fprintf(stderr, "alacs_calibrate: REFUSED: the quality gate was not reached (the stage above failed)\n");
    return 1;
  }
  if (verbose)
    for (const auto& line : run->log) std::printf("  %s\n", line.c_str());
  if (const geometry::CornerOutliers& o = run->camera.outliers; o.count() > 0)
    std::printf(
        "alacs_calibrate: %zu misplaced corners left out (residual > %.2f px; robust sigma %.3f px), "
        "the camera solved again\n",
        o.count(), o.boundPx, o.sigmaPx);
  geometry::Calibration cal = run->calibration;
  const auto& c = cal.camera;
  const auto& l = cal.laser;
  std::printf("camera: fx %.2f fy %.2f cx %.2f cy %.2f px, k1 %.5f k2 %.5f p1 %.6f p2 %.6f k3 %.5f\n", c.fxPx, c.fyPx,
              c.cxPx, c.cyPx, c.distortion[0], c.distortion[1], c.distortion[2], c.distortion[3], c.distortion[4]);
  std::printf("laser: normal (%.6f, %.6f, %.6f), offset %.3f mm, slide axis (%.4f, %.4f, %.4f), scale %.5f\n",
              l.planeNormal.x(), l.planeNormal.y(), l.planeNormal.z(), l.planeOffsetMm, l.slideAxis.x(),
              l.slideAxis.y(), l.slideAxis.z(), l.slideScale);
  printQuality(cal.quality);
  if (verbose) printUncertainty(run->uncertainty);
  std::vector<std::string> failedStages;
  if (!run->uncertaintyError.empty()) failedStages.push_back(run->uncertaintyError);
  const geometry::GateVerdict verdict = geometry::judgeCalibration(cal.quality, failedStages, limits);
  if (!verdict.passed()) {
    cal.quality.gate = geometry::CalibrationQuality::Gate::kRefused;
    std::fprintf(stderr, "alacs_calibrate: REFUSED by the quality gate:\n");
    for (const auto& f : verdict.failures) std::fprintf(stderr, "  %s\n", f.c_str());
    const Status s = geometry::writeFileAtomically(outPath + ".refused", geometry::calibrationJson(cal));
    if (s) std::fprintf(stderr, "alacs_calibrate: the refused calibration is in %s.refused (it will not load)\n",
                        outPath.c_str());
    return 3;
  }
  cal.quality.gate = geometry::CalibrationQuality::Gate::kPassed;
  if (Status s = geometry::saveCalibration(cal, outPath); !s) {
    std::fprintf(stderr, "alacs_calibrate: %s\n", s.toString().c_str());
    return 1;
  }
  std::printf("gate: passed; wrote %s\n", outPath.c_str());
  return 0;
}

// The simulated orchard scene behind `alacsd --sim`, the tests and the benchmark: a
// camera (optics and sensor), the laser on its slide, apples, leaves, branches, a
// calibration board, a background of foliage with gaps of sky, and the light.
// Every physical parameter and its source: docs/simulation.md.
// Units: mm in the camera frame (x right, y down, z forward), pixels for the image, lux
// for ambient light, mW for the laser, µs for exposures, electrons in the sensor.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "common/result.h"
#include "geometry/calibration.h"

namespace alacs::sim {

// An apple: an ellipsoid of revolution about its stem axis (real apples are a little
// oblate), radius `radiusMm` across and `aspect`·radius along the stem.
struct SimApple {
  int id = 0;
  Eigen::Vector3d centerMm{0.0, 0.0, 1200.0};
  double radiusMm = 40.0;                       // equatorial radius (half the diameter across)
  double aspect = 1.0;                          // polar / equatorial radius (1: a sphere)
  Eigen::Vector3d stemAxis{0.0, -1.0, 0.0};     // unit, from the centre through the stem
  Eigen::Vector3d skinRgb{0.45, 0.07, 0.06};    // albedo of the red blush per channel
  Eigen::Vector3d groundRgb{0.55, 0.48, 0.16};  // albedo of the yellow-green ground colour
  double blush = 1.0;                           // share of the skin that is blushed (1: red, ~0.5: bicolour)
  Eigen::Vector3d blushAxis{-0.2, -0.4, -0.9};  // from the centre towards the middle of the blush
  double specular = 0.04;                       // wax cuticle: Fresnel reflectance at normal incidence
  double shininess = 80.0;                      // Blinn-Phong exponent of the highlight
  // Irregular, lumpy fruit: in the frame where the ellipsoid is the unit sphere, the
  // surface lies at distance 1 + lumpAmplitude·h(û) from the centre along û, h a smooth
  // pattern (|h| < 1) of five ridges round the stem and a few bumps and dents drawn from
  // lumpSeed (AppleShape). 0: the smooth ellipsoid.
  double lumpAmplitude = 0.0;
  uint64_t lumpSeed = 0;
};

// The surface of one apple, for intersecting and sampling it: the ellipsoid's frame and
// axes and, for a lumpy apple, its pattern (built once from the seed, not per call).
class AppleShape {
 public:
  explicit AppleShape(const SimApple& apple);
  bool lumpy() const { return amplitude_ > 0.0; }
  // 1 + lumpAmplitude·h(û) for a unit direction in the scaled frame.
  double radialFactor(const Eigen::Vector3d& unitScaled) const;
  // Scaled frame: u = S⁻¹Rᵀ(p - c); the surface is |u| = radialFactor(û).
  Eigen::Vector3d toScaled(const Eigen::Vector3d& pointMm) const;
  Eigen::Vector3d fromScaled(const Eigen::Vector3d& u) const;
  // Outward unit normal at (or near) the world point.
  Eigen::Vector3d normal(const Eigen::Vector3d& pointMm) const;
  // The first crossing of the surface by origin + t·dir (scaled-frame origin and
  // direction, t unchanged by the scaling) in (tMin, tMax).
  bool intersectScaled(const Eigen::Vector3d& ol, const Eigen::Vector3d& dl, double tMin, double tMax, double* t) const;
  // The bound of radialFactor: every surface point has |u| within [1 - a, 1 + a].
  double amplitude() const { return amplitude_; }

 private:
  static constexpr int kBumps = 6;
  Eigen::Vector3d center_;
  Eigen::Matrix3d frame_;
  Eigen::Vector3d axes_;
  double amplitude_;
  double ridgePhase_ = 0.0;
  std::array<Eigen::Vector3d, kBumps> bumpDir_{};
  std::array<double, kBumps> bumpSign_{};
};

// A leaf: a flat lens-shaped blade, two-sided. |b| <= w/2 · (1 - (2a/L)²) in its plane.
struct SimLeaf {
  Eigen::Vector3d centerMm{0.0, 0.0, 1100.0};
  Eigen::Vector3d normal{0.0, 0.0, -1.0};  // unit
  Eigen::Vector3d axis{0.0, 1.0, 0.0};     // unit, along the blade, perpendicular to `normal`
  double lengthMm = 80.0;
  double widthMm = 40.0;
  Eigen::Vector3d albedoRgb{0.06, 0.14, 0.04};
};

// A branch or twig: a capsule (cylinder with round ends) from `aMm` to `bMm`.
struct SimBranch {
  Eigen::Vector3d aMm{-200.0, -150.0, 1300.0};
  Eigen::Vector3d bMm{200.0, -120.0, 1350.0};
  double radiusMm = 10.0;
  Eigen::Vector3d albedoRgb{0.20, 0.15, 0.11};
};

// A flat calibration board: `squaresX` × `squaresY` checkerboard squares of `squareMm`
// inside a white margin. The board frame: origin at the checkerboard's top-left
// corner, x along the rows of squares, y down the columns, z into the board (away
// from the camera): X_cam = rotation · X_board + originMm. Inner corners sit at
// (i·square, j·square) for i in 1..squaresX-1, j in 1..squaresY-1.
struct SimBoard {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d originMm{-200.0, -150.0, 1000.0};
  int squaresX = 10;
  int squaresY = 7;
  double squareMm = 40.0;
  double marginMm = 60.0;
  bool checkerboard = true;     // false: a plain white board (laser-plane target)
  double whiteAlbedo = 0.80;    // matte white print
  double blackAlbedo = 0.05;    // matte black print
};

struct SimBackground {
  enum class Kind { kFoliage, kBackdrop } kind = Kind::kFoliage;
  double depthMm = 2000.0;                        // the wall z = depthMm
  double skyShare = 0.0;                          // share of the foliage that is gaps of sky
  Eigen::Vector3d albedoRgb{0.07, 0.15, 0.05};    // mean albedo (foliage or backdrop)
  double textureCellMm = 35.0;                    // size of the leaf clumps
};

// Light: a diffuse part (overcast sky, room) and a directional part (sun, lamp).
struct SimLighting {
  std::string name = "lab";
  double diffuseLux = 900.0;                    // on a surface facing up
  double directLux = 1100.0;                    // on a surface facing the sun or lamp
  Eigen::Vector3d directDir{-0.3, -0.5, -0.8};  // towards the sun or lamp (unit), camera frame
  Eigen::Vector3d skyRgb{1.0, 1.0, 1.0};        // colour of the sky in the gaps
  double skyLuminanceFactor = 1.0;              // sky luminance = factor · diffuseLux / π
  double totalLux() const { return diffuseLux + directLux; }
};

// The line laser on the slide. Its sheet is the calibration's plane (truth.laser); the
// emitter is the fan's apex, on that plane.
struct SimLaser {
  Eigen::Vector3d originAtHomeMm{100.0, -60.0, 15.0};
  double powerMw = 20.0;
  double fanDeg = 30.0;                           // full fan angle
  double sheetSigmaMrad = 0.58;                   // 1σ half-thickness of the sheet, per metre of range
  Eigen::Vector3d channelResponse{1.0, 0.08, 0.04};  // 635 nm in the red, green, blue filters
  double haloShare = 0.35;                        // share of the light on skin that re-emerges from under it
  double haloLengthMm = 2.0;                      // exponential decay length of that halo
  double speckleContrast = 0.40;                  // std/mean of the speckle on the line
  double speckleCellPx = 1.6;                     // speckle grain in the image
  // The emitter at commanded slide position `slideMm` (it rides the slide).
  Eigen::Vector3d originAt(const geometry::LaserGeometry& g, double slideMm) const {
    return originAtHomeMm + g.slideScale * slideMm * g.slideAxis;
  }
};

// Optics and sensor (a FLIR Blackfly S with Sony IMX252: 2048×1536, 3.45 µm pixels).
struct SimSensor {
  double fNumber = 2.8;
  double lensTransmission = 0.9;
  double electronsPerLuxS = 25000.0;     // per channel, white light, image-plane lux·s, one pixel
  double electronsPerWattS = 1.7e7;      // red channel at 635 nm, per W/m² at the image plane per s
  double fullWellE = 10500.0;
  double readNoiseE = 2.3;
  double gainDb = 6.0;                   // analogue gain; 0 dB maps the full well to 12-bit full scale
  double prnu = 0.01;                    // photo-response non-uniformity (1σ, fixed per pixel)
  double psfSigmaPx = 0.6;               // optics blur (diffraction, aberrations, defocus)
  bool bayer = false;                    // RGGB mosaic + bilinear demosaic (the real camera)
  bool vignetting = true;                // cos⁴ fall-off
  int64_t exposureUs = 3000;             // used when a render does not say
  // Optional band-pass interference filter in front of the lens, centred on the laser
  // (635 nm): a flat top of `bandpassFwhmNm` (0: no filter) with `bandpassPeak`
  // transmission, blocking outside. docs/simulation.md, "Band-pass filter".
  double bandpassFwhmNm = 0.0;
  double bandpassPeak = 0.9;
  double bandpassCwlNm = 637.0;  // centre at normal incidence (a little above the laser's 635)
  double bandpassNeff = 2.0;     // effective index: the centre moves to cwl·√(1 − sin²θ/n²) off axis
  // What the filter passes: of the ambient (daylight-like, flat over 550-700 nm) light in
  // each channel (R, G, B), and of the laser (635 nm) arriving at sin²θ off the axis: the
  // pass band is flat to 1 nm inside its half-maximum points, with 2 nm linear edges.
  // All 1 without a filter.
  Eigen::Vector3d ambientFilterRgb() const;
  double laserFilter(double sin2Theta) const;
  // gainDb as the linear gain a camera reports (libcamera's AnalogueGain): 10^(dB/20).
  double analogueGain() const;
};

struct SimScene {
  geometry::Calibration truth;  // camera + laser plane as they really are
  SimLaser laser;
  SimSensor sensor;
  SimLighting lighting;
  SimBackground background;
  std::vector<SimApple> apples;
  std::vector<SimLeaf> leaves;
  std::vector<SimBranch> branches;
  std::optional<SimBoard> board;
  uint64_t seed = 1;

  // Errors name the offending field (kBadInput).
  Status validate() const;
  const SimApple* apple(int id) const;
};

// The built-in scene: one 80 mm red apple at 1.2 m in front of a backdrop at 2 m, in a
// bright lab. The camera and laser geometry of the paper's rig (docs/simulation.md).
SimScene defaultScene();

// Loads a scene JSON (the format saveScene writes; docs/simulation.md). Missing keys
// keep the defaults of defaultScene(). Errors: kNotFound, kBadInput naming the key.
// A regular file of at most kSceneMaxBytes; unknown keys are refused; "camera" and
// "laser_plane", when present, follow the calibration's schema with every field required.
Result<SimScene> loadScene(const std::string& path);
inline constexpr size_t kSceneMaxBytes = size_t{16} << 20;
// Overrides the parts of `scene` present in `json` (no validate()). Errors: kBadInput.
Status sceneFromJson(const Json& json, SimScene& scene);
OrderedJson sceneToJson(const SimScene& scene);
// Writes the whole scene (truth included) as JSON, loadable by loadScene, atomically.
Status saveScene(const SimScene& scene, const std::string& path);
std::string sceneJson(const SimScene& scene);
// Kept for alacsd --sim-truth-out: the same file as saveScene.
Status saveSceneTruth(const SimScene& scene, const std::string& path);

// The point of the apple's surface nearest the sensor on the line to its centre.
Eigen::Vector3d approachPoint(const SimApple& apple);
// The apple's frame: columns e1, e2 (equatorial) and the stem axis.
Eigen::Matrix3d appleFrame(const SimApple& apple);
// Outward unit normal of the apple's surface at (or near) `pointMm`.
Eigen::Vector3d appleNormal(const SimApple& apple, const Eigen::Vector3d& pointMm);
// Largest semi-axis, lumps included (a bounding radius).
inline double appleBoundMm(const SimApple& a) {
  return a.radiusMm * (a.aspect > 1.0 ? a.aspect : 1.0) * (1.0 + a.lumpAmplitude);
}

// Projects a camera-frame point with the Brown–Conrady model (OpenCV's), in double,
// without OpenCV. Pixel centres at integers. The point must have z > 0.
Eigen::Vector2d projectPx(const geometry::CameraIntrinsics& cam, const Eigen::Vector3d& pointMm);

}  // namespace alacs::sim

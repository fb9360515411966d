#include "sim/orchard.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <random>

#include "sim/truth.h"

namespace alacs::sim {

uint64_t CaseRng::next() {
  uint64_t z = (state_ += 0x9E3779B97F4A7C15ULL);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}
double CaseRng::uniform(double lo, double hi) {
  return lo + (hi - lo) * (static_cast<double>(next() >> 11) * (1.0 / 9007199254740992.0));
}
double CaseRng::normal() {
  const double a = uniform(1e-12, 1.0);
  const double b = uniform(0.0, 1.0);
  return std::sqrt(-2.0 * std::log(a)) * std::cos(2.0 * M_PI * b);
}
int CaseRng::integer(int lo, int hi) {
  return lo + static_cast<int>(next() % static_cast<uint64_t>(hi - lo + 1));
}
Eigen::Vector3d CaseRng::unitVector() {
  const double z = uniform(-1.0, 1.0);
  const double phi = uniform(0.0, 2.0 * M_PI);
  const double r = std::sqrt(1.0 - z * z);
  return {r * std::cos(phi), r * std::sin(phi), z};
}

const char* lightingName(LightingKind k) {
  switch (k) {
    case LightingKind::kLab: return "lab";
    case LightingKind::kOvercast: return "overcast";
    case LightingKind::kDirect: return "direct";
    case LightingKind::kFullSun: return "sun";
  }
  return "lab";
}

const char* worldName(World w) {
  switch (w) {
    case World::kBenchmark: return "benchmark";
    case World::kBenchmarkHard: return "benchmark-hard";
    case World::kHoldout: return "holdout";
  }
  return "benchmark";
}

Result<World> parseWorld(const std::string& name) {
  if (name == "benchmark") return World::kBenchmark;
  if (name == "benchmark-hard") return World::kBenchmarkHard;
  if (name == "holdout") return World::kHoldout;
  return Status(Error::kInvalidArgument, "world must be benchmark|benchmark-hard|holdout, got '" + name + "'");
}

Result<LightingKind> parseLighting(const std::string& name) {
  if (name == "lab") return LightingKind::kLab;
  if (name == "overcast") return LightingKind::kOvercast;
  if (name == "direct") return LightingKind::kDirect;
  if (name == "sun") return LightingKind::kFullSun;
  return Status(Error::kInvalidArgument, "lighting must be lab|overcast|direct|sun, got '" + name + "'");
}

double roughSigmaMm(double distanceMm) {
  // Mean of |N(0, σ²I₃)| is 1.596 σ; interpolate the paper's means over distance.
  static const double kDist[] = {1000.0, 1200.0, 1400.0, 1600.0};
  static const double kMean[] = {16.0, 17.3, 19.5, 21.5};
  double mean = kMean[0];
  if (distanceMm >= kDist[3]) {
    mean = kMean[3] + (distanceMm - kDist[3]) * (kMean[3] - kMean[2]) / 200.0;
  } else if (distanceMm > kDist[0]) {
    for (int i = 0; i < 3; ++i)
      if (distanceMm <= kDist[i + 1]) {
        mean = kMean[i] + (kMean[i + 1] - kMean[i]) * (distanceMm - kDist[i]) / (kDist[i + 1] - kDist[i]);
        break;
      }
  } else {
    mean = kMean[0] - (kDist[0] - distanceMm) * (kMean[1] - kMean[0]) / 200.0;
  }
  return std::max(5.0, mean) / 1.596;
}

int64_t autoExposureUs(const SimScene& s) {
  const auto& sen = s.sensor;
  const double lensK = sen.lensTransmission / (4.0 * sen.fNumber * sen.fNumber);
  const double fullScaleE = std::min(sen.fullWellE, sen.fullWellE / std::pow(10.0, sen.gainDb / 20.0));
  const double lux = std::max(1.0, s.lighting.totalLux());
  // Through a band-pass filter the white patch is dimmer (most in its brightest channel,
  // which the auto-exposure keeps at 60 %): the exposure grows by that factor.
  const double filter = sen.ambientFilterRgb().maxCoeff();
  const double seconds = 0.6 * fullScaleE / (lux * lensK * sen.electronsPerLuxS * filter);
  return std::clamp<int64_t>(std::llround(seconds * 1e6), 20, 3000);
}

namespace {

void setLighting(SimScene& s, LightingKind kind, CaseRng& rng, double* lux) {
  auto& l = s.lighting;
  l.name = lightingName(kind);
  // The sun or lamp: above, and within ±70° of the camera's back (front-lit scenes).
  const double elev = rng.uniform(20.0, 60.0) * M_PI / 180.0;
  const double azim = rng.uniform(-70.0, 70.0) * M_PI / 180.0;
  const Eigen::Vector3d towards(std::sin(azim) * std::cos(elev), -std::sin(elev), -std::cos(azim) * std::cos(elev));
  switch (kind) {
    case LightingKind::kLab:
      l.diffuseLux = rng.uniform(700.0, 1100.0);
      l.directLux = rng.uniform(800.0, 1400.0);
      l.directDir = towards.normalized();
      l.skyRgb = Eigen::Vector3d(1.0, 1.0, 1.0);
      break;
    case LightingKind::kOvercast:
      // The paper's outdoor range is 1000-6500 lux; overcast takes the lower part.
      l.diffuseLux = rng.uniform(1000.0, 4000.0);
      l.directLux = 0.0;
      l.skyRgb = Eigen::Vector3d(0.95, 1.0, 1.05);
      break;
    case LightingKind::kDirect: {
      // Direct light in the canopy at the paper's levels (up to 6500 lux in total).
      const double total = rng.uniform(3000.0, 6500.0);
      l.directLux = 0.7 * total;
      l.diffuseLux = 0.3 * total;
      l.directDir = towards.normalized();
      l.skyRgb = Eigen::Vector3d(0.75, 0.9, 1.25);
      break;
    }
    case LightingKind::kFullSun: {
      // Beyond the paper: open sun, 30-80 klux, and a clear sky's 15 %.
      l.directLux = rng.uniform(30000.0, 80000.0);
      l.diffuseLux = 0.15 * l.directLux;
      l.directDir = towards.normalized();
      l.skyRgb = Eigen::Vector3d(0.75, 0.9, 1.25);
      break;
    }
  }
  *lux = l.totalLux();
}

SimApple randomApple(CaseRng& rng, int id) {
  SimApple a;
  a.id = id;
  a.radiusMm = rng.uniform(32.5, 47.5);  // 65-95 mm across
  // A little oblate (height/width 0.82-0.98), the stem up to 35° off vertical.
  a.aspect = rng.uniform(0.82, 0.98);
  const double tiltRad = rng.uniform(0.0, 35.0) * M_PI / 180.0;
  const double spinRad = rng.uniform(0.0, 2.0 * M_PI);
  a.stemAxis = Eigen::Vector3d(std::sin(tiltRad) * std::cos(spinRad), -std::cos(tiltRad), std::sin(tiltRad) * std::sin(spinRad));
  const double shade = rng.uniform(0.8, 1.15);
  a.skinRgb = Eigen::Vector3d(0.45 * shade, rng.uniform(0.05, 0.09), rng.uniform(0.04, 0.07));
  a.groundRgb = Eigen::Vector3d(rng.uniform(0.45, 0.6), rng.uniform(0.38, 0.52), rng.uniform(0.10, 0.2));
  a.blush = rng.uniform(0.0, 1.0) < 0.5 ? 1.0 : rng.uniform(0.3, 0.85);
  a.blushAxis = (Eigen::Vector3d(rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.3), -1.0)).normalized();
  a.specular = rng.uniform(0.03, 0.05);
  a.shininess = rng.uniform(40.0, 120.0);
  return a;
}

SimLeaf randomLeaf(CaseRng& rng, const Eigen::Vector3d& centre) {
  SimLeaf l;
  l.centerMm = centre;
  l.lengthMm = rng.uniform(60.0, 100.0);
  l.widthMm = l.lengthMm * rng.uniform(0.4, 0.55);
  Eigen::Vector3d n = rng.unitVector();
  if (n.z() > 0.0) n.z() = -n.z();
  n.z() = std::min(n.z(), -0.2);
  l.normal = n.normalized();
  l.axis = l.normal.unitOrthogonal();
  const double spin = rng.uniform(0.0, 2.0 * M_PI);
  l.axis = (std::cos(spin) * l.axis + std::sin(spin) * l.normal.cross(l.axis)).normalized();
  l.albedoRgb = Eigen::Vector3d(rng.uniform(0.05, 0.08), rng.uniform(0.11, 0.18), rng.uniform(0.03, 0.05));
  return l;
}

bool leafTouchesApple(const SimLeaf& l, const std::vector<SimApple>& apples) {
  for (const auto& a : apples)
    if ((l.centerMm - a.centerMm).norm() < a.radiusMm + 0.5 * l.lengthMm + 3.0) return true;
  return false;
}

double shareWith(const SimScene& base, const SimApple& target) { return occlusionShare(base, target, 400); }

// Neighbours in the cluster: beside or behind the target, never in front of it.
void addNeighbours(SimScene& s, const SimApple& target, int maxNeighbours, CaseRng& rng) {
  const Eigen::Vector3d tc = target.centerMm;
  const int neighbours = rng.integer(0, maxNeighbours);
  for (int k = 0; k < neighbours; ++k) {
    for (int attempt = 0; attempt < 30; ++attempt) {
      SimApple a = randomApple(rng, 2 + k);
      Eigen::Vector3d dir = rng.unitVector();
      dir.z() = std::abs(dir.z()) * 0.8;
      dir.normalize();
      a.centerMm = tc + dir * (target.radiusMm + a.radiusMm + rng.uniform(1.0, 30.0));
      bool ok = a.centerMm.z() + a.radiusMm < s.background.depthMm;
      for (const auto& b : s.apples) ok = ok && (a.centerMm - b.centerMm).norm() > a.radiusMm + b.radiusMm + 0.5;
      if (!ok) continue;
      SimScene trial = s;
      trial.apples.push_back(a);
      if (shareWith(trial, target) > 0.02) continue;
      s.apples.push_back(a);
      break;
    }
  }
}

// The canopy: leaves around the cluster that do not hide the target.
void addCanopy(SimScene& s, const SimApple& target, CaseRng& rng) {
  const Eigen::Vector3d tc = target.centerMm;
  const int canopy = rng.integer(12, 30);
  for (int k = 0; k < canopy; ++k) {
    for (int attempt = 0; attempt < 10; ++attempt) {
      const Eigen::Vector3d c = tc + Eigen::Vector3d(rng.uniform(-260.0, 260.0), rng.uniform(-200.0, 200.0),
                                                     rng.uniform(-150.0, 300.0));
      SimLeaf l = randomLeaf(rng, c);
      if (leafTouchesApple(l, s.apples) || c.z() + 60.0 > s.background.depthMm) continue;
      SimScene trial = s;
      trial.leaves.push_back(l);
      if (shareWith(trial, target) > 0.0) continue;
      s.leaves.push_back(l);
      break;
    }
  }
}

// Twigs and branches, behind or beside the target.
void addBranches(SimScene& s, const SimApple& target, CaseRng& rng) {
  const Eigen::Vector3d tc = target.centerMm;
  const int branches = rng.integer(0, 2);
  for (int k = 0; k < branches; ++k) {
    for (int attempt = 0; attempt < 10; ++attempt) {
      SimBranch b;
      b.radiusMm = rng.uniform(5.0, 16.0);
      const Eigen::Vector3d mid = tc + Eigen::Vector3d(rng.uniform(-200.0, 200.0), rng.uniform(-150.0, 150.0),
                                                       rng.uniform(0.0, 250.0));
      Eigen::Vector3d ax = Eigen::Vector3d(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-0.3, 0.3)).normalized();
      const double half = rng.uniform(150.0, 300.0);
      b.aMm = mid - half * ax;
      b.bMm = mid + half * ax;
      b.albedoRgb = Eigen::Vector3d(rng.uniform(0.15, 0.25), rng.uniform(0.12, 0.18), rng.uniform(0.08, 0.12));
      bool ok = std::max(b.aMm.z(), b.bMm.z()) + b.radiusMm < s.background.depthMm && std::min(b.aMm.z(), b.bMm.z()) > 300.0;
      for (const auto& a : s.apples) {
        const Eigen::Vector3d ba = b.bMm - b.aMm;
        const double t = std::clamp((a.centerMm - b.aMm).dot(ba) / ba.squaredNorm(), 0.0, 1.0);
        ok = ok && (a.centerMm - (b.aMm + t * ba)).norm() > a.radiusMm + b.radiusMm + 2.0;
      }
      if (!ok) continue;
      SimScene trial = s;
      trial.branches.push_back(b);
      if (shareWith(trial, target) > 0.0) continue;
      s.branches.push_back(b);
      break;
    }
  }

}

// One to three leaves in front of the target, until 15-50 % of it is hidden (40 rounds);
// false when no round got there.
bool occludeTarget(SimScene& s, const SimApple& target, CaseRng& rng) {
  const Eigen::Vector3d tc = target.centerMm;
  bool done = false;
  for (int round = 0; round < 40 && !done; ++round) {
    SimScene trial = s;
    const int count = rng.integer(1, 3);
    for (int k = 0; k < count; ++k) {
      for (int attempt = 0; attempt < 20; ++attempt) {
        const double dz = rng.uniform(25.0, 160.0);
        const double zl = tc.z() - target.radiusMm - dz;
        const double ang = rng.uniform(0.0, 2.0 * M_PI);
        const double off = rng.uniform(0.35, 1.2) * target.radiusMm;
        const Eigen::Vector3d onAxis = tc * (zl / tc.z());
        const Eigen::Vector3d c = onAxis + off * Eigen::Vector3d(std::cos(ang), std::sin(ang), 0.0);
        SimLeaf l = randomLeaf(rng, c);
        l.normal = (Eigen::Vector3d(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), -1.0)).normalized();
        l.axis = (l.normal.unitOrthogonal()).normalized();
        const double spin = rng.uniform(0.0, 2.0 * M_PI);
        l.axis = (std::cos(spin) * l.axis + std::sin(spin) * l.normal.cross(l.axis)).normalized();
        if (leafTouchesApple(l, trial.apples)) continue;
        trial.leaves.push_back(l);
        break;
      }
    }
    const double share = shareWith(trial, target);
    if (share >= 0.15 && share <= 0.5) {
      s = trial;
      done = true;
    }
  }
  return done;
}

// ---- The hard worlds -------------------------------------------------------------------
// Two worlds of hard cases share this code with different settings: the second world
// (World::kHoldout), which no parameter choice may look at, and the benchmark's own hard
// cases (World::kBenchmarkHard), which parameters may be tuned on. Every range differs
// between them, and so do their seeds (docs/evaluation.md "The second world").
struct HardSettings {
  // Target shapes, one third each: a sphere (aspect in sphere[]), oblate, prolate.
  double sphere[2];
  double oblate[2];
  double prolate[2];
  double radiusMm[2];
  double stemTiltDeg;
  int maxNeighbours;
  double neighbourGapMm[2];
  double neighbourMinDirZ;    // -0.35: a little in front of the target; 0: beside or behind
  double neighbourHideShare;  // what neighbours may hide of the target
  double bands[4][2];         // hidden share bands of the occluded cases
  double leafGapMm[2];        // in front of the target's skin
  int maxLeaves;
  double leafLengthMm[2];
  double laserMw[2];
  double backgroundMm[2];  // behind the target's centre
  double sunLux[2];
  double sunExposure[2];  // × the auto exposure, in sun (and direct light when fixedInDirect)
  bool fixedInDirect;
  double lumpyShare;        // of the fruit (targets and neighbours) that are lumpy
  double lumpAmplitude[2];  // their SimApple::lumpAmplitude
  uint64_t salt;
};

constexpr HardSettings kHoldoutSettings{.sphere = {1.0, 1.0},
                                        .oblate = {0.78, 0.95},
                                        .prolate = {1.02, 1.15},
                                        .radiusMm = {30.0, 50.0},
                                        .stemTiltDeg = 60.0,
                                        .maxNeighbours = 4,
                                        .neighbourGapMm = {0.0, 3.0},
                                        .neighbourMinDirZ = -0.35,
                                        .neighbourHideShare = 0.12,
                                        .bands = {{0.25, 0.40}, {0.45, 0.60}, {0.65, 0.80}, {0.80, 0.95}},
                                        .leafGapMm = {10.0, 60.0},
                                        .maxLeaves = 5,
                                        .leafLengthMm = {60.0, 130.0},
                                        .laserMw = {8.0, 30.0},
                                        .backgroundMm = {150.0, 1500.0},
                                        .sunLux = {30000.0, 90000.0},
                                        .sunExposure = {1.6, 2.6},
                                        .fixedInDirect = true,
                                        .lumpyShare = 0.4,
                                        .lumpAmplitude = {0.02, 0.07},
                                        .salt = 0x7B0D5EEDULL};
constexpr HardSettings kTuningHardSettings{.sphere = {0.97, 1.03},
                                           .oblate = {0.80, 0.97},
                                           .prolate = {1.0, 1.10},
                                           .radiusMm = {31.0, 49.0},
                                           .stemTiltDeg = 55.0,
                                           .maxNeighbours = 4,
                                           .neighbourGapMm = {0.0, 4.0},
                                           .neighbourMinDirZ = -0.30,
                                           .neighbourHideShare = 0.13,
                                           .bands = {{0.30, 0.45}, {0.45, 0.60}, {0.60, 0.75}, {0.72, 0.93}},
                                           .leafGapMm = {8.0, 90.0},
                                           .maxLeaves = 4,
                                           .leafLengthMm = {55.0, 115.0},
                                           .laserMw = {7.0, 26.0},
                                           .backgroundMm = {250.0, 1200.0},
                                           .sunLux = {25000.0, 70000.0},
                                           .sunExposure = {1.3, 2.2},
                                           .fixedInDirect = true,
                                           .lumpyShare = 0.35,
                                           .lumpAmplitude = {0.02, 0.06},
                                           .salt = 0x5EED4A4DULL};

const HardSettings* hardSettings(World w) {
  if (w == World::kHoldout) return &kHoldoutSettings;
  if (w == World::kBenchmarkHard) return &kTuningHardSettings;
  return nullptr;
}

// Lumps from a stream of their own, keyed by what the case stream already drew for the
// apple: the rest of the world is drawn as it was without them.
void addLumps(const HardSettings& h, SimApple& a) {
  const auto bits = [](double v) { return std::bit_cast<uint64_t>(v); };
  std::mt19937_64 lumpRng(h.salt ^ bits(a.radiusMm) ^ (bits(a.aspect) * 0x9E3779B97F4A7C15ULL) ^
                          (bits(a.skinRgb.x()) * 0xBF58476D1CE4E5B9ULL) ^ static_cast<uint64_t>(a.id));
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  if (unit(lumpRng) >= h.lumpyShare) return;
  a.lumpAmplitude = h.lumpAmplitude[0] + (h.lumpAmplitude[1] - h.lumpAmplitude[0]) * unit(lumpRng);
  a.lumpSeed = lumpRng();
}

SimApple hardApple(const HardSettings& h, CaseRng& rng, int id, std::string* shape) {
  SimApple a = randomApple(rng, id);
  a.radiusMm = rng.uniform(h.radiusMm[0], h.radiusMm[1]);
  const int kind = rng.integer(0, 2);
  const double* range = kind == 0 ? h.sphere : kind == 1 ? h.oblate : h.prolate;
  a.aspect = rng.uniform(range[0], range[1]);
  if (shape != nullptr) *shape = kind == 0 ? "sphere" : kind == 1 ? "oblate" : "prolate";
  const double tiltRad = rng.uniform(0.0, h.stemTiltDeg) * M_PI / 180.0;
  const double spinRad = rng.uniform(0.0, 2.0 * M_PI);
  a.stemAxis =
      Eigen::Vector3d(std::sin(tiltRad) * std::cos(spinRad), -std::cos(tiltRad), std::sin(tiltRad) * std::sin(spinRad));
  a.skinRgb = Eigen::Vector3d(rng.uniform(0.30, 0.60), rng.uniform(0.04, 0.12), rng.uniform(0.03, 0.08));
  addLumps(h, a);
  if (shape != nullptr && a.lumpAmplitude > 0.0) *shape += ", lumpy";
  return a;
}

// True when any point of the leaf's blade lies inside an apple or within 2 mm of it
// (sampled over the blade; the benchmark's test is a coarser bound that keeps every
// leaf a half-length away, which cannot put a leaf 10 mm in front of the skin).
bool leafCutsApple(const SimLeaf& l, const std::vector<SimApple>& apples) {
  const Eigen::Vector3d side = l.normal.cross(l.axis).normalized();
  for (const auto& ap : apples) {
    if ((l.centerMm - ap.centerMm).norm() > appleBoundMm(ap) + 0.5 * l.lengthMm + 3.0) continue;
    const Eigen::Matrix3d toLocal = appleFrame(ap).transpose();
    const double grow = 1.0 + ap.lumpAmplitude;  // a lumpy apple's highest lump
    const Eigen::Vector3d inv(1.0 / (ap.radiusMm * grow + 2.0), 1.0 / (ap.radiusMm * grow + 2.0),
                              1.0 / (ap.radiusMm * ap.aspect * grow + 2.0));
    for (int i = -8; i <= 8; ++i) {
      const double u = 0.5 * l.lengthMm * i / 8.0;
      const double half = 0.5 * l.widthMm * (1.0 - (2.0 * u / l.lengthMm) * (2.0 * u / l.lengthMm));
      for (int j = -4; j <= 4; ++j) {
        const Eigen::Vector3d p = l.centerMm + u * l.axis + half * (j / 4.0) * side;
        if ((toLocal * (p - ap.centerMm)).cwiseProduct(inv).norm() < 1.0) return true;
      }
    }
  }
  return false;
}

// Neighbours touching the target (or nearly), beside, behind or a little in front of it.
void addHardNeighbours(const HardSettings& h, SimScene& s, const SimApple& target, CaseRng& rng) {
  const int neighbours = rng.integer(0, h.maxNeighbours);
  for (int k = 0; k < neighbours; ++k) {
    for (int attempt = 0; attempt < 40; ++attempt) {
      SimApple a = hardApple(h, rng, 2 + k, nullptr);
      Eigen::Vector3d dir = rng.unitVector();
      dir.z() = h.neighbourMinDirZ < 0.0 ? std::max(dir.z(), h.neighbourMinDirZ) : std::abs(dir.z()) * 0.8;
      dir.normalize();
      a.centerMm = target.centerMm + dir * (appleBoundMm(target) + appleBoundMm(a) +
                                            rng.uniform(h.neighbourGapMm[0], h.neighbourGapMm[1]));
      bool ok = a.centerMm.z() + appleBoundMm(a) < s.background.depthMm;
      for (const auto& b : s.apples)
        ok = ok && (a.centerMm - b.centerMm).norm() > appleBoundMm(a) + appleBoundMm(b) - 0.5;
      if (!ok) continue;
      SimScene trial = s;
      trial.apples.push_back(a);
      if (shareWith(trial, target) > h.neighbourHideShare) continue;
      s.apples.push_back(a);
      break;
    }
  }
}

// Leaves close in front of the target's skin until the hidden share is in a band drawn
// per case.
bool occludeHard(const HardSettings& h, SimScene& s, const SimApple& target, CaseRng& rng) {
  const auto& band = h.bands[rng.integer(0, 3)];
  const Eigen::Vector3d tc = target.centerMm;
  for (int round = 0; round < 120; ++round) {
    SimScene trial = s;
    const int count = rng.integer(1, h.maxLeaves);
    for (int k = 0; k < count; ++k) {
      for (int attempt = 0; attempt < 20; ++attempt) {
        const double zl = tc.z() - appleBoundMm(target) - rng.uniform(h.leafGapMm[0], h.leafGapMm[1]);
        const double ang = rng.uniform(0.0, 2.0 * M_PI);
        const double off = rng.uniform(0.0, 1.1) * target.radiusMm;
        const Eigen::Vector3d c = tc * (zl / tc.z()) + off * Eigen::Vector3d(std::cos(ang), std::sin(ang), 0.0);
        SimLeaf l = randomLeaf(rng, c);
        l.lengthMm = rng.uniform(h.leafLengthMm[0], h.leafLengthMm[1]);
        l.widthMm = l.lengthMm * rng.uniform(0.4, 0.6);
        l.normal = Eigen::Vector3d(rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), -1.0).normalized();
        l.axis = l.normal.unitOrthogonal();
        const double spin = rng.uniform(0.0, 2.0 * M_PI);
        l.axis = (std::cos(spin) * l.axis + std::sin(spin) * l.normal.cross(l.axis)).normalized();
        if (leafCutsApple(l, trial.apples)) continue;
        trial.leaves.push_back(l);
        break;
      }
    }
    const double share = shareWith(trial, target);
    if (share >= band[0] && share <= band[1]) {
      s = trial;
      return true;
    }
  }
  return false;
}

// The hard world's light, laser and background, after the benchmark's own choices.
void hardConditions(const HardSettings& h, SimScene& s, const CaseSpec& spec, const SimApple& target, CaseRng& rng) {
  s.laser.powerMw = rng.uniform(h.laserMw[0], h.laserMw[1]);
  s.background.depthMm = target.centerMm.z() + rng.uniform(h.backgroundMm[0], h.backgroundMm[1]);
  if (spec.lighting == LightingKind::kFullSun) s.lighting.directLux = rng.uniform(h.sunLux[0], h.sunLux[1]);
}

// A fixed exposure in sun: a multiple of what an auto-exposure would pick, so the red of
// sunlit skin comes near full scale (the daemon does not meter the scene).
int64_t hardExposureUs(const HardSettings& h, const SimScene& s, const CaseSpec& spec, CaseRng& rng) {
  const int64_t autoUs = autoExposureUs(s);
  const bool fixed =
      spec.lighting == LightingKind::kFullSun || (h.fixedInDirect && spec.lighting == LightingKind::kDirect);
  if (!fixed) return autoUs;
  return std::clamp<int64_t>(
      std::llround(static_cast<double>(autoUs) * rng.uniform(h.sunExposure[0], h.sunExposure[1])), 20, 3000);
}

}  // namespace

Result<OrchardCase> makeOrchardCase(const CaseSpec& spec, uint64_t seed) {
  const HardSettings* hard = hardSettings(spec.world);
  CaseRng rng(seed * 0x9E3779B97F4A7C15ULL + (hard != nullptr ? hard->salt : 0x1234567ULL));
  OrchardCase oc;
  SimScene& s = oc.scene;
  s = defaultScene();
  s.seed = seed;
  s.sensor.bayer = spec.bayer;
  s.sensor.bandpassFwhmNm = spec.bandpassFwhmNm;
  s.apples.clear();
  setLighting(s, spec.lighting, rng, &oc.lux);
  const auto& cam = s.truth.camera;
  const auto& las = s.truth.laser;

  // The target: at the distance, where the slide can centre five stops on it, inside
  // the central part of the image.
  oc.shape = "oblate";
  SimApple target = hard != nullptr ? hardApple(*hard, rng, 1, &oc.shape) : randomApple(rng, 1);
  bool placed = false;
  for (int attempt = 0; attempt < 200 && !placed; ++attempt) {
    const double z = spec.distanceMm + rng.uniform(-25.0, 25.0);
    const double sc = rng.uniform(spec.slideCentreMinMm, spec.slideCentreMaxMm);
    const double y = rng.uniform(-0.55, 0.55) * z * cam.cyPx / cam.fyPx;
    const Eigen::Vector3d& n = las.planeNormal;
    const double x = (las.planeOffsetAt(sc) - n.y() * y - n.z() * z) / n.x();
    target.centerMm = Eigen::Vector3d(x, y, z);
    const Eigen::Vector2d px = projectPx(cam, target.centerMm);
    const double rPx = target.radiusMm * cam.fxPx / z;
    placed = px.x() - 2.5 * rPx > 0 && px.x() + 2.5 * rPx < cam.widthPx && px.y() - 2.5 * rPx > 0 &&
             px.y() + 2.5 * rPx < cam.heightPx;
    oc.slideCentreMm = sc;
  }
  if (!placed) return Status(Error::kInternal, "no place for the target apple");
  s.apples.push_back(target);
  const Eigen::Vector3d tc = target.centerMm;

  // Background: foliage with sky outdoors, a backdrop in the lab.
  if (spec.lighting == LightingKind::kLab) {
    s.background.kind = SimBackground::Kind::kBackdrop;
    s.background.depthMm = std::max(tc.z() + 500.0, rng.uniform(1900.0, 2600.0));
    s.background.albedoRgb = Eigen::Vector3d(rng.uniform(0.08, 0.2), rng.uniform(0.12, 0.22), rng.uniform(0.08, 0.15));
  } else {
    s.background.kind = SimBackground::Kind::kFoliage;
    s.background.depthMm = tc.z() + rng.uniform(400.0, 1200.0);
    s.background.skyShare = rng.uniform(0.05, 0.25);
    s.background.albedoRgb = Eigen::Vector3d(rng.uniform(0.05, 0.09), rng.uniform(0.12, 0.18), rng.uniform(0.04, 0.06));
    s.background.textureCellMm = rng.uniform(25.0, 45.0);
  }

  if (hard != nullptr) {
    hardConditions(*hard, s, spec, target, rng);
    oc.lux = s.lighting.totalLux();
    addHardNeighbours(*hard, s, target, rng);
  } else {
    addNeighbours(s, target, spec.maxNeighbours, rng);
  }
  addCanopy(s, target, rng);
  addBranches(s, target, rng);

  // Occlusion: one to three leaves in front of the target, until 15-50 % of it is hidden
  // (the second world: up to five, 10-60 mm in front, up to 95 %).
  if (spec.occluded && hard != nullptr && !occludeHard(*hard, s, target, rng))
    return Status(Error::kInternal, "could not occlude the target in its band");
  if (spec.occluded && hard == nullptr && !occludeTarget(s, target, rng))
    return Status(Error::kInternal, "could not occlude the target by 15-50 %");
  oc.occlusionShare = occlusionShare(s, *s.apple(1));

  // What the RGB-D camera reports: the truth plus its error.
  const double sigma = roughSigmaMm(tc.norm());
  oc.roughMm = tc + sigma * Eigen::Vector3d(rng.normal(), rng.normal(), rng.normal());
  s.sensor.exposureUs = hard != nullptr ? hardExposureUs(*hard, s, spec, rng) : autoExposureUs(s);
  oc.targetId = 1;
  char buf[256];
  std::snprintf(buf, sizeof buf, "%s %.0f lux, target d=%.0f mm at %.0f mm, %zu apples, %zu leaves, %zu branches, occlusion %.0f %%",
                lightingName(spec.lighting), oc.lux, 2.0 * target.radiusMm, tc.norm(), s.apples.size(), s.leaves.size(),
                s.branches.size(), 100.0 * oc.occlusionShare);
  oc.description = buf;
  if (Status st = s.validate(); !st) return Status(Error::kInternal, "generated scene is invalid: " + st.toString());
  return oc;
}

}  // namespace alacs::sim

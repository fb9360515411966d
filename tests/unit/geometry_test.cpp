#include <catch2/catch.hpp>

#include <cstdio>
#include <fstream>
#include <random>

#include "geometry/calibration.h"
#include "geometry/sphere_fit.h"
#include "geometry/triangulation.h"
#include "sim/scene.h"
#include "temp_dir.h"

using namespace alacs;
using namespace alacs::geometry;

TEST_CASE("Triangulation inverts projection onto the laser plane", "[geometry]") {
  const Calibration cal = sim::defaultScene().truth;
  const double slide = 87.5;
  // A point on the plane at slide 87.5, 1.3 m away.
  const Eigen::Vector3d n = cal.laser.planeNormal;
  Eigen::Vector3d p(0.0, 55.0, 1300.0);
  p.x() = (cal.laser.planeOffsetAt(slide) - n.y() * p.y() - n.z() * p.z()) / n.x();
  const PixelPoint px = projectPoint(cal.camera, p);
  const auto xn = undistortPixels(cal.camera, {px});
  const TriangulatedPoint t = triangulate(cal.laser, slide, xn[0]);
  REQUIRE(t.valid);
  CHECK((t.pointMm - p).norm() < 1e-3);
}

TEST_CASE("Degenerate rays give an invalid point, never NaN", "[geometry]") {
  LaserGeometry laser;
  laser.planeNormal = Eigen::Vector3d(1, 0, 0);
  laser.planeOffsetMm = 100.0;
  SECTION("ray parallel to the plane") { CHECK_FALSE(triangulate(laser, 0, {0.0, 0.3}).valid); }
  SECTION("point behind the camera") { CHECK_FALSE(triangulate(laser, 0, {-0.1, 0.0}).valid); }
  SECTION("point beyond the working range") { CHECK_FALSE(triangulate(laser, 0, {0.01, 0.0}).valid); }
  SECTION("inside the range") {
    const auto t = triangulate(laser, 0, {0.1, 0.0});
    REQUIRE(t.valid);
    CHECK(t.pointMm.z() == Approx(1000.0));
  }
  SECTION("non-finite input") { CHECK_FALSE(triangulate(laser, 0, {std::nan(""), 0.0}).valid); }
}

TEST_CASE("Robust sphere fit ignores leaf points", "[geometry]") {
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.3);
  const Eigen::Vector3d c(20, -10, 1200);
  const double r = 38.0;
  std::vector<Eigen::Vector3d> pts;
  std::uniform_real_distribution<double> u(-0.7, 0.7);
  for (int i = 0; i < 400; ++i) {
    // Front cap, as the camera sees it.
    Eigen::Vector3d d(u(rng), u(rng), -1.0);
    d.normalize();
    pts.push_back(c + r * d + Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
  }
  for (int i = 0; i < 60; ++i) pts.push_back(c + Eigen::Vector3d(u(rng) * 40, u(rng) * 40, -r - 25.0));  // a leaf in front
  auto fit = fitSphere(pts);
  REQUIRE(fit.isOk());
  CHECK((fit->centerMm - c).norm() < 1.5);
  CHECK(fit->radiusMm == Approx(r).margin(1.0));
  CHECK(fitSphere({}).status().code() == Error::kBadInput);
}

TEST_CASE("Calibration files round-trip and bad ones name the field", "[geometry][calibration]") {
  const Calibration cal = sim::defaultScene().truth;
  const test::TempDir tmp;
  const std::string path = tmp.file("cal.json");
  REQUIRE(saveCalibration(cal, path).isOk());
  auto back = loadCalibration(path);
  REQUIRE(back.isOk());
  CHECK(back->camera.fxPx == Approx(cal.camera.fxPx));
  CHECK((back->laser.planeNormal - cal.laser.planeNormal).norm() < 1e-9);

  CHECK(loadCalibration("/nonexistent/cal.json").status().code() == Error::kNotFound);
  auto notJson = loadCalibration(tmp.write("bad.json", "{ this is not json"));
  CHECK(notJson.status().code() == Error::kBadInput);
  auto missing = loadCalibration(tmp.write("missing.json", R"({"camera": {"width_px": 2048}, "laser": {}})"));
  CHECK(missing.status().reason().find("camera.height_px") != std::string::npos);
  std::ifstream in(path);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto pos = text.find("\"slide_scale\": ");
  std::string badScale = text.substr(0, pos) + "\"slide_scale\": 7" + text.substr(text.find('}', pos));
  auto range = loadCalibration(tmp.write("range.json", badScale));
  CHECK(range.status().reason().find("laser.slide_scale") != std::string::npos);
}

// What the bus says about an estimate (app/result_status.h): only a fit that is the target
// as far as the sensor can tell goes out as MEASURED.
#include <catch2/catch.hpp>

#include "app/result_status.h"

using namespace alacs;
using protocol::ResultReason;
using protocol::ResultStatus;

TEST_CASE("Result status: each kind of estimate says what it is", "[app][result]") {
  localize::AppleEstimate est;
  est.sphereFit = true;
  SECTION("a fit of the target is a measurement, with no reason") {
    const app::ResultClass rc = app::classifyEstimate(est);
    CHECK(rc.status == ResultStatus::kMeasured);
    CHECK(rc.reason == ResultReason::kNone);
  }
  SECTION("the widened search's fit is a measurement found outside the gate") {
    est.outsideGate = true;
    const app::ResultClass rc = app::classifyEstimate(est);
    CHECK(rc.status == ResultStatus::kMeasured);
    CHECK(rc.reason == ResultReason::kOutsideGate);
  }
  SECTION("a fit far from the rough position is ambiguous, and says why") {
    est.outsideGate = true;
    est.doubt = localize::AppleEstimate::Doubt::kFarFromRough;
    const app::ResultClass rc = app::classifyEstimate(est);
    CHECK(rc.status == ResultStatus::kAmbiguous);
    CHECK(rc.reason == ResultReason::kFarFromRough);
  }
  SECTION("two objects that explain the lines alike are two surfaces") {
    est.doubt = localize::AppleEstimate::Doubt::kTwoSurfaces;
    const app::ResultClass rc = app::classifyEstimate(est);
    CHECK(rc.status == ResultStatus::kAmbiguous);
    CHECK(rc.reason == ResultReason::kTwoSurfaces);
  }
  SECTION("without a sphere fit it is never a measurement") {
    est.sphereFit = false;
    const app::ResultClass rc = app::classifyEstimate(est);
    CHECK(rc.status == ResultStatus::kRoughOnly);
    CHECK(rc.reason == ResultReason::kTooFewLines);
  }
  SECTION("the rough position in place of a fit that was another object says why") {
    est.sphereFit = false;
    est.doubt = localize::AppleEstimate::Doubt::kFarFromRough;
    const app::ResultClass rc = app::classifyEstimate(est);
    CHECK(rc.status == ResultStatus::kRoughOnly);
    CHECK(rc.reason == ResultReason::kFarFromRough);
  }
}

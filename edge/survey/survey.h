// Scan-all ("survey"): sweep the whole stroke, extract the laser line over the full frame
// at each stop, triangulate everything, split the points into objects by 3D proximity,
// and fuse each object with the localizer's own fusion. Pure logic, like the localizer.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "common/result.h"
#include "localize/localizer.h"

namespace alacs::survey {

struct SurveyParams {
  double stopSpacingMm = 8.0;   // the sheet moves ~8 mm on the fruit between stops: ≥ 5 lines on an 80 mm apple
  double clusterCellMm = 12.0;  // points closer than about this belong together
  size_t minPoints = 60;        // smaller clusters are leaves, twigs or noise
  size_t minCellPoints = 4;     // sparser grid cells (silhouette mixed pixels) link nothing
  double maxExtentMm = 130.0;   // larger clusters are foliage walls, not fruit
  double maxCenterSigmaMm = 3.0;  // a cluster whose sphere centre is this uncertain is not a fruit
                                  // (compared with the approach point's σ, which holds the shape term,
                                  // scan.shape_irregularity_pct: ~0.8 mm in quadrature on an 80 mm fruit)
  int maxObjects = 15;          // ALACS_ResultObject.ObjIndex is 4 bits
  Status validate() const;
};

// Slide positions of the sweep, from 0 to the stroke.
std::vector<double> surveyStops(double strokeMm, const SurveyParams& p);

class Survey {
 public:
  Survey(const geometry::Calibration& cal, const image::LleParams& lle, const localize::ScanParams& scan,
         const SurveyParams& params);

  // One frame of the sweep at `slideMm`: full-frame LLE and triangulation.
  Status addFrame(const image::ImageView& frame, double slideMm, image::LleWorkspace& ws);

  // The fruits found, nearest first. Empty when none.
  std::vector<localize::AppleEstimate> finish() const;

  size_t pointCount() const { return points_.size(); }

 private:
  struct Point {
    Eigen::Vector3d mm;
    int stop;
  };
  geometry::Calibration cal_;
  image::LleParams lle_;
  localize::ScanParams scan_;
  SurveyParams params_;
  std::vector<Point> points_;
  std::vector<double> stopsMm_;
};

}  // namespace alacs::survey

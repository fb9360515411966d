// Ray casting against the scene's objects (apples, leaves, branches, the calibration
// board). The background wall is not an object here: the renderer handles it. Used by
// the renderer (primary, shadow and laser rays) and by the truth (visibility).
// Thread-safe after construction (const queries).
#pragma once

#include <Eigen/Core>
#include <limits>
#include <vector>

#include "sim/scene.h"

namespace alacs::sim {

enum class SurfaceKind : uint8_t { kApple, kLeaf, kBranch, kBoard };

struct Hit {
  double t = std::numeric_limits<double>::infinity();  // distance along the (unit) ray, mm
  SurfaceKind kind = SurfaceKind::kApple;
  int index = -1;                                       // into the scene's list of that kind
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();     // unit, facing the ray's origin
  bool valid() const { return index >= 0; }
};

class SceneGeometry {
 public:
  explicit SceneGeometry(const SimScene& scene);

  struct Object {
    SurfaceKind kind;
    int index;
    Eigen::Vector3d boundCenter;
    double boundRadius;
    Eigen::Vector3d aabbMin;
    Eigen::Vector3d aabbMax;
  };
  const std::vector<Object>& objects() const { return objects_; }

  // Nearest hit with t in (tMin, tMax) along origin + t·dir (dir unit). When
  // `candidates` is given only those objects (indices into objects()) are tested.
  bool intersect(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double tMin, double tMax, Hit* hit,
                 const std::vector<int>* candidates = nullptr) const;
  // Whether anything other than object (kind, index) blocks the segment. Pass index -1
  // to test every object.
  bool blocked(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double tMin, double tMax,
               SurfaceKind skipKind, int skipIndex) const;
  // Hit test of one object (object index into objects()).
  bool intersectObject(int object, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double tMin, double tMax,
                       Hit* hit) const;

  const SimScene& scene() const { return scene_; }

 private:
  const SimScene& scene_;
  std::vector<Object> objects_;
  std::vector<Eigen::Vector3d> leafSide_;  // normal × axis, per leaf
  std::vector<Eigen::Matrix3d> appleToLocal_;  // per apple: Rᵀ, then scaled by appleInvAxes_
  std::vector<Eigen::Vector3d> appleInvAxes_;  // 1/a, 1/a, 1/c
  std::vector<AppleShape> appleShapes_;        // per apple: the lumpy ones are marched
};

}  // namespace alacs::sim

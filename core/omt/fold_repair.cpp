#include "omt/fold_repair.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "common/error.hpp"
#include "conformal/conformal_map.hpp"
#include "conformal/mobius.hpp"
#include "mesh/geometry.hpp"
#include "omt/barrier_energy.hpp"
#include "quality/quality.hpp"

namespace brenier::omt {
using detail::BarrierFace;
using detail::barrier_face;
using detail::PlaneBarrier;
using detail::SphereBarrier;
using detail::untangle_by_barrier;

namespace {

// The barrier repair of a sphere map's folds (repair_sphere_folds_by_barrier): regions of
// growing rings about each folded face untangled, each kept only if it lowers the folds
// without raising the area distortion and leaves the map covering the sphere once.
class SphereFoldRepair {
 public:
  SphereFoldRepair(const mesh::TriMesh& m, BarrierSpace space)
      : m_(m), space_(space), nv_(m.num_vertices()), nf_(m.num_faces()), area_(mesh::face_areas(m)), star_(nv_),
        ring_(nv_) {
    for (int f = 0; f < nf_; ++f)
      for (int k = 0; k < 3; ++k) {
        star_[m.F(f, k)].push_back(f);
        ring_[m.F(f, k)].push_back(m.F(f, (k + 1) % 3));
      }
  }

  bool folded_face(const mesh::Vertices& Z, int f) const { return conformal::face_folded(m_, Z, f, true); }
  int count_folds(const mesh::Vertices& Z) const {
    int k = 0;
    for (int f = 0; f < nf_; ++f) k += folded_face(Z, f);
    return k;
  }
  // Mean |log area ratio| over the faces.
  double distortion(const mesh::Vertices& Z) const {
    const Eigen::VectorXd r = quality::area_log_ratios(m_, Z);
    double sum = 0;
    for (Eigen::Index f = 0; f < r.size(); ++f) sum += std::abs(r[f]);
    return sum / static_cast<double>(r.size());
  }
  // Target areas in the energy's measure det(a, b, c) / 2, whose sum is the map's.
  void set_scale(const mesh::Vertices& X) {
    double total = 0;
    for (int f = 0; f < nf_; ++f) total += 0.5 * X.row(m_.F(f, 0)).dot(X.row(m_.F(f, 1)).cross(X.row(m_.F(f, 2))));
    scale_ = total / area_.sum();
  }

  // The distance in edges from the seed face's corners, up to `max_rings` (-1 beyond).
  std::vector<int> rings_from(int seed, int max_rings) const {
    std::vector<int> dist(nv_, -1), queue;
    for (int k = 0; k < 3; ++k) dist[m_.F(seed, k)] = 0, queue.push_back(m_.F(seed, k));
    for (size_t q = 0; q < queue.size(); ++q)
      if (dist[queue[q]] < max_rings)
        for (int w : ring_[queue[q]])
          if (dist[w] < 0) dist[w] = dist[queue[q]] + 1, queue.push_back(w);
    return dist;
  }

  // The vertices within `rings` (free) and the faces around them.
  int region(const std::vector<int>& dist, int rings, std::vector<char>& is_free, std::vector<int>& faces) const {
    is_free.assign(nv_, 0);
    faces.clear();
    std::vector<char> seen(nf_, 0);
    int nfree = 0;
    for (int v = 0; v < nv_; ++v)
      if (dist[v] >= 0 && dist[v] <= rings) {
        is_free[v] = 1, ++nfree;
        for (int f : star_[v])
          if (!seen[f]) seen[f] = 1, faces.push_back(f);
      }
    return nfree;
  }

  // Moves the free rows of Z over `faces` by the barrier untangling, on the sphere or in the
  // region's chart (whose areas are the sphere's times (1 + |z|^2)^2 / 4 at the face).
  void untangle(const std::vector<int>& faces, mesh::Vertices& Z, const std::vector<char>& free) const {
    if (space_ == BarrierSpace::kSphere) {
      std::vector<BarrierFace> ref;
      ref.reserve(faces.size());
      for (int f : faces) ref.push_back(reference(f, area_[f] * scale_));
      untangle_by_barrier<SphereBarrier>(ref, Z, free);
      return;
    }
    untangle_in_chart(faces, Z, free);
  }

 private:
  // The reference triangle of face f (m's shape) with target area a in the energy's measure.
  BarrierFace reference(int f, double a) const {
    return barrier_face(m_.F(f, 0), m_.F(f, 1), m_.F(f, 2), m_.V.row(m_.F(f, 0)), m_.V.row(m_.F(f, 1)),
                        m_.V.row(m_.F(f, 2)), a);
  }

  // The chart: the stereographic projection (conformal::stereographic) from the antipode of
  // the free vertices' centre, mirrored (conjugated) so that it keeps orientation: a face
  // turned outward on the sphere turns counter-clockwise in the plane. (The vertex farthest
  // from the seed in the mesh was tried as the pole too, for regions whose image spans a
  // hemisphere: dino came out with 5 folds instead of 2.)
  void untangle_in_chart(const std::vector<int>& faces, mesh::Vertices& Z, const std::vector<char>& free) const {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    for (int v = 0; v < nv_; ++v)
      if (free[v]) centre += Z.row(v).transpose();
    const Eigen::Matrix3d R =
        Eigen::Quaterniond::FromTwoVectors(-centre.normalized(), Eigen::Vector3d::UnitZ()).toRotationMatrix();
    mesh::Vertices P = mesh::Vertices::Zero(nv_, 3);
    for (int f : faces)
      for (int k = 0; k < 3; ++k) {
        const conformal::Complex z = std::conj(conformal::stereographic(R * Z.row(m_.F(f, k)).transpose()));
        P.row(m_.F(f, k)) << z.real(), z.imag(), 0;
      }
    std::vector<BarrierFace> ref;
    ref.reserve(faces.size());
    for (int f : faces) {
      const double r2 = ((P.row(m_.F(f, 0)) + P.row(m_.F(f, 1)) + P.row(m_.F(f, 2))) / 3).squaredNorm();
      ref.push_back(reference(f, area_[f] * scale_ * (1 + r2) * (1 + r2) / 4));
    }
    untangle_by_barrier<PlaneBarrier>(ref, P, free);
    for (int v = 0; v < nv_; ++v)
      if (free[v])
        Z.row(v) = (R.transpose() * conformal::inverse_stereographic(std::conj(conformal::Complex(P(v, 0), P(v, 1)))))
                       .transpose();
  }

  const mesh::TriMesh& m_;
  BarrierSpace space_;
  int nv_, nf_;
  Eigen::VectorXd area_;
  std::vector<std::vector<int>> star_, ring_;
  double scale_ = 1;
};

}  // namespace

int repair_sphere_folds_by_barrier(const mesh::TriMesh& m, mesh::Vertices& X, int& folded,
                                   const std::function<bool(int round, int folds)>& keep_going, BarrierSpace space) {
  const int nv = m.num_vertices(), nf = m.num_faces();
  SphereFoldRepair repair(m, space);
  folded = repair.count_folds(X);
  const double allowed = repair.distortion(X);
  repair.set_scale(X);
  int moved = 0;
  long work = 0;
  bool out_of_budget = false;
  std::vector<char> tried(nf, 0), is_free;
  std::vector<int> region_faces;
  for (int round = 0; round < nf && folded > 0 && !out_of_budget; ++round) {  // each face seeds once
    int seed = -1;
    for (int f = 0; f < nf && seed < 0; ++f)
      if (!tried[f] && repair.folded_face(X, f)) seed = f;
    if (seed < 0) break;
    if (keep_going && !keep_going(round, folded)) fail(ErrorCode::kCancelled, "fold repair cancelled");
    tried[seed] = 1;
    // The regions are the vertices within 1, 2, 4, 8 or 16 rings of the seed face.
    constexpr int kMaxRings = 16;
    const std::vector<int> dist = repair.rings_from(seed, kMaxRings);
    int last_free = -1;
    for (int rings : {1, 2, 4, 8, kMaxRings}) {
      const int nfree = repair.region(dist, rings, is_free, region_faces);
      if (nfree == last_free) break;  // the whole component is free already
      last_free = nfree;
      // A budget of free vertices untangled, all clusters and tries together: a map the
      // repair can mend takes well under one pass over its vertices (bull 0.9 nv,
      // armadillo 0.4 nv, camel 0.3 nv), while one it cannot kept man's going for minutes.
      if (work + nfree > 2L * nv + 1000) {
        out_of_budget = true;
        break;
      }
      work += nfree;
      mesh::Vertices back = X;
      repair.untangle(region_faces, back, is_free);
      if (!back.allFinite()) continue;
      const int left = repair.count_folds(back);
      const double after = repair.distortion(back);
      // A region untangled inside a fixed ring can still wrap around the sphere with every
      // face turned outward (cactus and u did, covering it 4 times): only a repair that
      // leaves the map's degree at 1 is a repair.
      if (left < folded && after <= allowed && quality::covers_once(quality::sphere_degree(m.F, back))) {
        X = std::move(back);
        folded = left;
        moved += nfree;
        repair.set_scale(X);
        break;
      }
    }
  }
  return moved;
}

}  // namespace brenier::omt

// The map g between two parameter domains of surface registration (dissertation sec. 4.3,
// Alg. 7 step 2): g takes the source's domain mesh (its image on the unit disk or sphere
// under phi1) onto the target's domain, sends every source landmark exactly onto its target
// landmark, and folds no face.
//
// Alg. 7 asks for a harmonic map with the landmarks as hard constraints. With the boundary
// alone that map is a rotation of the disk (harmonic, and a diffeomorphism by Rado's theorem,
// Thm 4.1), and it is where we start: the least-squares turn of the landmarks. Interior hard
// constraints, though, can make a harmonic map fold (Rado's hypotheses no longer hold), so the
// interior landmarks are carried to their targets by continuation along straight paths: each
// step moves the mesh by a smooth displacement that is exact at the landmarks (a thin-plate
// spline through their displacements, cut off to vanish on the circle), and is taken only if
// no face turns over, halved otherwise. Boundary landmarks first move the boundary along the
// circle by a monotone piecewise-linear map of the angle, the interior following as the
// harmonic map with the mesh's mean value weights (Floater 2003), which cannot fold for a
// convex boundary. Slivers of the domain mesh (faces thinner than 1 % of their longest edge,
// as three OMT cell centroids can fall nearly in line) are left out of that fold test: a
// smooth step turns them over long before the mesh around them folds. Those that turned are
// unfolded afterwards by local moves with the landmarks held, or the pair is refused.
//
// On the sphere the landmarks first fix a rotation (Kabsch), then the same steps run in the
// stereographic plane seen from a pole far from every landmark, on the vertices inside a
// circle that holds every landmark path; outside it g is that rotation. Where both starts
// are refused there, they are tried again with faces that become slivers on the way let turn
// (a long thin centroid face squeezed by the steps stopped them at any length), and what
// turned is unfolded afterwards, by local moves and then by the area-preserving maps' barrier
// untangling (omt/fold_repair.hpp), the landmarks held. Without it, every pair of cow's
// area-preserving domains was refused (bench/RESULTS.md, session 68).
//
// Conformal parameter domains are unique only up to the Moebius group (Thm 2.13 on the disk,
// sec. 3.2.5 on the sphere), so g can also start from the least-squares Moebius map of the
// landmarks (a turn composed with the disk's or the ball's automorphism sending a point a to
// 0, fitted by Levenberg-Marquardt): a bijection, conformal, and on the disk harmonic like the
// turn (it is holomorphic). The spline steps then carry only what no Moebius map fits. Where
// the steps cannot carry the landmarks unfolded from the start asked for, the other start is
// tried before refusing: the area-preserving domains of mannequin-devil and its remeshed,
// deformed copies are matched from the Moebius start where the turn's paths fold the mesh.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::registration {

/// The rotation R taking the points p nearest the points q, sum |R p_i - q_i|^2 least
/// (Kabsch); for one point the shortest turn, for none the identity.
Eigen::Matrix3d best_rotation(const std::vector<Eigen::Vector3d>& p, const std::vector<Eigen::Vector3d>& q);

/// best_rotation of the landmarks: rows `source_landmarks` of `source` onto rows
/// `target_landmarks` of `target`, paired by order (two maps of paired meshes onto the sphere:
/// the rotation that carries one map's pole, or any point, over to the other's).
Eigen::Matrix3d landmark_rotation(const mesh::Vertices& source, const std::vector<int>& source_landmarks,
                                  const mesh::Vertices& target, const std::vector<int>& target_landmarks);

/// One landmark pair: a vertex of the source's domain mesh, the point q of the target's
/// domain it goes to, and whether q lies on the disk's boundary circle (the target's boundary
/// vertex). `name` names it in messages.
struct LandmarkPair {
  int vertex = -1;
  Eigen::Vector3d q = Eigen::Vector3d::Zero();
  bool q_on_boundary = false;
  std::string name;
};

/// What g starts from before the landmark steps: the least-squares rotation (area-preserving
/// domains) or the least-squares Moebius transformation (conformal domains).
enum class MatchStart { kRotation, kMobius };

struct DomainMatch {
  mesh::Vertices mapped;       // g of every vertex (#V by 3; z = 0 on the disk)
  double rotation_angle = 0;   // the least-squares turn g starts from, radians
  MatchStart start = MatchStart::kRotation;  // the start used (the other one where the first was refused)
  Eigen::Vector3d mobius_a = Eigen::Vector3d::Zero();  // the automorphism's a (zero: a rotation)
  double start_rms = 0;        // the landmarks' rms distance from their targets after the start
  int steps = 0;               // harmonic steps that moved the landmarks (0: the turn sufficed)
  double max_landmark_error = 0;  // max |g(p_k) - q_k| over the landmarks (round-off)
  bool slivers_let_turn = false;  // the steps let faces turn that became slivers on the way
  int mended_faces = 0;           // faces folded after the steps, unfolded afterwards
};

/// g on the unit disk: `points` (#V by 3, z = 0) the source's domain mesh with `faces`, its
/// boundary vertices on the unit circle. Throws Error(kInvalidArgument) naming the landmarks
/// for pairs no homeomorphism of the disk matches (a boundary landmark paired with an interior
/// one, two landmarks at one place, boundary landmarks in a different order around the
/// circle) and for landmarks the mesh cannot follow unfolded (steps below 1e-6 of the way),
/// naming the two nearest the fold.
DomainMatch match_disks(const mesh::Vertices& points, const mesh::Faces& faces, const std::vector<LandmarkPair>& landmarks,
                        MatchStart start = MatchStart::kRotation);

/// g on the unit sphere (`points` on the sphere, a closed mesh). Errors as match_disks.
DomainMatch match_spheres(const mesh::Vertices& points, const mesh::Faces& faces,
                          const std::vector<LandmarkPair>& landmarks, MatchStart start = MatchStart::kRotation);

}  // namespace brenier::registration

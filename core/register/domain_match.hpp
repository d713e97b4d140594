// The map g between two parameter domains of surface registration (dissertation sec. 4.3,
// Alg. 7 step 2): g takes the source's domain mesh (its image on the unit disk or sphere
// under phi1) onto the target's domain, sends every source landmark exactly onto its target
// landmark, and folds no face.
//
// Alg. 7 asks for a harmonic map with the landmarks as hard constraints. With the boundary
// alone that map is a rotation of the disk (harmonic, and a diffeomorphism by Rado's theorem,
// Thm 4.1), and it is where we start: the least-squares turn of the landmarks. Interior hard
// constraints, though, can make a harmonic map fold (Rado's hypotheses no longer hold), so the
// landmarks are carried to their targets by continuation: in steps along straight paths,
// each step the discrete harmonic map with the landmarks (and the boundary) at their new
// places, with the mean value weights (Floater 2003) of the mesh as the last step left it.
// Those weights reproduce the mesh exactly, so a step is the identity plus a smooth harmonic
// displacement; a step is taken only if no face turns over, and halves otherwise. So g is a
// harmonic map with hard constraints wherever one step suffices, and a composition of
// near-identity harmonic steps, each checked unfolded, where the landmarks move far. Boundary
// landmarks move the boundary along the circle by a monotone piecewise-linear map of the angle.
//
// On the sphere the landmarks first fix a rotation (Kabsch), then the same steps run in the
// stereographic plane seen from a pole far from every landmark, on the vertices inside a
// circle that holds every landmark path; outside it g is that rotation.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::registration {

/// One landmark pair: a vertex of the source's domain mesh, the point q of the target's
/// domain it goes to, and whether q lies on the disk's boundary circle (the target's boundary
/// vertex). `name` names it in messages.
struct LandmarkPair {
  int vertex = -1;
  Eigen::Vector3d q = Eigen::Vector3d::Zero();
  bool q_on_boundary = false;
  std::string name;
};

struct DomainMatch {
  mesh::Vertices mapped;       // g of every vertex (#V by 3; z = 0 on the disk)
  double rotation_angle = 0;   // the least-squares turn g starts from, radians
  int steps = 0;               // harmonic steps that moved the landmarks (0: the turn sufficed)
  double max_landmark_error = 0;  // max |g(p_k) - q_k| over the landmarks (round-off)
};

/// g on the unit disk: `points` (#V by 3, z = 0) the source's domain mesh with `faces`, its
/// boundary vertices on the unit circle. Throws Error(kInvalidArgument) naming the landmarks
/// for pairs no homeomorphism of the disk matches (a boundary landmark paired with an interior
/// one, two landmarks at one place, boundary landmarks in a different order around the
/// circle) and for landmarks the mesh cannot follow unfolded (steps below 1e-6 of the way),
/// naming the two nearest the fold.
DomainMatch match_disks(const mesh::Vertices& points, const mesh::Faces& faces, const std::vector<LandmarkPair>& landmarks);

/// g on the unit sphere (`points` on the sphere, a closed mesh). Errors as match_disks.
DomainMatch match_spheres(const mesh::Vertices& points, const mesh::Faces& faces,
                          const std::vector<LandmarkPair>& landmarks);

}  // namespace brenier::registration

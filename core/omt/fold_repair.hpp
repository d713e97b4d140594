// Fold repair of area-preserving maps by a barrier energy that keeps areas (after Garanzha,
// Kaporin, Kudryavtseva, Protais, Ray, Sokolov, "Foldover-free maps in 50 lines of code",
// ACM TOG 2021). The centroids of neighbouring power cells (Alg. 3, step 4) can come out in
// the wrong order on coarse or CAD-like meshes; a Tutte repair removes such folds but pulls
// the region toward a harmonic layout, trading folds for area distortion. Here the free
// vertices instead minimize, per face f with Jacobian J_f against a reference triangle of
// the face's target area,
//     a_f [ theta (det J^2 + 1) + (1 - theta) |J|_F^2 ] / chi(det J, eps),
//     chi(D, eps) = (D + sqrt(eps^2 + D^2)) / 2,
// which for eps -> 0 is infinite on folded faces and least at det J = 1 (area kept) with J
// a rotation (shape kept). eps starts large enough that a folded start has finite energy
// and shrinks with the smallest det J, so the minimizer leaves the folds; once every face
// turns the right way the energy is a barrier and no fold comes back. A region whose deepest
// fold has stopped rising while eps is already small against it is given up before the
// schedule's end (barrier_energy.hpp, untangling_stalled), and the next, larger region is
// tried.
#pragma once

#include <functional>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::omt {

/// Where a cluster is untangled: on the sphere itself (x = y / |y|, orientation by the triple
/// product), or in a planar chart, the stereographic projection from the antipode of the
/// cluster's centre (mirrored to keep orientation), where det J is the plane's and a region
/// held by its fixed ring cannot wrap around the sphere while its faces all turn outward.
/// The chart's target areas are the sphere's times the projection's area factor
/// (1 + |z|^2)^2 / 4 at each face.
enum class BarrierSpace { kSphere, kChart };

/// What a repair may change. An area-preserving map's repair keeps its mean |log area ratio|
/// from rising and may move any vertex. A registration's g (register/domain_match.hpp) holds
/// its landmarks, and its reference areas are its own faces' before the repair, which any
/// untangling raises: there only the folds and the covering count.
struct BarrierRepairScope {
  std::vector<char> held;       // one flag per vertex: never moved (empty: none held)
  bool bound_distortion = true; // a repair must not raise the mean |log area ratio|
};

/// Repairs the folded faces of a map X of closed genus-0 `m` onto the unit sphere, one
/// cluster at a time: the vertices within 1, 2, 4, 8 or 16 rings of a folded face are
/// untangled against reference triangles of their faces' target areas (m's face areas
/// scaled to the map's). A cluster's repair is kept only if it leaves fewer folds and a mean
/// |log area ratio| (quality::area_log_ratios) no larger than the map's before the repair.
/// A repair must also leave the map covering the sphere once (quality::sphere_degree 1):
/// a region untangled inside its fixed ring can otherwise wrap around the sphere with
/// every face turned outward. The clusters' untangling stops once the free vertices of all
/// tries add up to 2 #V + 1000 (a map the repair can mend needs under 1 #V).
/// Returns the vertices moved; `folded` gets the folds left. `keep_going`, if given, is
/// called before each cluster with (round, folds left); false cancels (Error(kCancelled)).
/// `space` says where the clusters are untangled (BarrierSpace); `scope` which vertices stay
/// and whether the area distortion is bounded (BarrierRepairScope).
int repair_sphere_folds_by_barrier(const mesh::TriMesh& m, mesh::Vertices& X, int& folded,
                                   const std::function<bool(int round, int folds)>& keep_going = {},
                                   BarrierSpace space = BarrierSpace::kSphere, const BarrierRepairScope& scope = {});

/// How unfold_sphere_map goes about it.
struct SphereUnfold {
  BarrierRepairScope scope;        // held vertices (also held by the local moves) and the distortion bound
  bool keep_longest_edges = false; // conformal::untangle's: no local move lengthens a vertex's longest edge
  bool barrier = true;             // after the local moves, the barrier repair; false: local moves only
  bool only_covering_once = false; // each barrier step only while the map covers the sphere once (degree 1)
  int chart_passes = 1;            // chart passes, repeated while a pass mends something
  std::function<bool(int round, int folds)> keep_going;  // as repair_sphere_folds_by_barrier's
};

/// What unfold_sphere_map left.
struct SphereUnfolded {
  int folds = 0;      // folded faces left
  int moved = 0;      // vertices moved, summed over the local moves and the barrier's regions
  double degree = 0;  // the map's covering count (quality::sphere_degree) at the end
};

/// Unfolds a map X of closed genus-0 `m` onto the unit sphere in the order that mends the
/// most for the least: local moves (conformal::untangle: a corner mirrored across its
/// opposite edge, or a Tutte step), then for what they leave the barrier repair on the
/// sphere, then in charts, where a region cannot wrap around the sphere (diplodocus' centroid
/// map kept 4 folds on the sphere). A chart pass tries each folded face once; a fold that
/// resisted while its neighbours were folded too can give way once they are not, so up to
/// `chart_passes` passes run while each mends something. One place for the sequence the
/// area-preserving maps (each try's finish and the spreading stages) and the registration's
/// sphere domains (register/domain_match.cpp) run.
SphereUnfolded unfold_sphere_map(const mesh::TriMesh& m, mesh::Vertices& X, const SphereUnfold& how = {});

}  // namespace brenier::omt

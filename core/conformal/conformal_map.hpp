// Conformal maps of topological disks onto the unit disk and of closed genus-0 surfaces onto
// the unit sphere (dissertation sec. 3.1, Alg. 1, Thm 2.13, sec. 3.2.5).
#pragma once

#include <Eigen/Core>
#include <array>
#include <optional>
#include <string>
#include <vector>

#include "conformal/yamabe.hpp"
#include "mesh/mesh.hpp"

namespace brenier::conformal {

struct ConformalOptions {
  double tolerance = 1e-7;  // max |K - Kbar| in radians
  int max_iterations = 200;
  /// Disk: interior vertex sent to 0 and boundary vertex sent to 1 (Thm 2.13). Without
  /// them, the Moebius map that puts the pushed-forward area's centre of mass at 0, then the
  /// rotation sending the first boundary vertex to 1.
  std::optional<int> center_vertex;
  std::optional<int> boundary_vertex;
  /// Sphere: three vertices sent to 0, 1 and infinity of the stereographic plane (north
  /// pole = infinity). Without them, the area centre of mass goes to the origin.
  std::optional<std::array<int, 3>> sphere_markers;
  Progress progress;
};

struct ConformalMap {
  /// Disk: #V by 2 positions in the closed unit disk (rows of `positions` have z = 0).
  /// Sphere: #V by 3 positions on the unit sphere.
  mesh::Vertices positions;
  /// Per-vertex conformal factor lambda: the surface metric is e^{2 lambda} |dz|^2 in the
  /// domain's coordinates. Disk: from the discrete conformal factors, lambda_i = -(u_i -
  /// log R + sum log |M'(z_i)|) through the circle scaling and the Moebius maps. Sphere
  /// (metric of the unit sphere): likewise through the plane's scaling, the inverse
  /// stereographic projection and the centring maps; estimated as half the log ratio of
  /// vertex areas at the puncture and when markers are used.
  Eigen::VectorXd lambda;
  int newton_iterations = 0;
  double max_curvature_error = 0;  // max |K - Kbar| at the end
  bool converged = false;
  long flips = 0;  // intrinsic edge flips done
  std::string normalization;  // how the Moebius freedom was fixed
  /// Vertices moved by untangle() after the conformal solve (0 when every input face came
  /// out unfolded by itself), and the faces still folded after it.
  int relaxed_vertices = 0;
  int folded_faces = 0;
};

/// Whether face f of `mesh` is folded under positions X: in the plane (z = 0) when it does
/// not turn counter-clockwise, on the sphere when its chord triangle does not face outward.
bool face_folded(const mesh::TriMesh& mesh, const mesh::Vertices& X, int f, bool sphere);

/// Repairs folded faces of a planar map X (#V by 3, z = 0) of `mesh`: a Tutte embedding
/// with mean value weights of the free vertices within a few rings of the folds, the region
/// doubling until none is left (the last region is every vertex not `fixed`; with a convex
/// fixed outline Floater's theorem guarantees an embedding). Kept only if it folds fewer
/// faces. Returns the vertices whose weights were replaced; `folded` gets the folds left.
int repair_planar_folds(const mesh::TriMesh& mesh, mesh::Vertices& X, const std::vector<char>& fixed,
                        int& folded);

/// Places the vertices marked in `region` of a planar map X (#V by 3, z = 0) by a Tutte
/// embedding with the surface's own mean value coordinates (Floater 2003: positive, so with
/// a convex outline of unmarked vertices the result has no fold), the unmarked vertices
/// held where X has them; X's positions of the marked ones are not used. Returns false
/// when the linear solve failed (X unchanged then).
bool tutte_fill(const mesh::TriMesh& mesh, mesh::Vertices& X, const std::vector<char>& region);

/// Boundary curvature targets of the disk map (the turning angles of a polygon with edge
/// lengths L, in loop order, inscribed in a circle): turning[i] at vertex i between edges
/// i-1 and i, summing to 2 pi; tau[i] = tan(a_i / 2) for the central angles a_i, which give
/// the targets' derivative. Precondition: L describes a polygon (each L_i < sum of others).
void inscribed_targets(const std::vector<double>& L, std::vector<double>& turning,
                       std::vector<double>& tau);

/// Repairs input faces that the intrinsic map folds: the intrinsic triangulation the flow
/// runs on differs from the input's (Delaunay flips, boundary splits), and an input face
/// whose corner angle is nearly pi, or whose far corner lies between a boundary chord and
/// the circle, can come out inverted although the map of the intrinsic triangulation is
/// not. Each non-fixed vertex of a folded face is moved to the average of its neighbours
/// (one Tutte step; on the sphere, then back onto it), repeated until nothing is folded or
/// `max_rounds` passes. Returns the number of vertices moved; `folded` gets the count left.
/// With `keep_longest_edges`, a move that would lengthen the vertex's longest edge is
/// refused (for maps with torn faces, where a mirror move can throw a vertex far away).
int untangle(const mesh::TriMesh& mesh, mesh::Vertices& positions, bool sphere,
             const std::vector<char>& fixed, int& folded, int max_rounds = 100, bool keep_longest_edges = false);

/// Conformal map of a topological disk onto the unit disk. Boundary vertices land exactly
/// on the unit circle. Throws kInvalidArgument when the mesh is not a disk or a marker is
/// not valid; a solve that did not converge comes back with converged = false.
ConformalMap map_to_disk(const mesh::TriMesh& mesh, const ConformalOptions& options = {});

/// Conformal map of a closed genus-0 surface onto the unit sphere: the star of one vertex
/// (`puncture`, by default mesh::default_hole_vertex) is removed, the rest is mapped
/// onto the disk with its boundary on a circle, the plane is sent onto the sphere by the
/// inverse stereographic projection with the puncture at the north pole, and the result is
/// Moebius-normalized.
ConformalMap map_to_sphere(const mesh::TriMesh& mesh, const ConformalOptions& options = {},
                           std::optional<int> puncture = std::nullopt);

}  // namespace brenier::conformal

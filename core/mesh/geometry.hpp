// Areas, normalization (scale to a target area, centre at the area centroid) and opening a
// closed genus-0 surface into a disk by removing one vertex's star.
#pragma once

#include <Eigen/Core>
#include <optional>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::mesh {

/// #F face areas.
Eigen::VectorXd face_areas(const TriMesh& mesh);
/// The areas of the triangles F over positions X (e.g. a map's image of a mesh).
Eigen::VectorXd face_areas(const Faces& F, const Vertices& X);
double total_area(const TriMesh& mesh);
/// Area-weighted centroid of the surface (of its faces, not of its vertices).
Eigen::Vector3d area_centroid(const TriMesh& mesh);
/// #V vertex masses: one third of the area of every adjacent face (dissertation Alg. 3).
Eigen::VectorXd vertex_areas(const TriMesh& mesh);

struct Normalization {
  double scale = 1;            // x' = scale * (x - centre)
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
};

/// Moves the area centroid to the origin and scales so the total area is `target_area`
/// (pi for the disk, 4 pi for the sphere). Throws kInvalidArgument for a mesh of zero area.
Normalization normalize(TriMesh& mesh, double target_area);

struct CutHole {
  TriMesh mesh;                  // the opened mesh: the star of `vertex` removed
  int vertex = -1;               // the removed vertex (index in the input)
  std::vector<int> vertex_origin;  // #V of the cut mesh: its input vertex
  std::vector<int> face_origin;    // #F of the cut mesh: its input face
};

/// The vertex the default rule picks: for a near-diametral pair (a, b) found by a double
/// Dijkstra sweep along mesh edges, the vertex minimizing max(d(a, v), d(b, v)); it lies
/// close to the surface's centre, so that no protrusion is far from the hole.
int default_hole_vertex(const TriMesh& mesh);

/// Opens a closed genus-0 surface into a topological disk by deleting the vertex `v` (or the
/// default one) and its incident faces, as the dissertation does before mapping closed
/// brains and models onto the disk. Throws kInvalidArgument when v is out of range or the
/// mesh is not a closed genus-0 manifold.
CutHole cut_hole(const TriMesh& mesh, std::optional<int> v = std::nullopt);

}  // namespace brenier::mesh

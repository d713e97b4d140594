// Ground truth for surface registration: pairs made from one real mesh by a smooth non-rigid
// deformation and an independent remeshing (so no vertex of the target coincides with one of
// the source), the true place of every source vertex on the target, and the error of a
// correspondence as the geodesic distance on the target between the place found and the true
// one, over sqrt(target area) -- the measure of Kim, Lipman and Funkhouser (2011), whose
// cumulative curves (the share of points within each error) compare methods.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "mesh/mesh.hpp"
#include "register/correspondence.hpp"

namespace brenier::registration {

enum class Deformation { kNone, kBend, kTwist, kStretch };
const char* deformation_name(Deformation d);

/// A smooth deformation of the mesh along its principal axes: kBend bends the longest axis
/// onto a circular arc of `amount` x 90 degrees toward the second (isometric on the mid
/// plane), kTwist turns the cross sections about the longest axis by up to +-`amount` x 90
/// degrees at its ends, kStretch scales the longest axis by 1 + amount and the second by
/// 1 / (1 + amount).
mesh::Vertices deform(const mesh::Vertices& V, Deformation d, double amount);

/// An isotropic remeshing of the surface (CGAL's Polygon_mesh_processing::isotropic_remeshing,
/// `iterations` rounds) at `edge_scale` times its mean edge length, its vertices on the input
/// surface but, after the tangential smoothing, none where an input vertex was.
mesh::TriMesh remesh(const mesh::TriMesh& m, double edge_scale, int iterations = 3);

/// The point of `on` nearest each row of `points` (face and barycentric coordinates).
std::vector<SurfacePoint> nearest_points(const mesh::TriMesh& on, const mesh::Vertices& points);

/// Geodesic distances on `mesh` between pairs of its points (exact polyhedral geodesics,
/// CGAL's Surface_mesh_shortest_path: one shortest-path tree per pair's first point).
std::vector<double> geodesic_distances(const mesh::TriMesh& mesh, const std::vector<SurfacePoint>& from,
                                       const std::vector<SurfacePoint>& to);

/// `k` vertices spread over the mesh: farthest-point sampling by Euclidean distance, from the
/// vertex farthest from the centroid.
std::vector<int> spread_vertices(const mesh::Vertices& V, int k);

/// The share of errors <= each threshold: the cumulative error curve.
std::vector<double> cumulative_curve(const std::vector<double>& errors, const std::vector<double>& thresholds);

/// A ground-truth pair: the source (a real mesh as it is), the target (the same surface
/// remeshed, then deformed), the true place of every source vertex on the target, and
/// `landmarks` landmark pairs: spread source vertices and the target vertices nearest their
/// true places.
struct TruthPair {
  mesh::TriMesh source, target;
  std::vector<SurfacePoint> truth;  // per source vertex, on the target
  std::vector<int> source_landmarks, target_landmarks;
};
TruthPair make_truth_pair(const mesh::TriMesh& m, Deformation d, double amount, double edge_scale, int landmarks);

/// The normalized errors of a correspondence (`found`, per source vertex, on the target) at
/// up to `samples` source vertices spread evenly through the numbering: geodesic distance on
/// the target to the true place over sqrt(target area).
std::vector<double> registration_errors(const TruthPair& pair, const std::vector<SurfacePoint>& found, int samples);

/// How far two domain maps of a pair disagree: each source vertex's image (`source_domain`,
/// #V of pair.source by 3) against the image under `target_domain` of its true place, after
/// the best turn over all vertices (disk: about the centre; sphere: any rotation), i.e. the
/// part of the error no rotation g can remove. One distance per source vertex.
std::vector<double> domain_disagreement(const TruthPair& pair, const mesh::Vertices& source_domain,
                                        const mesh::Vertices& target_domain, bool sphere);

}  // namespace brenier::registration

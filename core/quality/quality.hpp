// Quality of a map of a surface mesh onto a domain (shared by every map of the project):
// flipped faces, angle distortion per corner, area distortion per face, quasi-conformal
// ratio per face, and the Beltrami coefficient between two maps of the same mesh (5.4.2).
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <complex>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::quality {

struct Stats {
  double mean = 0, p95 = 0, max = 0;
};

enum class Target { kPlane, kSphere };

struct MapQuality {
  int flipped_faces = 0;
  std::vector<int> flipped;            // their indices (at most 1000 listed)
  Stats angle_distortion_deg;          // |angle in image - angle on surface| per corner
  Stats area_distortion_log_abs;       // |log((A'/sum A') / (A/sum A))| per face
  Stats quasi_conformal;               // sigma_max / sigma_min of each face's affine map
  Eigen::VectorXd area_distortion_log; // #F signed log area ratios
  Eigen::VectorXd angle_distortion;    // #F: the largest of the face's three corners' errors, degrees
  Eigen::VectorXd qc_ratio;            // #F (infinity for flipped or degenerate faces)
  /// Sphere maps: sphere_degree of the image (1 for the plane). No flipped face does not
  /// make a bijection by itself: a map can wrap around the sphere several times with every
  /// face turned outward; it is one exactly when also the degree is 1.
  double degree = 1;
};

/// Preconditions: `image` is #V by 3 (planar maps have z = 0), same vertex order as
/// `surface`. For the plane, a face is flipped when its signed area is <= 0; for the
/// sphere, when it faces inward (normal . centroid <= 0).
MapQuality measure(const mesh::TriMesh& surface, const mesh::Vertices& image, Target target);

/// The signed log area ratios log((A'/sum A') / (A/sum A)) of every face, A' the image's
/// (chord) triangle areas: MapQuality::area_distortion_log without the rest of measure().
Eigen::VectorXd area_log_ratios(const mesh::TriMesh& surface, const mesh::Vertices& image);

/// Signed area of the geodesic triangle of the unit sphere with corners p, q, r (projected
/// onto the sphere): positive when they turn counter-clockwise seen from outside, in
/// (-2 pi, 2 pi).
double geodesic_triangle_area(const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Eigen::Vector3d& r);

/// How many times the map X (#V by 3, rows on or near the unit sphere; projected onto it)
/// of the closed triangle mesh F covers the unit sphere: the sum of the signed areas of its
/// geodesic triangles over 4 pi. An integer up to round-off for a closed surface; 1 for a
/// bijection, -1 for a mirrored one.
double sphere_degree(const mesh::Faces& F, const mesh::Vertices& X);

/// Whether a sphere_degree is 1 up to round-off: with no flipped face, the map is then a
/// bijection.
inline bool covers_once(double degree) { return std::abs(degree - 1) < 1e-6; }

/// Per-face Beltrami coefficient mu = f_zbar / f_z of the piecewise-affine map from map a's
/// triangles to map b's (both #V by 3, planar or each face in its own tangent frame).
/// |mu| < 1 on orientation-preserving faces; 0 where the two maps differ by a similarity.
Eigen::VectorXcd beltrami(const mesh::Faces& F, const mesh::Vertices& a, const mesh::Vertices& b);

/// mean, 95th percentile and max of the values.
Stats stats(std::vector<double> values);

}  // namespace brenier::quality

// What the shape distances need of one surface, computed once and cached by content hash
// (dissertation Alg. 5 steps 1-4 and Def. 2.24): its normalized conformal image of the unit
// disk with the pushed-forward area density, its vertex measure, and the optimal transport
// map from the uniform disk onto that measure sampled on a fixed quadrature.
#pragma once

#include <Eigen/Core>
#include <complex>
#include <memory>
#include <string>
#include <vector>

#include "conformal/conformal_map.hpp"
#include "mesh/mesh.hpp"
#include "omt/omt.hpp"
#include "omt/power_diagram.hpp"
#include "omt/surface_cells.hpp"

namespace brenier::distance {

/// A fixed quadrature of the unit disk: `rings` rings of equal area, `angles` points equally
/// spaced on each (ring k at radius sqrt((k + 1/2) / rings), point j at angle
/// 2 pi (j + 1/2) / angles), every point weighing pi / (rings * angles). Turning by a
/// multiple of 2 pi / angles permutes the points, which makes the minimum over those
/// rotations cheap and exact (see omt_linear).
struct Quadrature {
  int rings = 64;
  int angles = 256;
  omt::Points points() const;  // ring-major: point (k, j) is row k * angles + j
  /// On the unit sphere: `rings` bands of equal area (point (k, j) at height
  /// z_k = 1 - (2k + 1) / rings, longitude 2 pi (j + 1/2) / angles), each point weighing
  /// 4 pi / (rings * angles). With `angles` even, the half-turns about the three axes permute
  /// the points (what omt_linear uses on the sphere).
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> sphere_points() const;
};

struct ShapeOptions {
  /// The domain: false, topological disks onto the unit disk; true, closed genus-0
  /// surfaces onto the unit sphere (the OMT-map distance only, for now).
  bool sphere = false;
  /// Markers of Def. 2.24 / Thm 2.13: an interior vertex sent to 0 and a boundary vertex to
  /// 1. Without them, the Moebius map that centres the pushed-forward area, and the
  /// distances minimize over rotations.
  std::optional<int> center_vertex, boundary_vertex;
  double conformal_tolerance = 1e-7;  // max |K - Kbar|
  double omt_tolerance = 1e-8;        // the embedding's transport (max relative cell-mass error)
  /// The Wasserstein transports' tolerance (the shape's quantization cost and every pair's,
  /// which must agree for the bias to cancel). The cost is read from the Kantorovich dual,
  /// whose error is quadratic in the cell-mass error, so 1e-3 gives distances to ~1e-12
  /// (measured) for two Newton iterations less per transport than 1e-6 (which piecewise-
  /// constant densities of distorted conformal images cannot always reach: round-off floors
  /// near 5e-8 were seen).
  double transport_tolerance = 1e-3;
  /// And the transports stop once their cost is known to this relative accuracy, even with
  /// the cells still off (omt::OmtOptions::dual_gap_tolerance; 0: off): the Newton
  /// decrement, the rise of the dual to its maximum, is at most this fraction of it. The
  /// cost is then read as the dual plus that rise, accurate to third order: distances moved
  /// by at most 1.4e-9 relative against transports solved to 1e-9 (8 pairs of real and
  /// synthetic meshes), for 1-4 fewer Newton iterations per pair.
  double cost_tolerance = 1e-6;
  /// On the sphere: vertex images closer than this (chordal, on the unit sphere) become one
  /// site with their masses added. A conformal sphere map can put neighbouring vertices of
  /// a long protrusion 1e-13 apart, where no transport resolves their cells in doubles;
  /// what is transported is the measure, which this moves by at most the radius in W2.
  double merge_radius = 1e-5;
  /// On the sphere: the exact distance's source density (surface area over image area, mean
  /// 1) is held to at most this; the mass above it goes to the faces around (cap_density in
  /// shape.cpp), which moves the measure by at most Shape::density_shift in W2. 1e4: at 1e5
  /// camel x cow stopped unconverged (746 Newton iterations, 64x off); at 1e4 it converges
  /// (473) and bull x bear too (323), their bounds 0.015 and 0.018; 1e3 moves bull's by 0.083
  /// (bench/RESULTS.md, session 36).
  double density_cap = 1e4;
  Quadrature quadrature;
  /// A string of every option that changes the result (part of the cache key).
  std::string fingerprint() const;
};

struct Shape {
  std::string name;
  std::string key;  // SHA-256 of the mesh's arrays and the options' fingerprint
  int vertices = 0, faces = 0;
  bool sphere = false;           // the domain (ShapeOptions::sphere)
  int rings = 0, angles = 0;     // of the quadrature the map was sampled on
  bool markers = false;          // the normalization used the markers
  std::string normalization;     // how the Moebius freedom was fixed
  // Alg. 5 steps 1-4: the surface scaled to area pi, its conformal image of the disk,
  // vertex masses (eq. 3.30) summing to pi, and per face the pushed-forward area density
  // (surface area / image area: e^{2 lambda} of eq. 2.57, constant on each image triangle).
  omt::Points sites;
  Eigen::VectorXd mass;
  mesh::Faces tri;
  Eigen::VectorXd density;
  // Disk shapes: the source measure of every transport from this shape (Domain::
  // piecewise_constant of sites, tri and density: its hull, bucket grid and adjacency),
  // built once by prepare_shape and load_shape instead of once per pair and direction.
  std::shared_ptr<const omt::Domain> density_domain;
  // Sphere shapes: the conformal sphere map's vertices in the shape's principal frame (unit
  // vectors), `density` per face the surface area (total 4 pi) over the flat image
  // triangle's, and that density as the source measure of the exact distance (squared
  // chordal cost; omt/surface_cells.hpp), built by prepare_shape and load_shape.
  omt::Points3 sphere_sites;
  std::shared_ptr<const omt::SurfaceDensity> surface;
  /// Sphere shapes: the corners of the source's flat triangles (every vertex's image, one
  /// row per vertex). The sites are those images with the ones closer than
  /// ShapeOptions::merge_radius merged (merge_sphere_sites): then fewer rows, and `mass`,
  /// `h` and `sites` have one entry per site, not per vertex.
  omt::Points3 sphere_vertices;
  /// The vertices merged into another's site (0: none), and the farthest any vertex's mass
  /// was moved by it (chordal): the vertex measure moved by at most that in W2, and so did
  /// every transport's W2 with this shape as the sites (the triangle inequality).
  int merged_vertices = 0;
  double merge_shift = 0;
  /// Sphere: the farthest (chordal) any mass of the source density was moved by the cap of
  /// ShapeOptions::density_cap (0: nothing was over it), and the fraction of the mass moved.
  double density_shift = 0, capped_mass = 0;
  /// Sphere: the merge radius used: ShapeOptions::merge_radius, or up to 1e-3 where the
  /// transport onto the vertex measure needed more (transport_onto_vertices in shape.cpp).
  double merge_radius = 0;
  // The OMT map of Def. 2.24 from the uniform disk onto (sites, mass) (Alg. 2): heights h
  // and, at each quadrature point, the site of its cell, as complex numbers (ring by ring).
  Eigen::VectorXd h;
  Eigen::MatrixXcd samples;   // rings x angles
  Eigen::MatrixXcd spectrum;  // each ring's discrete Fourier transform over the angles
  /// Sphere: the OMT map of the uniform sphere onto the vertex measure, the conformal image
  /// put in the principal frame of its pushed-forward area (see prepare_shape), sampled on
  /// Quadrature::sphere_points (one row per point: the site's position on the sphere).
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> sphere_samples;
  /// W2^2 from the density to the shape's own vertex measure (its quantization cost, the
  /// bias the Wasserstein distance removes), by the same transport as a pair's.
  double quantization = 0;
  /// Disk: the heights of that transport (the density onto the shape's own vertices).
  Eigen::VectorXd quantization_h;
  // Of the quantization and of every pair with this shape as the sites (ShapeOptions).
  double transport_tolerance = 1e-3, cost_tolerance = 1e-6;
  int conformal_iterations = 0;
  double curvature_error = 0;
  int omt_iterations = 0;
  double omt_error = 0;
};

/// The exact distance's source density with its peaks capped (issue 23). A conformal sphere
/// map shrinks long protrusions exponentially: bull's legs carry 12 % of its area on images
/// where the density (surface area over image area) exceeds 1e4, up to 1e22. There the cell
/// masses of a transport jump with the heights by more than doubles resolve, and the pairs
/// whose sites must share such a peak did not converge (bull x bear: 708 Newton iterations,
/// still 178x off). The mass above `cap` times a face's image area is taken off each
/// connected set of faces over the cap and spread over the rings of faces around it, each
/// filled up to the cap before the next ring is touched. Every unit of mass moved goes from a
/// point of the set to a point of its rings, so the measure moves by at most the largest such
/// distance (a bound on W_infinity, hence on W2), returned with the mass moved.
struct DensityCap {
  double shift = 0;  // chordal: how far any unit of mass moved
  double moved = 0;  // the fraction of the mass moved
};
/// `mass` per face of F (corners rows of X), `image` each face's area; on return no face has
/// more mass than cap times its area, the total unchanged.
DensityCap cap_density(const mesh::Faces& F, const mesh::Vertices& X, const Eigen::VectorXd& image, double cap,
                       Eigen::VectorXd& mass);

/// The greedy merge of ShapeOptions::merge_radius: vertices in index order, each joins the
/// first earlier site within `radius` of it (a grid of cells of that size finds them) or
/// becomes a site itself. Sites are thus at least `radius` apart and every vertex within
/// `radius` of its site. site_of gets each vertex's site; returns the sites' positions.
/// Radius 0 keeps every vertex; a radius below 1e-15 (or not finite) is refused.
omt::Points3 merge_sphere_sites(const omt::Points3& X, double radius, std::vector<int>& site_of);

/// Prepares a topological disk (or, with options.sphere, a closed genus-0 surface): throws
/// Error(kInvalidArgument) for another topology or bad markers, Error(kNotConverged) naming
/// the step when the conformal map or the transport does not converge (a shape is never
/// used half-computed). On the sphere the conformal map, centred by Moebius maps, is free up
/// to a rotation; it is put in the principal frame of its pushed-forward area (the
/// eigenvectors of sum_i nu_i X_i X_i^T, largest first, right-handed), which leaves the
/// half-turns about the frame's axes, and those omt_linear tries.
Shape prepare_shape(const mesh::TriMesh& mesh, const std::string& name, const ShapeOptions& options,
                    const omt::Progress& progress = {});

/// The cache key prepare_shape would give (computable before the work).
std::string shape_key(const mesh::TriMesh& mesh, const ShapeOptions& options);

/// Cache files: a shape written whole (temporary file, then rename) and read back exactly.
/// load_shape returns false for a missing, truncated or foreign file (never throws for one).
void save_shape(const Shape& shape, const std::string& path);
bool load_shape(const std::string& path, Shape& shape);

}  // namespace brenier::distance

// Area-preserving parameterization of a topological disk onto the unit disk (dissertation
// sec. 3.2.4, Alg. 3): the conformal map, then the optimal transport from the uniform disk
// to the conformal images of the vertices weighted by their areas; each vertex goes to the
// centroid of its power cell.
#pragma once

#include <Eigen/Core>
#include <functional>

#include "conformal/conformal_map.hpp"
#include "mesh/mesh.hpp"
#include "omt/area_refinement.hpp"
#include "omt/omt.hpp"

namespace brenier::omt {

/// Chooses a sphere map's stereographic pole from its conformal map and the default pole.
using PoleChooser = std::function<Eigen::Vector3d(const mesh::Vertices& conformal, const Eigen::Vector3d& widest)>;

struct AreaPreservingOptions {
  conformal::ConformalOptions conformal;
  OmtOptions omt;
  /// The disk's transport takes the coarse-to-fine start (OmtOptions::multilevel, with its
  /// first-step trial) from this many vertices on (0: as omt says). The 99,731-vertex disk
  /// map spent 28 Newton iterations and 284 trial diagrams in the damped phase from the
  /// plain start (15 s) and 8 on the fine level from the coarse ones (7.7 s); lion-head
  /// (8.4K) and mannequin-devil (13K) were a little slower with it (bench/RESULTS.md,
  /// session 26).
  int multilevel_from = 50000;
  /// Region-of-interest multipliers of the vertex masses (sec. 6.3), one per vertex, > 0;
  /// empty: all 1. A region with weight 4 gets four times its share of the disk.
  Eigen::VectorXd weights;
  /// The polar-factorization family phi_t (sec. 3.2.8): 0 = area-preserving, 1 = conformal.
  double t = 0;
  /// The face-by-face area refinement after the centroids (area_refinement.hpp); it runs
  /// for t = 0 on a map without folds, toward the faces' areas times their corners' mean
  /// region weight.
  AreaRefineOptions refine;
  /// Called before each round of the sphere's fold repair with (round, folds left); false
  /// cancels (Error(kCancelled)), as the solvers' progress callbacks do.
  std::function<bool(int round, int folds)> repair_progress;
  /// Sphere: chooses the stereographic pole (sec. 3.2.5) from the conformal map and the
  /// default pole (the middle of the face with the widest image); called once. The map
  /// puts the pole in the middle of the face whose image holds the returned direction, so
  /// that no site lies at infinity. Empty: the default. The plane's transport commutes with
  /// turns about its pole only, so two meshings of one shape given poles at different places
  /// get maps that differ by more than a rotation; registration gives them corresponding
  /// poles through this (bench/RESULTS.md, sessions 31-32).
  PoleChooser pole;
};

struct AreaPreservingMap {
  mesh::Vertices positions;  // #V by 3: disk: z = 0, the cells' centroids; sphere: on the sphere
  conformal::ConformalMap conformal;
  OmtResult omt;
  int relaxed_vertices = 0;  // moved by the local fold repair after the centroids
  int folded_faces = 0;      // left folded after it
  /// Sphere: stages of the spreading start that ran before the transport (0: the
  /// transport started from the conformal map; see area_preserving_sphere), and their
  /// Newton iterations.
  int spreading_stages = 0;
  int spreading_newton_iterations = 0;
  /// Sphere: how many times the map covers the sphere (quality::sphere_degree). A map with
  /// no folded face is a bijection exactly when this is 1.
  double degree = 1;
  /// The face-by-face area refinement (ran = false: the seed's centroid map).
  AreaRefinement refinement;
  /// Sphere: the stereographic pole the transport used, in the conformal map's frame.
  Eigen::Vector3d pole = Eigen::Vector3d::UnitZ();
};

/// Vertex masses of eq. 3.30: one third of the adjacent face areas.
Eigen::VectorXd vertex_masses(const mesh::TriMesh& mesh);

/// The OMT map from `domain` to the sites (the images of m's vertices under a map of ours,
/// e.g. its conformal map) with masses nu (Alg. 2). Coincident sites or a transport that
/// does not converge are the map's limit, not bad input: Error(kNotConverged), saying when
/// the map puts neighbouring vertices closer than double precision resolves.
OmtResult transport_to_mesh_sites(const mesh::TriMesh& m, const Domain& domain, const Points& sites,
                                  const Eigen::VectorXd& nu, const OmtOptions& options);

/// The stereographic sites of a map X of m onto the unit sphere (sec. 3.2.5): X turned by R
/// so that the north pole lies in the middle of a face (no site at infinity), then
/// projected, y = (x1, x2) / (1 - x3). The face is the one whose image holds `toward` if
/// given (the one with the nearest middle if none does), else the one with the widest
/// image. R gets the turn; its last row is the pole.
Points stereographic_sites(const mesh::TriMesh& m, const mesh::Vertices& X, Eigen::Matrix3d& R,
                           const Eigen::Vector3d* toward = nullptr);

/// With options.t > 0, the map phi_t between the area-preserving map phi_0 and the conformal
/// map phi_1 (sec. 3.2.8): phi_t = grad u_t o phi_0 with u_t = (1 - t) |x|^2 / 2 + t u_1,
/// where grad u_1 is the OT map (the cell W_i to the site p_i = phi_1(v_i)), so vertex i goes
/// to (1 - t) c_i + t p_i (McCann's displacement interpolation: for every t the gradient of
/// a convex function, hence an optimal transport map onto its image). The dissertation's
/// Minkowski combination of the two potentials has, on the discrete upper envelopes, a
/// gradient that only takes the values p_i (it would map every vertex onto a site), so the
/// pointwise convex combination is the discrete form used here; both ends are exact.
/// Throws Error(kInvalidArgument) for a mesh that is not a disk or bad weights,
/// Error(kNotConverged) when the conformal map or the transport does not converge.
AreaPreservingMap area_preserving_disk(const mesh::TriMesh& mesh, const AreaPreservingOptions& options = {});

/// Area-preserving map of a closed genus-0 surface onto the unit sphere (sec. 3.2.5): the
/// conformal sphere map, turned so that the north pole lies in the middle of its largest
/// face (no site at infinity), then the stereographic projection gives the sites, and the
/// transport from the sphere's own measure on the stereographic plane
/// (Domain::stereographic_sphere) to them weighted by the vertex masses; each vertex goes
/// to the centroid of its cell on the sphere. We chose this over power diagrams on the
/// sphere through a 3-D convex hull: it is the dissertation's construction, it reuses the
/// planar solver whole (exact cell masses and Hessian in closed form), and the conformal
/// map already lives in that plane. With t > 0, vertex i goes to the normalized
/// (1 - t) c_i + t p_i, c_i its cell's centroid and p_i its conformal image. Folds left by
/// neighbouring centroids (coarse or CAD-like meshes) are untangled on the sphere, first by
/// local steps, then by the barrier repair of fold_repair.hpp on the sphere and in planar
/// charts, kept only where it leaves the area distortion no larger. Where the conformal map
/// is crowded below double precision, or its own map keeps folds, the transport starts
/// from a spread map instead (three tries; see the .cpp); the first bijective map is returned,
/// else the nearest one, with its folds and degree reported. Errors as area_preserving_disk.
AreaPreservingMap area_preserving_sphere(const mesh::TriMesh& mesh, const AreaPreservingOptions& options = {});

}  // namespace brenier::omt

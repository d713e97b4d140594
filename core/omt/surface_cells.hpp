// Laguerre cells of the squared Euclidean cost in R^3 on a triangulated surface: the first
// building block of the exact Wasserstein distance on the sphere (issue 5; dissertation
// Alg. 5 with the squared chordal cost, eq. 3.31). The source measure is a constant density
// on each flat triangle of a surface (a shape's sphere image: the polyhedron inscribed in
// the sphere, as the disk distance uses the flat triangles of the conformal image); the
// sites y_i are points of R^3 (the other shape's vertex images on the sphere).
//
// W_i = {x on the surface : <x, y_i> + h_i >= <x, y_j> + h_j for all j}, the restriction of
// the 3-D power diagram of the weighted points (y_i, |y_i|^2 + 2 h_i): the cells of
// c(x, y) = |x - y|^2 with dual weights |y_i|^2 + 2 h_i. Every piece W_i ∩ T of a flat
// triangle T is a convex polygon of T's plane, integrated exactly.
//
// Used by the exact Wasserstein distance on the sphere (distance/distance.hpp,
// transport_cost_sphere).
#pragma once

#include <Eigen/Core>
#include <span>
#include <vector>

#include "omt/omt.hpp"
#include "omt/power_diagram.hpp"

namespace brenier::omt {

using Points3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// A constant density on each flat triangle of a surface in R^3.
struct SurfaceDensity {
  Points3 vertices;
  Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor> faces;
  Eigen::VectorXd density;  // per face, >= 0
  /// Throws Error(kInvalidArgument) for indices out of range, non-finite vertices,
  /// negative or non-finite densities, or a degenerate (zero-area) triangle.
  void check() const;
  double mass() const;  // sum of density times area
};

struct SurfaceCells {
  Eigen::VectorXd mass;           // ∫_{W_i} rho dA
  Points3 first;                  // ∫_{W_i} x rho dA (the centroid times the mass)
  Eigen::VectorXd second_moment;  // ∫_{W_i} |x - y_i|^2 rho dA: the transport cost
  /// One per pair of cells sharing a side of positive length on some triangle: `length` is
  /// -dm_i/dh_j = sum over the triangles T of rho_T |side ∩ T| / |P_T (y_i - y_j)| (P_T the
  /// projection onto T's plane: how fast the side sweeps T as h_j moves), the Hessian's
  /// off-diagonal weight of the transport energy.
  std::vector<DualEdge> edges;
  int empty_cells = 0;
  /// Per triangle, the cell of its first piece (-1: none), the hint of the next evaluation
  /// at nearby heights.
  std::vector<int> owner;
};

/// The cells of `sites` at heights h on the surface. Pieces are found per triangle by a flood
/// fill over the cells from the owner of the triangle's centroid, each piece cut by its
/// cell's neighbours in CGAL's 3-D regular triangulation; triangles run in parallel and the
/// sums are taken in triangle order, so the result does not depend on the thread count.
/// `hint` (empty, or one per triangle: an earlier evaluation's SurfaceCells::owner) starts each
/// triangle's search for its centroid's cell near it, a few steps of the walk instead of tens
/// where the sites crowd; where the hints bound the scores on the surface, a centre point at
/// the origin also goes into the triangulation (see Diagram3). Any hints give the same cells
/// to round-off (the cuts can come in a different set, so not always to the bit).
/// Throws Error(kInvalidArgument) for sizes that do not match or non-finite input.
SurfaceCells surface_power_cells(const SurfaceDensity& surface, const Points3& sites, const Eigen::VectorXd& h,
                                 std::span<const int> hint = {});

struct SurfaceOmtResult {
  Eigen::VectorXd h;       // heights, mean zero (unique up to a constant where the cells touch)
  SurfaceCells cells;      // at h
  Eigen::VectorXd target;  // nu, scaled to the surface's mass
  int iterations = 0;
  double max_relative_error = 0;  // max_i |m_i - nu_i| / nu_i at h
  bool converged = false;
  /// The Kantorovich dual at h: sum_i ∫_{W_i} |x - y_i|^2 dmu - sum_i w_i (m_i - nu_i), w_i =
  /// |y_i|^2 + 2 h_i; W2^2 at the solution, a lower bound of it anywhere.
  double dual_value = 0;
  /// When the solve stopped by OmtOptions::dual_gap_tolerance: the Newton step's predicted
  /// rise of the dual to its maximum (dual_value + dual_rise estimates W2^2 to third order).
  double dual_rise = 0;
  bool abandoned = false;  // stopped by OmtOptions::abandon (converged is then false)
  bool stalled = false;    // stopped by OmtOptions::stall_window (converged is then false)
  int levels = 1;          // OmtOptions::multilevel: the levels the start came from, this one included
  int coarse_iterations = 0;  // of `iterations`, those spent on the coarse levels
};

/// Semi-discrete transport from the surface's density to the sites with masses nu (scaled to
/// the surface's mass), squared Euclidean cost: Newton's method on the convex energy of
/// Alg. 2 with Kitagawa-Merigot-Thibert damping (every cell keeps half the smaller of its
/// target and the start's smallest cell), one set of surface cells per trial step, each
/// Newton system factored afresh (CHOLMOD). options.tolerance: max relative cell-mass
/// error, or options.dual_gap_tolerance as in solve_omt; options.initial_h: the start
/// (default 0: for sites on the unit sphere, the spherical Voronoi diagram);
/// options.multilevel: as in solve_omt, where the start is 10x off and there are at least
/// 1,000 sites (without the first-step trial).
SurfaceOmtResult solve_surface_omt(const SurfaceDensity& surface, const Points3& sites, const Eigen::VectorXd& nu,
                                   const OmtOptions& options = {});

}  // namespace brenier::omt

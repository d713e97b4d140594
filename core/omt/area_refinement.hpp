// Face-by-face area refinement of an area-preserving map (issue 26). The seed's Alg. 3 puts
// each vertex at the centroid of its power cell: every cell has exactly its mass, but the
// triangles spanned by the centroids do not have their faces' areas (lion-head: mean
// |log area ratio| 0.27). The refinement starts from that bijective map and minimizes, over
// the free vertices, the barrier energy of fold_repair.hpp (Garanzha et al. 2021) with eps = 0,
//     sum_f A_f [theta (D_f + 1 / D_f) + (1 - theta) |J_f|_F^2 / D_f],
// J_f the face's Jacobian against its surface triangle scaled to the target area A_f and
// D_f = det J_f its area ratio. On the sphere D_f is measured first by volume,
// det(a, b, c) / 2 A_f (a barrier against turning, from any start), then, where the
// tolerances are not met, by the chord area |(b - a) x (c - a)| / 2 A_f, the measure the
// result is judged by, with a small barrier 1e-3 A_f / h_f on each face's plane distance h_f
// from the centre, the one thing that keeps a chord face from turning over (area_refinement.cpp
// says why both measures, and why the barrier). The first term is least at
// D_f = 1, the face's own area; the second, the MIPS energy, is scale-free and keeps the
// shapes, which makes the minimizer unique and keeps the triangles from turning into slivers;
// theta rises stage by stage and lets the area term win: 0.999, then 0.9999; on the sphere,
// from a start far from its areas (mean |log area ratio| above 0.25: spread starts, coarse
// polyhedra), 0.98, 0.995, 0.999, 0.9999, 0.99999, a continuation whose stiffer first stages
// move the arms as a whole (area_refinement.cpp). The minimization is a projected Newton
// method (each face's Hessian with its negative eigenvalues clamped, CHOLMOD for the system),
// the step cut before any face degenerates (in closed form on the plane and on the sphere) and
// by Armijo's rule; the energy is infinite on a degenerate face, so from a map with no flipped
// face no face flips, and on the sphere a step is also kept only if the map still covers the
// sphere once.
// The disk's boundary vertices slide along the circle (a face with three corners there could
// not change its area if they were held). Stops when the stated tolerances hold (mean and
// 95th percentile of |log area ratio|) or after the step budget, saying which; on the sphere
// a volume stage also ends after three steps in a row that do not lower the mean |log area
// ratio|, a chord stage after three that gain less than 1 %, each returning its best map. A
// result worse than its start is not kept.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <memory>
#include <vector>

#include "mesh/mesh.hpp"
#include "quality/quality.hpp"

namespace brenier::omt {

struct AreaRefineOptions {
  /// false: the seed's centroid map as it is (--no-refine).
  bool enabled = true;
  /// Stop once mean |log area ratio| <= mean_tolerance and its 95th percentile <= p95_tolerance
  /// (both maps scaled to equal total area, as quality::area_log_ratios).
  double mean_tolerance = 0.01;
  double p95_tolerance = 0.05;
  /// The disk's boundary vertices slide along the circle (false: held where they are).
  bool slide_boundary = true;
  /// Newton steps over all stages of one run. On the sphere the volume run has this budget, and
  /// so has each chord run after it (from its result and, if still short, from the start). The
  /// reweighted rounds' steps (at most 50 a round) come on top and are counted in
  /// AreaRefinement::iterations.
  int max_iterations = 100;
  /// Meshes of at most 1,000 faces whose stages end short of the tolerances (on the sphere, the
  /// chord stages): rounds of reweighted Newton steps toward the measure itself, the mean of
  /// |log area ratio| over the faces (area_refinement.cpp); a round's map is kept only where it
  /// is better. 0: none.
  int reweighted_rounds = 15;
  /// Called after every Newton step with the run's steps so far (the sphere's volume and chord
  /// runs count from 0 each) and the mean |log area ratio| at the step's map (in a reweighted
  /// round: the best kept so far); returning false cancels the refinement (Error(kCancelled)).
  /// The refinement of a 100K-vertex map takes seconds: a job's cancellation must reach it.
  std::function<bool(int step, double mean)> keep_going;
};

struct AreaRefinement {
  bool ran = false;        // false: disabled, phi_t with t > 0, or a start with folds
  bool converged = false;  // both tolerances met
  bool kept_start = false;  // the minimum came out worse than the start, which was kept
  int iterations = 0;      // Newton steps in all
  int stages = 0;          // theta stages run
  quality::Stats before, after;  // |log(area / target area)| per face, totals equal
  double mean_tolerance = 0, p95_tolerance = 0;  // the stop it was given
  double seconds = 0;
};

/// |log((a_f / sum a) / (target_f / sum target))| per face, a the chord triangle areas of X.
Eigen::VectorXd abs_log_area_ratios(const mesh::Faces& F, const mesh::Vertices& X, const Eigen::VectorXd& target);

/// The refinement's linear algebra, which depends only on the mesh's faces and on which
/// vertices move: the unknowns, the Hessian's sparsity pattern and CHOLMOD's fill-reducing
/// analysis of it (nested dissection: 1.0 s of the 100K-vertex disk map's 4.5 s refinement,
/// bench/RESULTS.md, session 49). Made ahead of the map it refines, it can be computed on a
/// second core while the conformal map and the transport, serial for the most part, run on
/// the first (omt::area_preserving_disk and _sphere do so). One plan serves any number of
/// refinements of the same mesh, one at a time (the sphere's volume and chord stages).
struct RefinementPlan;

/// The plan for refine_disk_areas(m, ..., fixed, options, plan).
std::shared_ptr<RefinementPlan> plan_disk_refinement(const mesh::TriMesh& m, const std::vector<char>& fixed,
                                                     const AreaRefineOptions& options);
/// The plan for refine_sphere_areas(m, ...).
std::shared_ptr<RefinementPlan> plan_sphere_refinement(const mesh::TriMesh& m);

/// Refines a planar map X (#V by 3, z = 0, no flipped face) of m toward the face areas
/// `target` (any scale: only their ratios count, their common scale is refitted to the map
/// before every step); the rows with fixed[v] != 0 (the disk's boundary, on the unit circle)
/// slide along the circle, or are held without options.slide_boundary. X keeps no flipped
/// face, so the boundary keeps its cyclic order. `plan`, from plan_disk_refinement with the
/// same m, fixed and options (checked), saves its analysis; without one it is made here.
/// The result's seconds count the refinement, not the plan made ahead.
AreaRefinement refine_disk_areas(const mesh::TriMesh& m, const Eigen::VectorXd& target, mesh::Vertices& X,
                                 const std::vector<char>& fixed, const AreaRefineOptions& options,
                                 std::shared_ptr<RefinementPlan> plan = nullptr);

/// Refines a map X of closed genus-0 m onto the unit sphere (no flipped face, covering the
/// sphere once) toward the face areas `target`; every vertex moves, on the sphere. X stays a
/// bijection. `plan`: from plan_sphere_refinement(m), or made here.
AreaRefinement refine_sphere_areas(const mesh::TriMesh& m, const Eigen::VectorXd& target, mesh::Vertices& X,
                                   const AreaRefineOptions& options, std::shared_ptr<RefinementPlan> plan = nullptr);

}  // namespace brenier::omt

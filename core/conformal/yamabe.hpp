// Discrete surface Yamabe flow by Newton's method (dissertation Alg. 1, eq. 3.1-3.4) on an
// intrinsic triangulation kept Delaunay by flips (Def. 3.5, the "surgery").
#pragma once

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <functional>
#include <memory>
#include <vector>

#include "conformal/intrinsic.hpp"

namespace brenier::conformal {

/// Called after every Newton iteration with (iteration, max |K - Kbar|); returning false
/// cancels the solve (it then throws Error(kCancelled)).
using Progress = std::function<bool(int iteration, double residual)>;

/// Target curvature Kbar(u) for the current factors u, with its derivative when it depends
/// on u (the disk's boundary targets follow the boundary lengths): dKbar/du = M - c w w^T
/// for a sparse symmetric M (as triplets) and a rank-one term. Must satisfy Gauss-Bonnet.
struct Target {
  Eigen::VectorXd K;
  std::vector<Eigen::Triplet<double>> M;
  Eigen::VectorXd w;
  double c = 0;
};
using TargetCurvature =
    std::function<Target(const IntrinsicTriangulation&, const Eigen::VectorXd& u)>;

/// A Cholesky factor of the Newton system kept between solves (opaque): passing the same one
/// to the solves of one map lets a solve restarted after boundary splits precondition with
/// the previous factor instead of factoring afresh.
struct KeptFactor;
std::shared_ptr<KeptFactor> make_kept_factor();

struct YamabeOptions {
  double tolerance = 1e-7;  // stop when max_i |K_i - Kbar_i| <= tolerance (radians)
  int max_iterations = 200;
  Progress progress;
  /// Return (blocked = true) as soon as a boundary triangle throttles the steps, so that
  /// the caller can refine the boundary; otherwise crawl on.
  bool stop_when_blocked = true;
  std::shared_ptr<KeptFactor> kept_factor;  // null: each solve keeps its own
};

struct YamabeResult {
  Eigen::VectorXd u;  // #V conformal factors: lengths scale by exp((u_i + u_j) / 2)
  int iterations = 0;
  double residual = 0;  // max |K - Kbar| at u
  bool converged = false;
  bool blocked = false;  // stopped by a boundary triangle that would become degenerate
  long flips = 0;
};

/// Discrete Gaussian curvature (Def. 3.2): 2 pi - angle sum inside, pi - angle sum on the
/// boundary. Precondition: every triangle of T satisfies the triangle inequality at u.
Eigen::VectorXd curvature(const IntrinsicTriangulation& T, const Eigen::VectorXd& u);

/// dK/du (eq. 3.3-3.4): the cotangent Laplacian of the current triangulation, H_ij =
/// -(cot a_ij + cot b_ij)/2 for an edge ij, H_ii = -sum_j H_ij (boundary edges: one cot).
/// Symmetric positive semi-definite with the constants as null space.
Eigen::SparseMatrix<double> curvature_jacobian(const IntrinsicTriangulation& T,
                                               const Eigen::VectorXd& u);

/// Newton's method for K(u) = Kbar(u) starting from u0 (#V), flipping T to Delaunay at every
/// step: (H - dKbar/du) du = Kbar - K on the free vertices, with the `fixed` vertices (#V
/// mask; at least one, since the constants are H's null space) keeping their u0 (Dirichlet).
/// Each system is solved by GMRES preconditioned with a sparse Cholesky factor of H (CHOLMOD
/// supernodal), kept across iterations while it serves; J itself (LDL^T, rank-one part by
/// Sherman-Morrison) only if GMRES fails. Steps are halved until |Kbar - K| decreases and
/// every triangle is valid.
YamabeResult solve_yamabe(IntrinsicTriangulation& T, const TargetCurvature& target,
                          const Eigen::VectorXd& u0, const std::vector<char>& fixed,
                          const YamabeOptions& options);

}  // namespace brenier::conformal

// The Newton direction of a semi-discrete transport whose mass Jacobian is the weighted graph
// Laplacian of its cells' common sides (eq. 3.28; on a surface, with the chordal or the
// geodesic cost): shared by the transport on a surface (surface_cells.cpp) and Riemannian OMT
// (geodesic_omt.cpp). Internal to the engine.
#pragma once

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCore>
#include <optional>
#include <vector>

#include "omt/power_diagram.hpp"

namespace brenier::omt::detail {

using NewtonFactor = Eigen::CholmodDecomposition<Eigen::SparseMatrix<double>>;

/// dh solving H dh = -g, H = dm/dh (dm_i/dh_j = -w_ij for a side of weight w_ij, dm_i/dh_i =
/// sum_j w_ij), with h[held] fixed (the energy is invariant under h + constant), factored by
/// `llt` (its mode set by the caller); nothing when H is singular (a cell without sides).
inline std::optional<Eigen::VectorXd> newton_direction(const std::vector<DualEdge>& sides, const Eigen::VectorXd& g,
                                                       Eigen::Index held, NewtonFactor& llt) {
  const Eigen::Index k = g.size();
  auto slot = [held](Eigen::Index i) { return i < held ? i : i - 1; };
  std::vector<Eigen::Triplet<double>> entries;
  Eigen::VectorXd diag = Eigen::VectorXd::Zero(k);
  for (const DualEdge& e : sides) {
    diag[e.i] += e.length;
    diag[e.j] += e.length;
    if (e.i == held || e.j == held) continue;
    entries.emplace_back(slot(e.i), slot(e.j), -e.length);
    entries.emplace_back(slot(e.j), slot(e.i), -e.length);
  }
  for (Eigen::Index i = 0; i < k; ++i)
    if (i != held) entries.emplace_back(slot(i), slot(i), diag[i]);
  Eigen::SparseMatrix<double> H(k - 1, k - 1);
  H.setFromTriplets(entries.begin(), entries.end());
  llt.compute(H);
  if (llt.info() != Eigen::Success) return std::nullopt;
  Eigen::VectorXd rhs(k - 1);
  for (Eigen::Index i = 0; i < k; ++i)
    if (i != held) rhs[slot(i)] = -g[i];
  const Eigen::VectorXd d = llt.solve(rhs);
  Eigen::VectorXd dh = Eigen::VectorXd::Zero(k);
  for (Eigen::Index i = 0; i < k; ++i)
    if (i != held) dh[i] = d[slot(i)];
  return dh;
}

}  // namespace brenier::omt::detail

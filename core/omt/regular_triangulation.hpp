// The regular triangulation of weighted sites (CGAL's Regular_triangulation_2), whose
// adjacency is the power diagram's (dissertation sec. 3.2.2): built anew, or updated by
// Lawson's flips when only the weights moved, with a filtered power test. Internal to
// core/omt (power_diagram.cpp).
#pragma once

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Regular_triangulation_2.h>
#include <CGAL/Regular_triangulation_face_base_2.h>
#include <CGAL/Regular_triangulation_vertex_base_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>

#include <cmath>
#include <vector>

#include "omt/power_diagram.hpp"

namespace brenier::omt::regular {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using WP = K::Weighted_point_2;

// The regular triangulation's in-circle test -- the sign of the 3x3 determinant of the
// rows (x - t_x, y - t_y, |(x, y) - t|^2 - w + w_t) for p, q, r against t -- decided in
// plain doubles when the result clears a forward error bound, and by CGAL's exact
// predicate (interval filter, then exact arithmetic) otherwise: a semi-static filter.
// CGAL's Epick has static filters for the Delaunay in-circle test but none for this one,
// and its interval filter (rounding-mode switches) was a sixth of a whole OT solve.
// The bound: each entry is off by at most 5 units of round-off u relative to the sum of
// the absolute values it is made of (Z = dx^2 + dy^2 + |w| + |w_t| for the last column),
// each of the six products of the expansion adds 3 u, and their sum 5 u; 64 u against the
// permanent of those magnitudes leaves a wide margin. Magnitudes out of [1e-120, 1e120]
// (where the bound itself could underflow or overflow) go to the exact predicate.
struct PowerTest : K::Power_side_of_oriented_power_circle_2 {
  using Exact = K::Power_side_of_oriented_power_circle_2;
  using Exact::operator();
  CGAL::Oriented_side operator()(const WP& p, const WP& q, const WP& r, const WP& t) const {
    const double tx = t.x(), ty = t.y(), tw = t.weight();
    const double px = p.x() - tx, py = p.y() - ty, qx = q.x() - tx, qy = q.y() - ty, rx = r.x() - tx,
                 ry = r.y() - ty;
    const double pz = (px * px + py * py) + (tw - p.weight());
    const double qz = (qx * qx + qy * qy) + (tw - q.weight());
    const double rz = (rx * rx + ry * ry) + (tw - r.weight());
    const double det = px * (qy * rz - ry * qz) - py * (qx * rz - rx * qz) + pz * (qx * ry - rx * qy);
    const double Zp = px * px + py * py + std::abs(tw) + std::abs(p.weight());
    const double Zq = qx * qx + qy * qy + std::abs(tw) + std::abs(q.weight());
    const double Zr = rx * rx + ry * ry + std::abs(tw) + std::abs(r.weight());
    const double ax = std::abs(px), ay = std::abs(py), bx = std::abs(qx), by = std::abs(qy), cx = std::abs(rx),
                 cy = std::abs(ry);
    const double perm = ax * (by * Zr + cy * Zq) + ay * (bx * Zr + cx * Zq) + Zp * (bx * cy + cx * by);
    constexpr double kBound = 64 * 0x1p-53;
    if (perm > 1e-120 && perm < 1e120) {
      if (det > kBound * perm) return CGAL::ON_POSITIVE_SIDE;
      if (det < -kBound * perm) return CGAL::ON_NEGATIVE_SIDE;
    }
    return Exact::operator()(p, q, r, t);
  }
};
struct Traits : K {
  using Power_side_of_oriented_power_circle_2 = PowerTest;
  PowerTest power_side_of_oriented_power_circle_2_object() const { return {}; }
};

using Vbb = CGAL::Regular_triangulation_vertex_base_2<Traits>;
using Vb = CGAL::Triangulation_vertex_base_with_info_2<int, Traits, Vbb>;
using Fb = CGAL::Regular_triangulation_face_base_2<Traits>;
using Tds = CGAL::Triangulation_data_structure_2<Vb, Fb>;
using RT = CGAL::Regular_triangulation_2<Traits, Tds>;


// Regular triangulation of the weighted points (y_i, 2 psi_i), psi the offsets of
// PowerDiagrams (power weight |y_i|^2 + 2 h_i = 2 psi_i, exact), inserted in `order`:
// its adjacency is the power diagram's; hidden points have empty cells. A hidden point
// stays hidden as more are inserted (the lifted lower hull only descends), so with
// `fail_if_hidden` it stops, returning false, at the first one found.
bool triangulate(const Points& sites, const Eigen::VectorXd& psi, const std::vector<int>& order, bool fail_if_hidden,
                 RT& rt);

// Lawson's flips for regular triangulations: from a regular triangulation of all the sites
// for the previous heights, with the sites' weights set to the new ones, flip every edge
// whose opposite vertex is strictly inside the power circle of its face (the edge is not
// locally regular) while the quadrilateral is strictly convex. A triangulation of every
// site that is locally regular at every edge is the regular triangulation (Edelsbrunner
// and Shah 1996): the lifted points then form a locally convex, hence convex, surface, and
// no site is hidden. Sites do not move, so the convex hull and the edges on it stay. When
// edges remain that cannot be flipped -- a site that has to be hidden, or a flip sequence
// that is stuck -- every flip is undone and the weights restored, and the caller builds
// the triangulation anew. A Newton step moves few edges, so the flips cost a fraction of
// a new triangulation (mostly CGAL's insertions; figures in bench/RESULTS.md).
enum class Reweighted { kRegular, kHidden, kStuck };
// `faces` caches rt's finite faces between calls: a flip of an edge between two finite faces
// reuses both, so the set stays; pass it empty for a new triangulation.
Reweighted reweight_by_flips(RT& rt, std::vector<RT::Face_handle>& faces, const Points& sites,
                             const Eigen::VectorXd& old_psi, const Eigen::VectorXd& psi,
                             bool stop_if_hidden);

}  // namespace brenier::omt::regular

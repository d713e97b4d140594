// Power diagrams of weighted sites clipped exactly by a convex domain (dissertation sec.
// 3.2.2-3.2.3, 6.2.2): the cells, their masses, centroids and second moments, and the
// clipped dual edges the Newton Hessian of the OMT energy is made of (eq. 3.27-3.28).
#pragma once

#include <Eigen/Core>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

namespace brenier::omt {

using Points = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;

/// The source domain Omega with the uniform density: a disk of radius R centred at the
/// origin (cells clipped with exact circular arcs) or a convex polygon.
/// Triangles of a piecewise-constant source density (the conformal image of a mesh, say),
/// with a bucket grid to find those a cell overlaps.
struct DensityMesh {
  Points vertices;
  Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor> faces;
  Eigen::VectorXd density;  // per face, >= 0
  // Grid over the triangles' bounding box: bucket b holds the faces overlapping it.
  double x0 = 0, y0 = 0, cell = 1;
  int nx = 1, ny = 1;
  std::vector<int> bucket_start, bucket_faces;
  // neighbour(f, k): the triangle across edge (faces(f, k), faces(f, k + 1)), -1 on the hull.
  Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor> neighbour;
};

struct Domain {
  bool is_disk = true;
  double radius = 1.0;
  Points polygon;  // counter-clockwise corners when !is_disk
  std::shared_ptr<const DensityMesh> density;  // null: uniform density 1
  bool is_sphere = false;  // the stereographic plane with the sphere's measure

  static Domain unit_disk();
  /// The unit sphere's area measure on its stereographic plane (dissertation sec. 3.2.5):
  /// density 4 / (1 + |x|^2)^2 over the whole plane (total 4 pi), the north pole at
  /// infinity. Sites are stereographic images y = (X1, X2) / (1 - X3); cells on the convex
  /// hull of the sites are unbounded (cut at |x| = 1e9, which leaves out 1e-17 of the
  /// sphere). Masses and dual-edge masses are exact; each cell also gets its centroid on
  /// the sphere (from the boundary formula  int_W X dA = 1/2 oint X x dX  along the image
  /// circles of its edges) and its second moment in the chordal distance.
  static Domain stereographic_sphere();
  /// Throws Error(kInvalidArgument) unless the corners form a convex counter-clockwise
  /// polygon of positive area.
  static Domain convex_polygon(const Points& corners);
  static Domain square(double half_side = 1.0);
  /// The density `density[f]` on each triangle of (vertices, faces), zero elsewhere; the
  /// cells are clipped by the convex hull of the vertices, so the triangles should cover a
  /// convex region (as the conformal image of a disk mesh does: its boundary is inscribed in
  /// the circle). Integrals over cell ∩ triangle are exact. Throws on bad input.
  static Domain piecewise_constant(const Points& vertices,
                                   const Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>& faces,
                                   const Eigen::VectorXd& density);
  /// Total mass of the source measure (the area for the uniform density).
  double area() const;
  bool contains(double x, double y, double slack = 0) const;
};

/// One clipped dual edge: the common boundary of cells i < j inside the domain.
struct DualEdge {
  int i, j;
  double length;  // of W_i ∩ W_j ∩ Omega
};

struct PowerCells {
  Eigen::VectorXd mass;        // of W_i ∩ Omega under the domain's measure
  Points centroid;             // of W_i ∩ Omega (the site itself when the cell is empty)
  Eigen::VectorXd second_moment;  // ∫_{W_i ∩ Omega} |x - y_i|^2 dx: the transport cost
  /// Sphere domain only: unit vector of ∫_{W_i} X dA on the sphere (the cell's centroid
  /// direction; `centroid` is its stereographic image), and second_moment is then
  /// ∫_{W_i} |X - Y_i|^2 dA with Y_i the site on the sphere (squared chordal distance).
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> sphere_centroid;
  std::vector<DualEdge> edges;
  int empty_cells = 0;         // hidden sites and cells that miss the domain
};

/// The power diagram of sites y_i with heights h_i in the convention of sec. 6.2.2:
/// u_h(x) = max_i <x, y_i> + h_i, W_i = {x : <x, y_i> + h_i is the max}, i.e. the power
/// diagram of the weighted points (y_i, |y_i|^2 + 2 h_i). Built on CGAL's
/// Regular_triangulation_2 (exact predicates); each cell is the intersection of the
/// half-planes of its regular-triangulation neighbours with the domain, integrated
/// exactly (circular sectors for the disk). Cells are computed in parallel.
/// Throws Error(kInvalidArgument) for coincident sites (unless check_distinct is false: the
/// caller has checked them) or non-finite input.
PowerCells power_cells(const Domain& domain, const Points& sites, const Eigen::VectorXd& h,
                       bool check_distinct = true);

/// Adjacency lists (CSR: the neighbours of i are nbr[start[i] .. start[i + 1]), ascending)
/// of n items from a list of adjacent pairs, each pair listed once.
void neighbour_lists(int n, const std::vector<std::pair<int, int>>& pairs, std::vector<int>& start,
                     std::vector<int>& nbr);

/// Power diagrams of one fixed set of sites for many heights, as the Newton iterations of
/// the OMT solver need: the sites are checked once (finite, distinct unless
/// `check_distinct` is false) and their spatial order for the insertions is kept.
class PowerDiagrams {
 public:
  PowerDiagrams(Domain domain, Points sites, bool check_distinct = true);
  ~PowerDiagrams();
  /// The diagram at heights h (as power_cells).
  PowerCells operator()(const Eigen::VectorXd& h) const;
  /// The diagram at the offsets psi_i = h_i + |y_i|^2 / 2 (half the power weight; psi = 0 is
  /// the Voronoi diagram). Heights of sites far from the origin carry the round-off of
  /// |y_i|^2, which places the bisector of two sites d apart only to eps |y|^2 / d; the
  /// offsets are what the regular triangulation's weights are made of (exactly) and keep
  /// their own precision, so the OMT solver iterates on them.
  /// An optional low part `lo` makes the offsets psi + lo (double-double, as the solver
  /// accumulates its Newton steps): the bisectors then use psi_i - psi_j + lo_i - lo_j, the
  /// first difference exact for the close sites where it matters (Sterbenz), while the
  /// triangulation's weights are 2 psi (a neighbour missed by that rounding has an edge of
  /// length ~eps |psi| / d, so it changes the cells only to second order).
  PowerCells at_offsets(const Eigen::VectorXd& psi, const Eigen::VectorXd& lo = {}) const;
  /// The same, or nothing as soon as one site is found hidden (its cell empty): a rejected
  /// trial step then costs a fraction of a diagram.
  std::optional<PowerCells> at_offsets_if_none_hidden(const Eigen::VectorXd& psi,
                                                      const Eigen::VectorXd& lo = {}) const;
  /// The offsets of heights h.
  Eigen::VectorXd offsets(const Eigen::VectorXd& h) const;
  /// For each query point x, the site whose cell at heights h holds it (argmax_i <x, y_i> +
  /// h_i, exact predicates; a tie goes to the least site index); the plane's cells, unclipped by
  /// the domain. The queries may come in any order.
  std::vector<int> locate(const Eigen::VectorXd& h, const Points& queries) const;
  /// For each query point x, the smoothed maximum  eps log sum_i exp((<x, y_i> + h_i - M) /
  /// eps) + M,  M = max_i <x, y_i> + h_i, summed over the terms within kSmoothedMaxCut eps of
  /// M (20: each one left out adds under 2.1e-9 of the sum, so N sites move the result by
  /// under eps N 2.1e-9). Those sites' lifted points lie below a plane, so
  /// they form a connected set of the regular triangulation's vertices (the convex lower
  /// hull minus a linear function is convex and linear on each triangle, so every edge that
  /// crosses the segment between two of them has an endpoint among them): a walk to the
  /// maximum and a search through neighbours from it find them all, in time proportional to
  /// their number instead of to the number of sites. Sites hidden at heights h (above the
  /// lower hull) are left out.
  Eigen::VectorXd smoothed_max(const Eigen::VectorXd& h, const Points& queries, double eps) const;
  /// smoothed_max's cut, in units of eps. Its one caller places a transport's coarse-to-fine
  /// start (coarse_to_fine.hpp), whose own error is of order one: with the cut at 40 (4e-18
  /// of the sum a term) the sums took 197 ms of the 100K-vertex disk map's 2.1 s transport,
  /// at 20 they take 122 ms, with the same Newton iterations and distances (bench/RESULTS.md,
  /// session 76).
  static constexpr double kSmoothedMaxCut = 20;

 private:
  struct Triangulation;
  std::optional<PowerCells> build(const Eigen::VectorXd& psi, const Eigen::VectorXd& lo, bool fail_if_hidden) const;
  const Triangulation* regular(const Eigen::VectorXd& psi, bool fail_if_hidden, Triangulation& fresh) const;
  Domain domain_;
  Points sites_;
  std::vector<int> order_;  // Hilbert order of the sites
  // Piecewise-constant densities: per site, a triangle its cell overlapped in the last
  // diagram, where the next diagram's search for the cell's triangles starts. Each entry is
  // only touched by the thread integrating that cell, and depends only on that cell's
  // history, so diagrams stay identical for any number of threads.
  mutable std::vector<int> start_triangle_;
  // The last regular triangulation that held every site, kept so that the next heights
  // (a Newton step away) are reached by edge flips instead of a new triangulation.
  mutable std::unique_ptr<Triangulation> last_;
};

namespace detail {
/// The regular triangulation's in-circle test on weighted points {x, y, weight}: the side
/// (+1, 0, -1, as CGAL's Oriented_side) of t's power circle against the one through p, q, r
/// (counter-clockwise). `power_side` is what the triangulations here run (a double-precision
/// filter, CGAL's exact predicate when the filter cannot decide); `power_side_exact` is
/// CGAL's predicate alone. Exposed for the tests that hold the two equal.
int power_side(const double p[3], const double q[3], const double r[3], const double t[3]);
int power_side_exact(const double p[3], const double q[3], const double r[3], const double t[3]);
}  // namespace detail

}  // namespace brenier::omt

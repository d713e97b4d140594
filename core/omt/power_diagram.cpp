#include "omt/power_diagram.hpp"

#include <CGAL/Spatial_sort_traits_adapter_2.h>
#include <CGAL/hilbert_sort.h>
#include <boost/property_map/function_property_map.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

#include "common/check.hpp"
#include "common/error.hpp"
#include "omt/cell_geometry.hpp"
#include "omt/regular_triangulation.hpp"

namespace brenier::omt {

using namespace cells;
using namespace regular;

struct PowerDiagrams::Triangulation {
  RT rt;
  std::vector<RT::Face_handle> faces;     // rt's finite faces, listed by the first flips (flips keep them)
  Eigen::VectorXd psi;                    // the offsets rt is regular for
};

PowerDiagrams::~PowerDiagrams() = default;

void neighbour_lists(int n, const std::vector<std::pair<int, int>>& pairs, std::vector<int>& start,
                     std::vector<int>& nbr) {
  start.assign(n + 1, 0);
  for (auto [a, b] : pairs) ++start[a + 1], ++start[b + 1];
  for (int i = 0; i < n; ++i) start[i + 1] += start[i];
  nbr.resize(start[n]);
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (auto [a, b] : pairs) nbr[fill[a]++] = b, nbr[fill[b]++] = a;
  // Each cell is cut by its neighbours in index order, so the round-off of a cell does not
  // depend on how the triangulation was built or traversed (same input, same bits).
#pragma omp parallel for schedule(static)
  for (int i = 0; i < n; ++i) std::sort(nbr.begin() + start[i], nbr.begin() + start[i + 1]);
}


Domain Domain::unit_disk() { return Domain{}; }

Domain Domain::stereographic_sphere() {
  Domain d;
  d.is_disk = false;
  d.is_sphere = true;
  d.polygon.resize(4, 2);
  d.polygon << -kSphereFar, -kSphereFar, kSphereFar, -kSphereFar, kSphereFar, kSphereFar, -kSphereFar, kSphereFar;
  return d;
}

Domain Domain::convex_polygon(const Points& corners) {
  const int n = static_cast<int>(corners.rows());
  if (n < 3) invalid("a polygon domain needs at least 3 corners, got " + std::to_string(n));
  if (!corners.allFinite()) invalid("the polygon domain has non-finite corners");
  for (int k = 0; k < n; ++k) {
    Vec2 a = corners.row(k), b = corners.row((k + 1) % n), c = corners.row((k + 2) % n);
    if (!(cross(b - a, c - b) > 0))
      invalid("the polygon domain is not strictly convex and counter-clockwise at corner " + std::to_string((k + 1) % n));
  }
  Domain d;
  d.is_disk = false;
  d.polygon = corners;
  return d;
}

Domain Domain::square(double half) {
  Points p(4, 2);
  p << -half, -half, half, -half, half, half, -half, half;
  return convex_polygon(p);
}

double Domain::area() const {
  if (is_sphere) return 4 * std::numbers::pi;
  if (density) {
    double m = 0;
    for (int f = 0; f < density->faces.rows(); ++f) {
      Vec2 a = density->vertices.row(density->faces(f, 0)), b = density->vertices.row(density->faces(f, 1)),
           c = density->vertices.row(density->faces(f, 2));
      m += density->density[f] * 0.5 * cross(b - a, c - a);
    }
    return m;
  }
  if (is_disk) return std::numbers::pi * radius * radius;
  double a = 0;
  for (int k = 0; k < polygon.rows(); ++k) a += 0.5 * cross(polygon.row(k), polygon.row((k + 1) % polygon.rows()));
  return a;
}

bool Domain::contains(double x, double y, double slack) const {
  if (is_sphere) return std::isfinite(x) && std::isfinite(y);
  if (is_disk) return std::hypot(x, y) <= radius + slack;
  for (int k = 0; k < polygon.rows(); ++k) {
    Vec2 a = polygon.row(k), b = polygon.row((k + 1) % polygon.rows());
    Vec2 e = b - a;
    if (cross(e, Vec2(x, y) - a) < -slack * e.norm()) return false;
  }
  return true;
}

namespace {

// The points' indices in Hilbert order: plain (no random rounds of CGAL's spatial_sort), so
// deterministic.
std::vector<int> hilbert_order(const Points& points) {
  std::vector<int> order(points.rows());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  // (A lambda's own type, not a std::function: the sort reads the map O(n log n) times.)
  auto at = [&points](int i) { return K::Point_2(points(i, 0), points(i, 1)); };
  using Map = boost::function_property_map<decltype(at), int, K::Point_2>;
  const CGAL::Spatial_sort_traits_adapter_2<K, Map> traits{Map{at}};
  CGAL::hilbert_sort(order.begin(), order.end(), traits);
  return order;
}

// The neighbour lists (CSR, as neighbour_lists makes them) of a planar regular triangulation
// of n sites, from one pass over its finite edges; hidden sites have none.
void triangulation_neighbours(const RT& rt, int n, std::vector<int>& start, std::vector<int>& nbr) {
  std::vector<std::pair<int, int>> adjacent;
  adjacent.reserve(3 * static_cast<size_t>(n));
  for (auto e = rt.finite_edges_begin(); e != rt.finite_edges_end(); ++e)
    adjacent.emplace_back(e->first->vertex(RT::cw(e->second))->info(), e->first->vertex(RT::ccw(e->second))->info());
  neighbour_lists(n, adjacent, start, nbr);
}

}  // namespace

PowerDiagrams::PowerDiagrams(Domain domain, Points sites, bool check_distinct)
    : domain_(std::move(domain)), sites_(std::move(sites)) {
  const int n = static_cast<int>(sites_.rows());
  if (n == 0) invalid("no sites");
  if (!sites_.allFinite()) invalid("sites must be finite");
  // Coincident sites would share one cell: refuse them by name.
  if (check_distinct) {
    std::vector<int> order(n);
    for (int i = 0; i < n; ++i) order[i] = i;
    std::sort(order.begin(), order.end(), [&](int a, int b) {
      return sites_(a, 0) < sites_(b, 0) || (sites_(a, 0) == sites_(b, 0) && sites_(a, 1) < sites_(b, 1));
    });
    for (int k = 1; k < n; ++k)
      if (sites_.row(order[k]) == sites_.row(order[k - 1]))
        invalid("sites " + std::to_string(std::min(order[k], order[k - 1])) + " and " +
                std::to_string(std::max(order[k], order[k - 1])) + " coincide");
  }
  // The sites never move between diagrams (only their heights do), so their Hilbert order
  // -- which makes each insertion's point location walk a step or two -- is computed once.
  order_ = hilbert_order(sites_);
}

Eigen::VectorXd PowerDiagrams::offsets(const Eigen::VectorXd& h) const {
  if (h.size() != sites_.rows())
    invalid("heights: " + std::to_string(h.size()) + " for " + std::to_string(sites_.rows()) + " sites");
  return h + 0.5 * sites_.rowwise().squaredNorm();
}

PowerCells PowerDiagrams::operator()(const Eigen::VectorXd& h) const { return *build(offsets(h), {}, false); }

PowerCells PowerDiagrams::at_offsets(const Eigen::VectorXd& psi, const Eigen::VectorXd& lo) const {
  return *build(psi, lo, false);
}

std::optional<PowerCells> PowerDiagrams::at_offsets_if_none_hidden(const Eigen::VectorXd& psi,
                                                                   const Eigen::VectorXd& lo) const {
  return build(psi, lo, true);
}

namespace {

// The polygon every cell starts from: the domain's box or polygon. A polygon of many sides
// (the hull of a conformal image: every boundary vertex a corner) would make every cell
// start with hundreds of vertices. Cells start from its bounding box instead and are cut by
// the polygon's sides afterwards, only those near the outline: a cell whose corners all lie
// within the polygon's inscribed circle about its vertex mean is inside (a 5K-site diagram
// on a 240-gon spent a third of its time clipping before).
class CellStart {
 public:
  explicit CellStart(const Domain& domain) {
    std::vector<Vec2> corners;
    if (domain.is_disk) {
      const double r = domain.radius;
      corners = {Vec2(-r, -r), Vec2(r, -r), Vec2(r, r), Vec2(-r, r)};
    } else {
      for (int k = 0; k < domain.polygon.rows(); ++k) corners.push_back(domain.polygon.row(k));
    }
    late_ = !domain.is_disk && corners.size() > 8;
    outline_ = outline(corners);
    if (late_) corners = late_outline(corners);
    start_ = outline(corners);
  }
  const LabelledPolygon& polygon() const { return start_; }

  /// Cuts P by the outline's sides that can cut it (nothing unless the outline is late).
  void cut_by_outline(LabelledPolygon& P, LabelledPolygon& scratch) const {
    if (!late_) return;
    const auto [first, count] = sides_near(P);
    const int sides = static_cast<int>(outline_.line.size());
    for (int q = 0; q < count && P.p.size() >= 3; ++q) {
      const Eigen::Vector3d& ln = outline_.line[static_cast<size_t>((first + q) % sides)];
      bool cuts = false;
      for (const Vec2& x : P.p) cuts = cuts || ln.head<2>().dot(x) + ln.z() < 0;
      if (cuts) clip(P, ln.head<2>(), ln.z(), -1, scratch);
    }
  }

 private:
  // The centre, the inscribed radius and the corners' angles about the centre; returns the
  // bounding box's corners, which cells start from.
  std::vector<Vec2> late_outline(const std::vector<Vec2>& corners) {
    for (const Vec2& x : corners) centre_ += x;
    centre_ /= static_cast<double>(corners.size());
    inscribed_ = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < corners.size(); ++k) {
      const Eigen::Vector3d& ln = outline_.line[k];
      inscribed_ = std::min(inscribed_, (ln.head<2>().dot(centre_) + ln.z()) / ln.head<2>().norm());
    }
    inscribed_ *= 1 - 1e-12;
    // The corners' angles about the centre, increasing from the first's (the outline is
    // convex and counter-clockwise about it).
    for (const Vec2& x : corners) {
      double a = std::atan2(x.y() - centre_.y(), x.x() - centre_.x());
      while (!corner_angle_.empty() && a < corner_angle_.front()) a += 2 * std::numbers::pi;
      corner_angle_.push_back(a);
    }
    Vec2 lo = corners.front(), hi = lo;
    for (const Vec2& x : corners) lo = lo.cwiseMin(x), hi = hi.cwiseMax(x);
    const Vec2 pad = 1e-9 * (hi - lo) + Vec2::Constant(1e-300);
    lo -= pad, hi += pad;
    return {lo, Vec2(hi.x(), lo.y()), hi, Vec2(lo.x(), hi.y())};
  }

  // The outline's sides that can cut P, as (first, count) in cyclic order. Each point of P
  // outside the outline is outside the side its angle about the centre falls in, so the
  // sides whose angular spans meet P's suffice (one more at either end against round-off);
  // P spanning 3 radians or more (about the centre) is cut by every side. (Trying every
  // side of a 5K image's ~240-gon on each cell near it made a pair measurably slower.)
  std::pair<int, int> sides_near(const LabelledPolygon& P) const {
    bool inside = true;
    for (const Vec2& x : P.p) inside = inside && (x - centre_).squaredNorm() <= inscribed_ * inscribed_;
    const int sides = static_cast<int>(outline_.line.size());
    if (inside) return {0, 0};
    const Vec2 u0 = P.p.front() - centre_;
    double dmin = 0, dmax = 0;
    for (const Vec2& x : P.p) {
      const Vec2 u = x - centre_;
      const double d = std::atan2(cross(u0, u), u0.dot(u));
      dmin = std::min(dmin, d), dmax = std::max(dmax, d);
    }
    if (dmax - dmin >= 3) return {0, sides};
    double a = std::atan2(u0.y(), u0.x()) + dmin;
    while (a < corner_angle_.front()) a += 2 * std::numbers::pi;
    while (a >= corner_angle_.front() + 2 * std::numbers::pi) a -= 2 * std::numbers::pi;
    const int k0 =
        static_cast<int>(std::upper_bound(corner_angle_.begin(), corner_angle_.end(), a) - corner_angle_.begin()) - 1;
    const double end = a + (dmax - dmin);
    int k = k0 + 1;
    auto angle = [&](int j) { return corner_angle_[j % sides] + (j >= sides ? 2 * std::numbers::pi : 0.0); };
    while (k < k0 + sides && angle(k) < end) ++k;
    return {(k0 - 1 + sides) % sides, std::min(sides, k - k0 + 2)};
  }

  bool late_ = false;
  LabelledPolygon outline_, start_;
  Vec2 centre_ = Vec2::Zero();
  double inscribed_ = 0;
  std::vector<double> corner_angle_;
};

// Per-thread scratch of the cells' integrals.
struct CellScratch {
  LabelledPolygon P, clipped;
  TrianglePiece piece;
  DiskBoundary boundary;
  std::vector<int> stamp, queue;
  explicit CellScratch(const Domain& domain) {
    if (!domain.density) return;
    piece.stamp.assign(domain.density->vertices.rows(), -1);
    piece.mask.resize(domain.density->vertices.rows());
    stamp.assign(domain.density->faces.rows(), -1);
  }
};

// Cell i's mass, centroid and second moment from its integrals (about its site y).
void store_cell(const Domain& domain, int i, const Vec2& y, const CellResult& cr, PowerCells& out) {
  out.mass[i] = cr.m.area;
  if (domain.is_sphere) {
    const double norm = cr.sphere_first.norm();
    // (A cell that is the whole sphere but for a null set has no direction.)
    const Eigen::Vector3d C = norm > 1e-300 ? Eigen::Vector3d(cr.sphere_first / norm) : to_sphere(y);
    out.sphere_centroid.row(i) = C.transpose();
    out.centroid.row(i) << C.x() / (1 - C.z()), C.y() / (1 - C.z());
    out.second_moment[i] = 2 * cr.m.area - 2 * cr.sphere_first.dot(to_sphere(y));
    return;
  }
  out.centroid.row(i) = (y + cr.m.first / cr.m.area).transpose();
  out.second_moment[i] = cr.m.second;
}

}  // namespace

// The kept triangulation updated by flips, or a new one in `fresh` (kept when it holds
// every site). Null when a site was found hidden and `fail_if_hidden` asked to stop.
const PowerDiagrams::Triangulation* PowerDiagrams::regular(const Eigen::VectorXd& psi, bool fail_if_hidden,
                                                           Triangulation& fresh) const {
  const int n = static_cast<int>(sites_.rows());
  const Reweighted flipped =
      last_ ? reweight_by_flips(last_->rt, last_->faces, sites_, last_->psi, psi, fail_if_hidden) : Reweighted::kStuck;
  if (flipped == Reweighted::kHidden) return nullptr;
  if (flipped == Reweighted::kRegular) {
    last_->psi = psi;
    return last_.get();
  }
  if (!triangulate(sites_, psi, order_, fail_if_hidden, fresh.rt)) return nullptr;
  if (fresh.rt.number_of_hidden_vertices() != 0 || static_cast<int>(fresh.rt.number_of_vertices()) != n ||
      fresh.rt.dimension() != 2)
    return &fresh;
  if (!last_) last_ = std::make_unique<Triangulation>();
  last_->rt.swap(fresh.rt);
  last_->faces.clear();
  last_->psi = psi;
  return last_.get();
}

std::optional<PowerCells> PowerDiagrams::build(const Eigen::VectorXd& psi, const Eigen::VectorXd& lo,
                                               bool fail_if_hidden) const {
  const Domain& domain = domain_;
  const Points& sites = sites_;
  const int n = static_cast<int>(sites.rows());
  if (psi.size() != n || (lo.size() != 0 && lo.size() != n))
    invalid("offsets: " + std::to_string(psi.size()) + " for " + std::to_string(n) + " sites");
  if (!psi.allFinite() || !lo.allFinite()) invalid("heights must be finite");
  const bool has_lo = lo.size() != 0;
  Triangulation fresh;
  const Triangulation* t = regular(psi, fail_if_hidden, fresh);
  if (!t) return std::nullopt;
  const RT& rt = t->rt;
  if (domain.density && start_triangle_.size() != static_cast<size_t>(n)) start_triangle_.assign(n, -1);
  // Neighbour lists (CSR) from one pass over the triangulation's edges; which sites have a vertex.
  std::vector<char> present(n, 0);
  for (auto v = rt.finite_vertices_begin(); v != rt.finite_vertices_end(); ++v) present[v->info()] = 1;
  std::vector<int> start, nbr;
  triangulation_neighbours(rt, n, start, nbr);
  PowerCells out;
  out.mass = Eigen::VectorXd::Zero(n);
  out.centroid = sites;
  out.second_moment = Eigen::VectorXd::Zero(n);
  if (domain.is_sphere) {
    out.sphere_centroid.resize(n, 3);
    for (int i = 0; i < n; ++i) out.sphere_centroid.row(i) = to_sphere(sites.row(i)).transpose();
  }
  std::vector<double> slot_length(nbr.size(), 0.0);
  const CellStart cell_start(domain);
#pragma omp parallel
  {
    CellScratch s(domain);
#pragma omp for schedule(dynamic, 256)
    for (int i = 0; i < n; ++i) {
      if (!present[i]) continue;
      LabelledPolygon& P = s.P;
      P = cell_start.polygon();
      const Vec2 yi = sites.row(i);
      for (int k = start[i]; k < start[i + 1] && !P.p.empty(); ++k) {
        const int j = nbr[k];
        const Vec2 yj = sites.row(j);
        // W_i: <x, y_i> + h_i >= <x, y_j> + h_j, with h_i - h_j = psi_i - psi_j - <y_i - y_j, y_i + y_j> / 2:
        // the difference of the squares as a product keeps its relative precision for
        // sites close together (h_i itself carries the round-off of |y_i|^2).
        const double low = has_lo ? lo[i] - lo[j] : 0.0;
        clip(P, yi - yj, ((psi[i] - psi[j]) + low) - 0.5 * (yi - yj).dot(yi + yj), k, s.clipped);
      }
      cell_start.cut_by_outline(P, s.clipped);
      if (P.p.size() < 3) continue;
      CellResult cr;
      cr.slot_length = slot_length.data();
      if (domain.is_sphere)
        integrate_sphere(P, yi, cr);
      else if (domain.density)
        integrate_density(P, *domain.density, yi, i, s.stamp, s.queue, start_triangle_[i], s.piece, cr);
      else if (domain.is_disk)
        integrate_disk(P, domain.radius, yi, s.boundary, cr);
      else
        integrate_polygon(P, yi, cr);
      if (cr.m.area > 0) store_cell(domain, i, yi, cr, out);
    }
  }
  for (int i = 0; i < n; ++i) {
    if (!(out.mass[i] > 0)) ++out.empty_cells;
    for (int k = start[i]; k < start[i + 1]; ++k)
      if (i < nbr[k] && slot_length[k] > 0) out.edges.push_back({i, nbr[k], slot_length[k]});
  }
  return out;
}

namespace {

// Greedy walk (as CGAL's nearest_power_vertex, but from a given vertex): move to a neighbour
// of smaller power distance to p until none is; on a regular triangulation the local
// minimum is the global one. Exact predicates decide every comparison. `tied` tells whether
// a neighbour of the answer is as near to p.
RT::Vertex_handle walk_to_nearest(const RT& rt, RT::Vertex_handle v, const K::Point_2& p, bool& tied) {
  const auto closer = K().compare_power_distance_2_object();
  for (bool moved = true; moved;) {
    moved = false;
    tied = false;
    RT::Vertex_circulator c = rt.incident_vertices(v), first = c;
    if (c == nullptr) break;
    do {
      if (rt.is_infinite(c)) continue;
      const CGAL::Comparison_result r = closer(p, c->point(), v->point());
      if (r == CGAL::SMALLER) {
        v = c;
        moved = true;
        break;
      }
      tied = tied || r == CGAL::EQUAL;
    } while (++c != first);
  }
  return v;
}

// The least site index among v (nearest to p in power distance) and the sites as near to p
// (all of them: they are connected through the triangulation's edges, as the vertices of one
// face of the power diagram are).
int least_tied(const RT& rt, RT::Vertex_handle v, const K::Point_2& p) {
  const auto compare = K().compare_power_distance_2_object();
  int least = v->info();
  std::vector<RT::Vertex_handle> tied{v};
  for (size_t k = 0; k < tied.size(); ++k) {
    RT::Vertex_circulator c = rt.incident_vertices(tied[k]), first = c;
    if (c == nullptr) continue;
    do {
      if (rt.is_infinite(c) || std::find(tied.begin(), tied.end(), RT::Vertex_handle(c)) != tied.end()) continue;
      if (compare(p, c->point(), v->point()) == CGAL::EQUAL) {
        tied.push_back(c);
        least = std::min(least, c->info());
      }
    } while (++c != first);
  }
  return least;
}

void check_queries(const Eigen::VectorXd& h, const Points& queries, int n) {
  if (h.size() != n) invalid("heights: " + std::to_string(h.size()) + " for " + std::to_string(n) + " sites");
  if (!h.allFinite()) invalid("heights must be finite");
  if (!queries.allFinite()) invalid("query points must be finite");
}

}  // namespace

std::vector<int> PowerDiagrams::locate(const Eigen::VectorXd& h, const Points& queries) const {
  check_queries(h, queries, static_cast<int>(sites_.rows()));
  RT rt;
  triangulate(sites_, offsets(h), order_, false, rt);
  std::vector<int> out(queries.rows(), -1);
  if (rt.number_of_vertices() == 0) return out;
  // Queries in Hilbert order, each thread a contiguous run of them (the triangulation is only
  // read): each walk starts at the last answer, a step or two away. In the callers' order a
  // walk from the last answer crossed the diagram for every query that came in no spatial
  // order: omt-bench's random 100K sites against their 12,500 coarse ones took 0.54 s, a fifth
  // of the whole transport (bench/RESULTS.md, session 77). A query on a power bisector goes
  // to the least site index among the tied ones, whatever path its walk took.
  const std::vector<int> order = hilbert_order(queries);
#pragma omp parallel
  {
    RT::Vertex_handle v = rt.finite_vertices_begin();
#pragma omp for schedule(static)
    for (size_t k = 0; k < order.size(); ++k) {
      const int q = order[k];
      const K::Point_2 p(queries(q, 0), queries(q, 1));
      bool tied = false;
      v = walk_to_nearest(rt, v, p, tied);
      out[q] = tied ? least_tied(rt, v, p) : v->info();
    }
  }
  return out;
}

Eigen::VectorXd PowerDiagrams::smoothed_max(const Eigen::VectorXd& h, const Points& queries, double eps) const {
  check_queries(h, queries, static_cast<int>(sites_.rows()));
  if (!(eps > 0)) invalid("the smoothing width must be positive");
  const int n = static_cast<int>(sites_.rows());
  RT rt;
  triangulate(sites_, offsets(h), order_, false, rt);
  Eigen::VectorXd out(queries.rows());
  if (rt.number_of_vertices() == 0) return out.setConstant(-std::numeric_limits<double>::infinity());
  // The walks and the sums read the triangulation's neighbour lists (CSR) and the sites as
  // plain arrays: through CGAL's circulators and handles the finest level of the 100K disk
  // map's coarse start took 0.62-0.66 s (bench/RESULTS.md, session 48).
  std::vector<int> start, nbr;
  triangulation_neighbours(rt, n, start, nbr);
  std::vector<double> y(2 * static_cast<size_t>(n));  // the sites, x and y side by side
  for (int i = 0; i < n; ++i) {
    y[2 * i] = sites_(i, 0);
    y[2 * i + 1] = sites_(i, 1);
  }
  const int some_vertex = rt.finite_vertices_begin()->info();
  // Queries in Hilbert order, each thread a contiguous run of them: each walk starts at the
  // last answer, a step or two away.
  const std::vector<int> order = hilbert_order(queries);
#pragma omp parallel
  {
    std::vector<int> stamp(n, -1);
    std::vector<int> queue;
    int v = some_vertex;
#pragma omp for schedule(static)
    for (size_t k = 0; k < order.size(); ++k) {
      const int q = order[k];
      const double qx = queries(q, 0), qy = queries(q, 1);
      auto value = [&](int w) { return qx * y[2 * w] + qy * y[2 * w + 1] + h[w]; };
      // The largest value, <x, y_w> + h_w (the least power distance), by steepest ascent: in
      // a regular triangulation a vertex no neighbour beats is the power diagram's cell of x.
      double top = value(v);
      for (int from = -1; from != v;) {
        from = v;
        for (int j = start[from]; j < start[from + 1]; ++j) {
          const double t = value(nbr[j]);
          if (t > top) {
            top = t;
            v = nbr[j];
          }
        }
      }
      // The terms within e^-kSmoothedMaxCut of the largest, found by a search from it over the lists.
      double sum = 0;
      queue.assign(1, v);
      stamp[v] = q;
      while (!queue.empty()) {
        const int w = queue.back();
        queue.pop_back();
        const double t = (value(w) - top) / eps;
        if (!(t > -kSmoothedMaxCut)) continue;  // (the maximum itself always counts: t = 0)
        sum += std::exp(t);
        for (int j = start[w]; j < start[w + 1]; ++j)
          if (stamp[nbr[j]] != q) {
            stamp[nbr[j]] = q;
            queue.push_back(nbr[j]);
          }
      }
      out[q] = top + eps * std::log(sum);
    }
  }
  return out;
}

PowerCells power_cells(const Domain& domain, const Points& sites, const Eigen::VectorXd& h, bool check_distinct) {
  return PowerDiagrams(domain, sites, check_distinct)(h);
}

}  // namespace brenier::omt

#include "omt/power_diagram.hpp"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Regular_triangulation_2.h>
#include <CGAL/Regular_triangulation_face_base_2.h>
#include <CGAL/Regular_triangulation_vertex_base_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>
#include <CGAL/Spatial_sort_traits_adapter_2.h>
#include <CGAL/hilbert_sort.h>
#include <boost/property_map/function_property_map.hpp>

#include <functional>

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

#include "common/error.hpp"

namespace brenier::omt {

namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Vbb = CGAL::Regular_triangulation_vertex_base_2<K>;
using Vb = CGAL::Triangulation_vertex_base_with_info_2<int, K, Vbb>;
using Fb = CGAL::Regular_triangulation_face_base_2<K>;
using Tds = CGAL::Triangulation_data_structure_2<Vb, Fb>;
using RT = CGAL::Regular_triangulation_2<K, Tds>;
using WP = K::Weighted_point_2;

using Vec2 = Eigen::Vector2d;
double cross(const Vec2& a, const Vec2& b) { return a.x() * b.y() - a.y() * b.x(); }

// Integrals of 1, x and |x|^2 over a region, accumulated from pieces.
struct Moments {
  double area = 0;
  Vec2 first = Vec2::Zero();
  double second = 0;
  void add_triangle(const Vec2& p, const Vec2& q) {  // triangle (0, p, q), signed
    double a = 0.5 * cross(p, q);
    area += a;
    first += a * (p + q) / 3.0;
    second += a * (p.squaredNorm() + q.squaredNorm() + p.dot(q)) / 6.0;
  }
};

// Circular segment of the disk |x| <= R between the chord X -> Y and the arc from X to Y
// counter-clockwise (central angle theta in (0, 2 pi)): integrals about the disk centre,
// in closed form without cancellation for short chords (series for small theta).
Moments circular_segment(const Vec2& X, const Vec2& Y, double R) {
  Moments m;
  double theta = std::atan2(cross(X, Y), X.dot(Y));
  if (theta < 0) theta = theta > -1e-12 ? 0.0 : theta + 2 * std::numbers::pi;
  if (theta == 0) return m;
  const double t2 = theta * theta;
  // theta - sin(theta) and 3 theta - 2 sin(theta) - sin(2 theta) / 2.
  double a = theta < 1e-2 ? theta * t2 * (1.0 / 6 - t2 / 120 + t2 * t2 / 5040) : theta - std::sin(theta);
  double s = theta < 1e-2 ? theta * t2 * (1 - 0.15 * t2 + 33.0 / 2520 * t2 * t2)
                          : 3 * theta - 2 * std::sin(theta) - 0.5 * std::sin(2 * theta);
  const double R2 = R * R;
  m.area = 0.5 * R2 * a;
  const double mid = std::atan2(X.y(), X.x()) + 0.5 * theta, h = std::sin(0.5 * theta);
  m.first = (2.0 / 3.0) * R2 * R * h * h * h * Vec2(std::cos(mid), std::sin(mid));
  m.second = R2 * R2 / 12.0 * s;
  return m;
}

// A convex polygon with, for each edge (corner k -> k+1), the slot of the neighbour whose
// bisector it lies on (-1: the domain's or the bounding box's side).
struct LabelledPolygon {
  std::vector<Vec2> p;
  std::vector<int> label;
};

// Keeps the part where <x, n> + c >= 0 (Sutherland-Hodgman); the new side is labelled j.
void clip(LabelledPolygon& P, const Vec2& n, double c, int j, LabelledPolygon& out) {
  out.p.clear();
  out.label.clear();
  const size_t m = P.p.size();
  for (size_t k = 0; k < m; ++k) {
    const Vec2& a = P.p[k];
    const Vec2& b = P.p[(k + 1) % m];
    double fa = a.dot(n) + c, fb = b.dot(n) + c;
    if (fa >= 0) {
      out.p.push_back(a);
      out.label.push_back(P.label[k]);
      if (fb < 0) {
        out.p.push_back(a + (fa / (fa - fb)) * (b - a));
        out.label.push_back(j);
      }
    } else if (fb >= 0) {
      out.p.push_back(a + (fa / (fa - fb)) * (b - a));
      out.label.push_back(P.label[k]);
    }
  }
  std::swap(P, out);
}

struct CellResult {
  Moments m;  // about the site
  double* slot_length = nullptr;  // per neighbour slot (the polygon labels): its edge length
};

enum BoundaryKind { kCorner, kEntry, kExit };
using DiskBoundary = std::vector<std::pair<Vec2, BoundaryKind>>;

// Integrates polygon ∩ disk(R) about the local origin c; dual-edge lengths per label. `q`
// is scratch (the boundary of P ∩ D in order: corners inside, entry and exit points).
void integrate_disk(const LabelledPolygon& P, double R, const Vec2& c, DiskBoundary& q, CellResult& out) {
  const double R2 = R * R;
  const size_t m = P.p.size();
  q.clear();
  for (size_t k = 0; k < m; ++k) {
    const Vec2& a = P.p[k];
    const Vec2& b = P.p[(k + 1) % m];
    const Vec2 d = b - a;
    const bool ina = a.squaredNorm() <= R2, inb = b.squaredNorm() <= R2;
    // The part s in [s_in, s_out] of the edge a + s d is inside the disk. An edge with one
    // end inside always has its crossing recorded (even at the corner itself: a corner on
    // the circle counts as inside), one with both ends outside only when it cuts through.
    double s_in = 0, s_out = 1;
    bool entry = false, exit = false;
    if (!ina || !inb) {
      const double A = d.squaredNorm(), B = a.dot(d), C = a.squaredNorm() - R2;
      const double disc = B * B - A * C;
      double s1 = inb ? 1.0 : 0.0, s2 = s1;
      if (A > 0 && disc >= 0) {
        const double r = std::sqrt(disc);
        const double qq = -(B + std::copysign(r, B));  // roots without cancellation
        s1 = qq != 0 ? qq / A : 0.0;
        s2 = qq != 0 ? C / qq : 0.0;
        if (s1 > s2) std::swap(s1, s2);
      }
      if (ina) {
        exit = true;
        s_out = std::clamp(s2, 0.0, 1.0);
      } else if (inb) {
        entry = true;
        s_in = std::clamp(s1, 0.0, 1.0);
      } else if (A > 0 && disc > 0 && s1 > 0 && s2 < 1 && s1 < s2) {
        entry = exit = true;
        s_in = s1;
        s_out = s2;
      } else {
        continue;  // wholly outside
      }
    }
    if (ina) q.push_back({a, kCorner});
    if (entry) q.push_back({a + s_in * d, kEntry});
    if (exit) q.push_back({a + s_out * d, kExit});
    if (P.label[k] >= 0 && s_out > s_in) out.slot_length[P.label[k]] += std::sqrt(d.squaredNorm()) * (s_out - s_in);
  }
  Moments& mo = out.m;
  if (q.empty()) {
    // No corner inside and no edge crossing: the disk is inside P (P holds the centre) or
    // misses it.
    bool centre_inside = true;
    for (size_t k = 0; k < m; ++k) centre_inside = centre_inside && cross(P.p[(k + 1) % m] - P.p[k], -P.p[k]) >= 0;
    if (!centre_inside) return;
    mo.area = std::numbers::pi * R2;
    mo.first = -mo.area * c;  // about c: ∫(x - c) = -c |D|
    mo.second = 0.5 * std::numbers::pi * R2 * R2 + mo.area * c.squaredNorm();
    return;
  }
  const size_t nq = q.size();
  for (size_t k = 0; k < nq; ++k) {
    const auto& [x, kx] = q[k];
    const auto& [y, ky] = q[(k + 1) % nq];
    mo.add_triangle(x - c, y - c);
    if (kx == kExit && ky == kEntry) {
      // The boundary follows the circle from x to y: add the segment beyond the chord,
      // moved from the disk centre to the local origin c.
      Moments s = circular_segment(x, y, R);
      mo.area += s.area;
      mo.first += s.first - s.area * c;
      mo.second += s.second - 2 * c.dot(s.first) + s.area * c.squaredNorm();
    }
  }
}

// Polygon integrals about the local origin c, times a constant density.
void integrate_polygon(const LabelledPolygon& P, const Vec2& c, CellResult& out, double density = 1.0) {
  const size_t m = P.p.size();
  Moments part;
  for (size_t k = 0; k < m; ++k) {
    const Vec2& a = P.p[k];
    const Vec2& b = P.p[(k + 1) % m];
    part.add_triangle(a - c, b - c);
    if (P.label[k] >= 0) out.slot_length[P.label[k]] += density * (b - a).norm();
  }
  out.m.area += density * part.area;
  out.m.first += density * part.first;
  out.m.second += density * part.second;
}

// Cell polygon P against the piecewise-constant density: P ∩ T for every triangle T of the
// buckets P's bounding box meets (each once: stamp), integrated with T's density.
void integrate_density(const LabelledPolygon& P, const DensityMesh& dm, const Vec2& c, int cell_id,
                       std::vector<int>& stamp, LabelledPolygon& Q, LabelledPolygon& scratch, CellResult& out) {
  double xmin = P.p[0].x(), xmax = xmin, ymin = P.p[0].y(), ymax = ymin;
  for (const Vec2& q : P.p) {
    xmin = std::min(xmin, q.x()), xmax = std::max(xmax, q.x());
    ymin = std::min(ymin, q.y()), ymax = std::max(ymax, q.y());
  }
  auto bx = [&](double x) { return std::clamp(static_cast<int>((x - dm.x0) / dm.cell), 0, dm.nx - 1); };
  auto by = [&](double y) { return std::clamp(static_cast<int>((y - dm.y0) / dm.cell), 0, dm.ny - 1); };
  for (int gy = by(ymin); gy <= by(ymax); ++gy)
    for (int gx = bx(xmin); gx <= bx(xmax); ++gx) {
      const int b = gy * dm.nx + gx;
      for (int k = dm.bucket_start[b]; k < dm.bucket_start[b + 1]; ++k) {
        const int f = dm.bucket_faces[k];
        if (stamp[f] == cell_id || dm.density[f] == 0) continue;
        stamp[f] = cell_id;
        Q = P;
        for (int e = 0; e < 3 && Q.p.size() >= 3; ++e) {
          const Vec2 a = dm.vertices.row(dm.faces(f, e)), d = Vec2(dm.vertices.row(dm.faces(f, (e + 1) % 3))) - a;
          const Vec2 n(-d.y(), d.x());  // inward normal of the counter-clockwise triangle
          clip(Q, n, -a.dot(n), -1, scratch);
        }
        if (Q.p.size() >= 3) integrate_polygon(Q, c, out, dm.density[f]);
      }
    }
}

}  // namespace

Domain Domain::unit_disk() { return Domain{}; }

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

Domain Domain::piecewise_constant(const Points& V, const Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>& F,
                                  const Eigen::VectorXd& rho) {
  const int nv = static_cast<int>(V.rows()), nf = static_cast<int>(F.rows());
  if (nf == 0 || nv < 3) invalid("the density mesh has no triangles");
  if (rho.size() != nf)
    invalid("density: " + std::to_string(rho.size()) + " values for " + std::to_string(nf) + " triangles");
  if (!V.allFinite()) invalid("the density mesh has non-finite vertices");
  auto dm = std::make_shared<DensityMesh>();
  dm->vertices = V;
  dm->faces = F;
  dm->density = rho;
  for (int f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k)
      if (F(f, k) < 0 || F(f, k) >= nv) invalid("triangle " + std::to_string(f) + " has a vertex out of range");
    if (!(rho[f] >= 0) || !std::isfinite(rho[f]))
      invalid("the density of triangle " + std::to_string(f) + " is " + std::to_string(rho[f]) + "; it must be >= 0");
    Vec2 a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    if (cross(b - a, c - a) < 0) std::swap(dm->faces(f, 1), dm->faces(f, 2));  // counter-clockwise
  }
  // Convex hull (Andrew's monotone chain), counter-clockwise: the cells' outline.
  std::vector<int> idx(nv);
  for (int i = 0; i < nv; ++i) idx[i] = i;
  std::sort(idx.begin(), idx.end(), [&](int a, int b) { return V(a, 0) < V(b, 0) || (V(a, 0) == V(b, 0) && V(a, 1) < V(b, 1)); });
  std::vector<int> hull(2 * nv);
  int k = 0;
  auto turn = [&](int o, int a, int b) { return cross(Vec2(V.row(a)) - Vec2(V.row(o)), Vec2(V.row(b)) - Vec2(V.row(o))); };
  for (int i = 0; i < nv; ++i) {
    while (k >= 2 && turn(hull[k - 2], hull[k - 1], idx[i]) <= 0) --k;
    hull[k++] = idx[i];
  }
  for (int i = nv - 2, lower = k + 1; i >= 0; --i) {
    while (k >= lower && turn(hull[k - 2], hull[k - 1], idx[i]) <= 0) --k;
    hull[k++] = idx[i];
  }
  if (k - 1 < 3) invalid("the density mesh is degenerate (collinear vertices)");
  Points corners(k - 1, 2);
  for (int i = 0; i < k - 1; ++i) corners.row(i) = V.row(hull[i]);
  Domain d = convex_polygon(corners);
  // Bucket grid of about one triangle per bucket.
  double xmin = V.col(0).minCoeff(), xmax = V.col(0).maxCoeff(), ymin = V.col(1).minCoeff(), ymax = V.col(1).maxCoeff();
  const double side = std::max(xmax - xmin, ymax - ymin);
  const int g = std::clamp(static_cast<int>(std::sqrt(static_cast<double>(nf))), 1, 4096);
  dm->x0 = xmin;
  dm->y0 = ymin;
  dm->cell = side / g * (1 + 1e-12);
  dm->nx = dm->ny = g;
  std::vector<std::pair<int, int>> entries;  // (bucket, face)
  for (int f = 0; f < nf; ++f) {
    double fx0 = V(F(f, 0), 0), fx1 = fx0, fy0 = V(F(f, 0), 1), fy1 = fy0;
    for (int c = 1; c < 3; ++c) {
      fx0 = std::min(fx0, V(F(f, c), 0)), fx1 = std::max(fx1, V(F(f, c), 0));
      fy0 = std::min(fy0, V(F(f, c), 1)), fy1 = std::max(fy1, V(F(f, c), 1));
    }
    auto bx = [&](double x) { return std::clamp(static_cast<int>((x - dm->x0) / dm->cell), 0, g - 1); };
    auto by = [&](double y) { return std::clamp(static_cast<int>((y - dm->y0) / dm->cell), 0, g - 1); };
    for (int gy = by(fy0); gy <= by(fy1); ++gy)
      for (int gx = bx(fx0); gx <= bx(fx1); ++gx) entries.push_back({gy * g + gx, f});
  }
  std::sort(entries.begin(), entries.end());
  dm->bucket_start.assign(static_cast<size_t>(g) * g + 1, 0);
  for (auto [b, f] : entries) ++dm->bucket_start[b + 1];
  for (size_t b = 0; b + 1 < dm->bucket_start.size(); ++b) dm->bucket_start[b + 1] += dm->bucket_start[b];
  for (auto [b, f] : entries) dm->bucket_faces.push_back(f);
  d.density = dm;
  return d;
}

double Domain::area() const {
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
  if (is_disk) return std::hypot(x, y) <= radius + slack;
  for (int k = 0; k < polygon.rows(); ++k) {
    Vec2 a = polygon.row(k), b = polygon.row((k + 1) % polygon.rows());
    Vec2 e = b - a;
    if (cross(e, Vec2(x, y) - a) < -slack * e.norm()) return false;
  }
  return true;
}

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
  order_.resize(n);
  for (int i = 0; i < n; ++i) order_[i] = i;
  using Map = boost::function_property_map<std::function<K::Point_2(int)>, int, K::Point_2>;
  std::function<K::Point_2(int)> at = [this](int i) { return K::Point_2(sites_(i, 0), sites_(i, 1)); };
  CGAL::Spatial_sort_traits_adapter_2<K, Map> traits(boost::make_function_property_map<int, K::Point_2>(at));
  // Plain Hilbert order (no random rounds of CGAL's spatial_sort): deterministic.
  CGAL::hilbert_sort(order_.begin(), order_.end(), traits);
}

PowerCells PowerDiagrams::operator()(const Eigen::VectorXd& h) const { return *build(h, false); }

std::optional<PowerCells> PowerDiagrams::if_none_hidden(const Eigen::VectorXd& h) const { return build(h, true); }

std::optional<PowerCells> PowerDiagrams::build(const Eigen::VectorXd& h, bool fail_if_hidden) const {
  const Domain& domain = domain_;
  const Points& sites = sites_;
  const int n = static_cast<int>(sites.rows());
  if (h.size() != n) invalid("heights: " + std::to_string(h.size()) + " for " + std::to_string(n) + " sites");
  if (!h.allFinite()) invalid("heights must be finite");
  // Regular triangulation of the weighted points (y_i, |y_i|^2 + 2 h_i): its adjacency is
  // the power diagram's; hidden points have empty cells. A hidden point stays hidden as
  // more are inserted (the lifted lower hull only descends), so a caller that rejects any
  // empty cell can stop at the first one found.
  RT rt;
  RT::Face_handle hint;
  const int check_every = std::max(256, n / 64);
  for (int k = 0; k < n; ++k) {
    const int i = order_[k];
    const WP p(K::Point_2(sites(i, 0), sites(i, 1)), sites.row(i).squaredNorm() + 2 * h[i]);
    RT::Vertex_handle v = rt.insert(p, hint);
    if (v == RT::Vertex_handle()) continue;
    v->info() = i;
    hint = v->face();
    if (fail_if_hidden && (k + 1) % check_every == 0 && rt.number_of_hidden_vertices() > 0) return std::nullopt;
  }
  if (fail_if_hidden && rt.number_of_hidden_vertices() > 0) return std::nullopt;
  // Neighbour lists (CSR) from one pass over the triangulation's edges.
  std::vector<int> start(n + 1, 0), nbr;
  std::vector<char> present(n, 0);
  for (auto v = rt.finite_vertices_begin(); v != rt.finite_vertices_end(); ++v) present[v->info()] = 1;
  std::vector<std::pair<int, int>> adjacent;
  adjacent.reserve(3 * static_cast<size_t>(n));
  for (auto e = rt.finite_edges_begin(); e != rt.finite_edges_end(); ++e) {
    const int a = e->first->vertex(RT::cw(e->second))->info(), b = e->first->vertex(RT::ccw(e->second))->info();
    adjacent.emplace_back(a, b);
    ++start[a + 1];
    ++start[b + 1];
  }
  for (int i = 0; i < n; ++i) start[i + 1] += start[i];
  nbr.resize(start[n]);
  {
    std::vector<int> fill(start.begin(), start.end() - 1);
    for (auto [a, b] : adjacent) {
      nbr[fill[a]++] = b;
      nbr[fill[b]++] = a;
    }
  }
  // Each cell clips by its neighbours in index order, so the round-off of a cell does not
  // depend on how the triangulation was built or traversed (same input, same bits).
  for (int i = 0; i < n; ++i) std::sort(nbr.begin() + start[i], nbr.begin() + start[i + 1]);
  PowerCells out;
  out.mass = Eigen::VectorXd::Zero(n);
  out.centroid = sites;
  out.second_moment = Eigen::VectorXd::Zero(n);
  std::vector<double> slot_length(nbr.size(), 0.0);
  LabelledPolygon start_polygon;
  if (domain.is_disk) {
    const double r = domain.radius;
    start_polygon.p = {Vec2(-r, -r), Vec2(r, -r), Vec2(r, r), Vec2(-r, r)};
  } else {
    for (int k = 0; k < domain.polygon.rows(); ++k) start_polygon.p.push_back(domain.polygon.row(k));
  }
  start_polygon.label.assign(start_polygon.p.size(), -1);

#pragma omp parallel
  {
    LabelledPolygon P, scratch, Q;
    DiskBoundary q;
    std::vector<int> stamp(domain.density ? domain.density->faces.rows() : 0, -1);
#pragma omp for schedule(dynamic, 256)
    for (int i = 0; i < n; ++i) {
      if (!present[i]) continue;
      P = start_polygon;
      const Vec2 yi = sites.row(i);
      for (int k = start[i]; k < start[i + 1] && !P.p.empty(); ++k) {
        const int j = nbr[k];
        const Vec2 yj = sites.row(j);
        // W_i: <x, y_i> + h_i >= <x, y_j> + h_j.
        clip(P, yi - yj, h[i] - h[j], k, scratch);
      }
      if (P.p.size() < 3) continue;
      CellResult cr;
      cr.slot_length = slot_length.data();
      if (domain.density)
        integrate_density(P, *domain.density, yi, i, stamp, Q, scratch, cr);
      else if (domain.is_disk)
        integrate_disk(P, domain.radius, yi, q, cr);
      else
        integrate_polygon(P, yi, cr);
      if (!(cr.m.area > 0)) continue;
      out.mass[i] = cr.m.area;
      out.centroid.row(i) = (yi + cr.m.first / cr.m.area).transpose();
      out.second_moment[i] = cr.m.second;
    }
  }
  for (int i = 0; i < n; ++i) {
    if (!(out.mass[i] > 0)) ++out.empty_cells;
    for (int k = start[i]; k < start[i + 1]; ++k)
      if (i < nbr[k] && slot_length[k] > 0) out.edges.push_back({i, nbr[k], slot_length[k]});
  }
  return out;
}

PowerCells power_cells(const Domain& domain, const Points& sites, const Eigen::VectorXd& h, bool check_distinct) {
  if (h.size() != sites.rows())
    invalid("heights: " + std::to_string(h.size()) + " for " + std::to_string(sites.rows()) + " sites");
  return PowerDiagrams(domain, sites, check_distinct)(h);
}

}  // namespace brenier::omt

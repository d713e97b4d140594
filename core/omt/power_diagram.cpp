#include "omt/power_diagram.hpp"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Regular_triangulation_2.h>
#include <CGAL/Regular_triangulation_face_base_2.h>
#include <CGAL/Regular_triangulation_vertex_base_2.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>

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

// Integrates polygon ∩ disk(R) about the local origin c; dual-edge lengths per label.
void integrate_disk(const LabelledPolygon& P, double R, const Vec2& c, CellResult& out) {
  const double R2 = R * R;
  const size_t m = P.p.size();
  // The boundary of P ∩ D in order: corners inside, entry and exit points.
  enum Kind { kCorner, kEntry, kExit };
  std::vector<std::pair<Vec2, Kind>> q;
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

void integrate_polygon(const LabelledPolygon& P, const Vec2& c, CellResult& out) {
  const size_t m = P.p.size();
  for (size_t k = 0; k < m; ++k) {
    const Vec2& a = P.p[k];
    const Vec2& b = P.p[(k + 1) % m];
    out.m.add_triangle(a - c, b - c);
    if (P.label[k] >= 0) out.slot_length[P.label[k]] += (b - a).norm();
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

double Domain::area() const {
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

PowerCells power_cells(const Domain& domain, const Points& sites, const Eigen::VectorXd& h, bool check_distinct) {
  const int n = static_cast<int>(sites.rows());
  if (n == 0) invalid("no sites");
  if (h.size() != n) invalid("heights: " + std::to_string(h.size()) + " for " + std::to_string(n) + " sites");
  if (!sites.allFinite() || !h.allFinite()) invalid("sites and heights must be finite");
  // Coincident sites would share one cell: refuse them by name.
  if (check_distinct) {
    std::vector<int> order(n);
    for (int i = 0; i < n; ++i) order[i] = i;
    std::sort(order.begin(), order.end(), [&](int a, int b) {
      return sites(a, 0) < sites(b, 0) || (sites(a, 0) == sites(b, 0) && sites(a, 1) < sites(b, 1));
    });
    for (int k = 1; k < n; ++k)
      if (sites.row(order[k]) == sites.row(order[k - 1]))
        invalid("sites " + std::to_string(std::min(order[k], order[k - 1])) + " and " +
                std::to_string(std::max(order[k], order[k - 1])) + " coincide");
  }
  // Regular triangulation of the weighted points (y_i, |y_i|^2 + 2 h_i): its adjacency is
  // the power diagram's; hidden points have empty cells.
  std::vector<std::pair<WP, int>> wp;
  wp.reserve(n);
  for (int i = 0; i < n; ++i) {
    K::Point_2 y(sites(i, 0), sites(i, 1));
    wp.push_back({WP(y, sites.row(i).squaredNorm() + 2 * h[i]), i});
  }
  RT rt;
  rt.insert(wp.begin(), wp.end());
  // Neighbour lists (CSR) in two passes over the triangulation, without per-site vectors.
  std::vector<int> start(n + 1, 0), nbr;
  std::vector<char> present(n, 0);
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<int> fill;
    if (pass == 1) {
      for (int i = 0; i < n; ++i) start[i + 1] += start[i];
      nbr.resize(start[n]);
      fill.assign(start.begin(), start.end() - 1);
    }
    for (auto v = rt.finite_vertices_begin(); v != rt.finite_vertices_end(); ++v) {
      const int i = v->info();
      present[i] = 1;
      if (rt.dimension() == 0) continue;
      auto c = rt.incident_vertices(v), done = c;
      do {
        if (rt.is_infinite(c)) continue;
        if (pass == 0)
          ++start[i + 1];
        else
          nbr[fill[i]++] = c->info();
      } while (++c != done);
    }
  }
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
    LabelledPolygon P, scratch;
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
      if (domain.is_disk)
        integrate_disk(P, domain.radius, yi, cr);
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

}  // namespace brenier::omt

#include "omt/power_diagram.hpp"

#include <Eigen/Geometry>

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
#include <bit>
#include <cstdint>
#include <cmath>
#include <limits>
#include <numbers>
#include <span>
#include <string>
#include <tuple>
#include <vector>

#include "common/check.hpp"
#include "common/error.hpp"

namespace brenier::omt {

namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using WP = K::Weighted_point_2;

// The regular triangulation's in-circle test -- the sign of the 3x3 determinant of the
// rows (x - t_x, y - t_y, |(x, y) - t|^2 - w + w_t) for p, q, r against t -- decided in
// plain doubles when the result clears a forward error bound, and by CGAL's exact
// predicate (interval filter, then exact arithmetic) otherwise: a semi-static filter.
// CGAL's Epick has static filters for the Delaunay in-circle test but none for this one,
// and its interval filter (rounding-mode switches) was 15-17 % of a whole OT solve.
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
// bisector it lies on (-1: the domain's or the bounding box's side) and that line,
// {x : <x, n> + c = 0} stored as (n, c).
struct LabelledPolygon {
  std::vector<Vec2> p;
  std::vector<int> label;
  std::vector<Eigen::Vector3d> line;
  std::vector<double> value;  // scratch of clip: each corner's <x, n> + c
  void add(const Vec2& x, int l, const Eigen::Vector3d& ln) {
    p.push_back(x);
    label.push_back(l);
    line.push_back(ln);
  }
};

// Where the edge a -> b (on `edge_line`) crosses the line <x, n> + c = 0 (fa, fb: its
// values at a and b, of opposite signs). Interpolation keeps the point between a and b but
// carries an error of eps |b - a|: fine for edges of the unit disk's box, far too much for
// edges of the sphere's stereographic plane, clipped from a box 1e9 across. Long edges
// therefore meet the two lines directly (error relative to the lines' own coefficients),
// unless they are nearly parallel.
Vec2 crossing(const Vec2& a, const Vec2& b, double fa, double fb, const Eigen::Vector3d& edge_line, const Vec2& n,
              double c) {
  const Vec2 interpolated = a + (fa / (fa - fb)) * (b - a);
  if ((b - a).squaredNorm() < 1e4) return interpolated;
  const double det = edge_line.x() * n.y() - edge_line.y() * n.x();
  const double scale = std::hypot(edge_line.x(), edge_line.y()) * n.norm();
  if (!(std::abs(det) > 1e-8 * scale)) return interpolated;
  const Vec2 x((-edge_line.z() * n.y() + c * edge_line.y()) / det, (-c * edge_line.x() + edge_line.z() * n.x()) / det);
  const double slack = 1e-9 * (b - a).norm();
  if (x.x() < std::min(a.x(), b.x()) - slack || x.x() > std::max(a.x(), b.x()) + slack ||
      x.y() < std::min(a.y(), b.y()) - slack || x.y() > std::max(a.y(), b.y()) + slack)
    return interpolated;
  return x;
}

// Keeps the part where <x, n> + c >= 0 (Sutherland-Hodgman); the new side is labelled j.
void clip(LabelledPolygon& P, const Vec2& n, double c, int j, LabelledPolygon& out) {
  // Most half-planes leave the polygon whole (a cell's far neighbours, a triangle side
  // beyond the cell): then nothing is copied. Each corner's value is computed once, for the
  // test and the cut both (clip was a quarter of a Wasserstein pair's time).
  const size_t m = P.p.size();
  std::vector<double>& f = P.value;
  f.resize(m);
  bool whole = true;
  for (size_t k = 0; k < m; ++k) {
    f[k] = P.p[k].dot(n) + c;
    whole = whole && !(f[k] < 0);
  }
  if (whole) return;
  out.p.clear();
  out.label.clear();
  out.line.clear();
  const Eigen::Vector3d new_line(n.x(), n.y(), c);
  for (size_t k = 0; k < m; ++k) {
    const size_t k1 = k + 1 == m ? 0 : k + 1;
    const Vec2& a = P.p[k];
    const Vec2& b = P.p[k1];
    const double fa = f[k], fb = f[k1];
    if (fa >= 0) {
      out.add(a, P.label[k], P.line[k]);
      if (fb < 0) out.add(crossing(a, b, fa, fb, P.line[k], n, c), j, new_line);
    } else if (fb >= 0) {
      out.add(crossing(a, b, fa, fb, P.line[k], n, c), P.label[k], P.line[k]);
    }
  }
  std::swap(P, out);
}

// The polygon of the given counter-clockwise corners, every side labelled -1.
LabelledPolygon outline(const std::vector<Vec2>& corners) {
  LabelledPolygon P;
  const size_t m = corners.size();
  for (size_t k = 0; k < m; ++k) {
    const Vec2 d = corners[(k + 1) % m] - corners[k];
    const Vec2 n(-d.y(), d.x());  // inward
    P.add(corners[k], -1, Eigen::Vector3d(n.x(), n.y(), -corners[k].dot(n)));
  }
  return P;
}

struct CellResult {
  Moments m;  // about the site (sphere: m.area only)
  Eigen::Vector3d sphere_first = Eigen::Vector3d::Zero();  // sphere: ∫ X dA
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
    const Vec2& b = P.p[k + 1 == m ? 0 : k + 1];
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

// Polygon integrals about the local origin c, times a constant density (P: corners p and
// side labels, a LabelledPolygon or a TrianglePiece).
template <class Polygon>
void integrate_polygon(const Polygon& P, const Vec2& c, CellResult& out, double density = 1.0) {
  const size_t m = P.p.size();
  Moments part;
  for (size_t k = 0; k < m; ++k) {
    const Vec2& a = P.p[k];
    const Vec2& b = P.p[k + 1 == m ? 0 : k + 1];
    part.add_triangle(a - c, b - c);
    if (P.label[k] >= 0) out.slot_length[P.label[k]] += density * (b - a).norm();
  }
  out.m.area += density * part.area;
  out.m.first += density * part.first;
  out.m.second += density * part.second;
}

// Cell polygon P against the piecewise-constant density: P ∩ T for every triangle T of the
// buckets P's bounding box meets (each once: stamp), integrated with T's density.
// The triangle of dm holding point p, by a visibility walk from triangle t (crossing an edge
// that has p on its outer side, the edges tried in a rotating order so that the walk cannot
// circle forever in a non-Delaunay triangulation); -1 if the walk is too long.
int walk_to(const DensityMesh& dm, int t, const Vec2& p) {
  const int limit = 64 + 8 * static_cast<int>(std::sqrt(static_cast<double>(dm.faces.rows())));
  for (int step = 0; step < limit; ++step) {
    bool moved = false;
    for (int r = 0; r < 3 && !moved; ++r) {
      const int e = (r + step) % 3;
      const Vec2 a = dm.vertices.row(dm.faces(t, e)), b = dm.vertices.row(dm.faces(t, (e + 1) % 3));
      if (cross(b - a, p - a) < 0) {
        const int g = dm.neighbour(t, e);
        if (g < 0) return t;  // p beyond the hull (by round-off): its nearest triangle will do
        t = g;
        moved = true;
      }
    }
    if (!moved) return t;
  }
  return -1;
}

// A piece of one density triangle: its corners and, per side (corner k -> k + 1), the slot
// of the cell side it lies on (-1: a side of the triangle). Scratch of integrate_density.
struct TrianglePiece {
  // Two buffers of corners and side labels (a cut reads one and writes the other), sized
  // for three corners plus one per side of the cell (a cut adds at most one corner).
  std::vector<Vec2> corner[2];
  std::vector<int> label[2];
  std::vector<double> f;  // each corner's value against the line being cut by
  int now = 0;            // the buffer holding the piece
  size_t size = 0;
  void reserve(size_t sides) {
    if (f.size() >= sides + 3) return;
    for (int b = 0; b < 2; ++b) corner[b].resize(sides + 3), label[b].resize(sides + 3);
    f.resize(sides + 3);
  }
  void set_triangle(const Vec2 (&t)[3]) {
    now = 0;
    size = 3;
    for (int v = 0; v < 3; ++v) corner[0][v] = t[v], label[0][v] = -1;
  }
  struct View {
    std::span<const Vec2> p;
    std::span<const int> label;
  };
  View view() const { return {{corner[now].data(), size}, {label[now].data(), size}}; }
  // Per vertex of the density mesh: the cell its mask was computed for, and the mask (bit e:
  // the vertex is strictly outside side e of that cell).
  static constexpr size_t kMaskSides = 64;
  std::vector<int> stamp;
  std::vector<uint64_t> mask;
  uint64_t outside(int vertex, const Vec2& x, const LabelledPolygon& P, int cell) {
    if (stamp[vertex] == cell) return mask[vertex];
    uint64_t bits = 0;
    const Eigen::Vector3d* line = P.line.data();
    for (size_t e = 0, m = std::min(P.line.size(), kMaskSides); e < m; ++e)
      bits |= uint64_t{line[e].x() * x.x() + line[e].y() * x.y() + line[e].z() < 0} << e;
    stamp[vertex] = cell;
    return mask[vertex] = bits;
  }
};

// Keeps the part of the piece where <x, n> + c >= 0, given each corner's value f
// (Sutherland-Hodgman, as clip(), on plain corners: the density's triangles lie within the
// unit disk, where interpolated crossings are accurate); the new side is labelled j.
void cut_piece(TrianglePiece& T, int j) {
  const size_t m = T.size;
  const Vec2* p = T.corner[T.now].data();
  const int* l = T.label[T.now].data();
  Vec2* q = T.corner[1 - T.now].data();
  int* ql = T.label[1 - T.now].data();
  const double* f = T.f.data();
  size_t out = 0;
  for (size_t k = 0; k < m; ++k) {
    const size_t k1 = k + 1 == m ? 0 : k + 1;
    const double fa = f[k], fb = f[k1];
    if (fa >= 0) {
      q[out] = p[k];
      ql[out++] = l[k];
      if (fb < 0) {
        q[out] = p[k] + (fa / (fa - fb)) * (p[k1] - p[k]);
        ql[out++] = j;
      }
    } else if (fb >= 0) {
      q[out] = p[k] + (fa / (fa - fb)) * (p[k1] - p[k]);
      ql[out++] = l[k];
    }
  }
  T.now = 1 - T.now;
  T.size = out;
}

// Cell P (site c) under the piecewise-constant density: each triangle T it overlaps,
// clipped by the sides of P that cut it, integrated exactly with T's density (moments about
// c, and the dual-edge lengths weighted by the density). The triangles are found by a flood
// fill over triangle adjacency from one holding a point of P (P is convex and the triangles
// tile the hull, so those meeting P's interior are edge-connected), which costs what the
// overlaps cost however unevenly the triangles are sized (the conformal image of a long
// protrusion packs thousands into one bucket of a uniform grid). `start` is where the
// search begins and gets the triangle found.
//
// Clipping the triangle (three corners, cut by the sides of P with a corner outside: 2.8
// on average, the triangles being about as large as the cells) rather than P by the
// triangle (a copy of P's six or so corners, cut by up to three sides), with each mesh
// vertex's sides found once per cell, took a 5K diagram's cells from 12 to 8.3 ms.
void integrate_density(const LabelledPolygon& P, const DensityMesh& dm, const Vec2& c, int cell_id,
                       std::vector<int>& stamp, std::vector<int>& queue, int& start, TrianglePiece& T,
                       CellResult& out) {
  Vec2 inside = Vec2::Zero();
  for (const Vec2& q : P.p) inside += q;
  inside /= static_cast<double>(P.p.size());
  int t = start;
  if (t < 0 || t >= dm.faces.rows()) {
    const int gx = std::clamp(static_cast<int>((inside.x() - dm.x0) / dm.cell), 0, dm.nx - 1);
    const int gy = std::clamp(static_cast<int>((inside.y() - dm.y0) / dm.cell), 0, dm.ny - 1);
    const int b = gy * dm.nx + gx;
    t = dm.bucket_start[b] < dm.bucket_start[b + 1] ? dm.bucket_faces[dm.bucket_start[b]] : 0;
  }
  t = walk_to(dm, t, inside);
  if (t < 0) t = walk_to(dm, 0, inside);
  BRENIER_CHECK(t >= 0, "no triangle of the density mesh found for cell " << cell_id);
  start = t;
  T.reserve(P.p.size());
  queue.clear();
  queue.push_back(t);
  stamp[t] = cell_id;
  for (size_t k = 0; k < queue.size(); ++k) {
    const int f = queue[k];
    const Vec2 corner[3] = {dm.vertices.row(dm.faces(f, 0)), dm.vertices.row(dm.faces(f, 1)),
                            dm.vertices.row(dm.faces(f, 2))};
    // About half the triangles the flood fill looks at are the ring just outside the cell
    // (apart: nothing to integrate or spread from), a quarter lie inside it. Each corner's
    // sides of P are found once per cell, as a bit mask (a corner is shared by about six
    // triangles): a side with all three corners outside separates the two; the sides with
    // one outside cut the triangle. A triangle apart from P that no side of P separates
    // from it (near a corner of P) is cut away to nothing below.
    uint64_t outside_all = ~uint64_t{0}, outside_any = 0;
    for (int v = 0; v < 3; ++v) {
      const uint64_t mask = T.outside(dm.faces(f, v), corner[v], P, cell_id);
      outside_all &= mask;
      outside_any |= mask;
    }
    if (outside_all != 0) continue;
    T.set_triangle(corner);
    auto cut_by = [&](size_t e) {
      const double a = P.line[e].x(), b = P.line[e].y(), c0 = P.line[e].z();
      const Vec2* p = T.corner[T.now].data();
      double* value = T.f.data();
      bool whole = true;
      for (size_t v = 0, m = T.size; v < m; ++v) {
        value[v] = a * p[v].x() + b * p[v].y() + c0;
        whole &= !(value[v] < 0);
      }
      if (!whole) cut_piece(T, P.label[e]);
    };
    for (uint64_t bits = outside_any; bits != 0 && T.size >= 3; bits &= bits - 1) cut_by(std::countr_zero(bits));
    // (Sides beyond the 64 a mask holds -- a cell along many sides of the domain's outline
    // -- are tried on every triangle.)
    for (size_t e = TrianglePiece::kMaskSides; e < P.line.size() && T.size >= 3; ++e) cut_by(e);
    if (T.size < 3) continue;  // P misses f: do not spread from it
    if (dm.density[f] > 0) integrate_polygon(T.view(), c, out, dm.density[f]);
    for (int e = 0; e < 3; ++e) {
      const int g = dm.neighbour(f, e);
      if (g >= 0 && stamp[g] != cell_id) {
        stamp[g] = cell_id;
        queue.push_back(g);
      }
    }
  }
}

constexpr double kSphereFar = 1e9;  // half side of the box the unbounded sphere cells are cut by

// The inverse stereographic projection (north pole = infinity).
Eigen::Vector3d to_sphere(const Vec2& x) {
  const double q = 1 + x.squaredNorm();
  return Eigen::Vector3d(2 * x.x() / q, 2 * x.y() / q, (x.squaredNorm() - 1) / q);
}

// Polygon P under the sphere's measure 4 / (1 + |x|^2)^2 dx of the stereographic plane
// (sec. 3.2.5), edge by edge. For the edge a -> b on the line at signed distance d from
// the origin (d = a x e, e the unit direction; t = <x, e> along the line, s^2 = 1 + d^2):
// - mass, as the signed fan (0, a, b) in polar coordinates: int 2 r^2 / (1 + r^2) dtheta
//   = (2 d / s) [atan(t / s)] from t_a to t_b;
// - dual-edge mass: int 4 / (s^2 + t^2)^2 dt = 2 [t / (s^2 (s^2 + t^2)) + atan(t / s) / s^3];
// - first moment on the sphere: the line's image is the circle of the plane
//   <(X1, X2), m> + d X3 = d (m = (e_y, -e_x)), unit normal N = (m, d) / s, centre
//   c = (d / s) N, radius 1 / s, through the north pole; int_W X dA = 1/2 oint X x dX and
//   along an arc of angle dphi about N that is 1/2 [c x (X_b - X_a) + dphi N / s^2]. The
//   arc is the one that avoids the north pole (the image of infinity).
// Small cells are integrated by quadrature instead (integrate_sphere_small): the closed
// forms are differences of O(1) fan terms, so a cell 1e-9 across would keep only round-off.
void integrate_sphere(const LabelledPolygon& P, const Vec2& site, CellResult& out);

// Gauss-Legendre, 4 points on [0, 1].
constexpr double kGaussX[4] = {0.0694318442029737, 0.3300094782075719, 0.6699905217924281, 0.9305681557970263};
constexpr double kGaussW[4] = {0.1739274225687269, 0.3260725774312731, 0.3260725774312731, 0.1739274225687269};

// The same integrals over a cell that is small beside the scale on which the density
// varies: each fan triangle (site, a, b) by a collapsed 4 x 4 Gauss rule (exact to degree
// 7; the density's relative variation over the cell is below 0.05, so the relative error
// stays ~1e-11), each edge by 4-point Gauss.
void integrate_sphere_small(const LabelledPolygon& P, const Vec2& site, CellResult& out) {
  const size_t m = P.p.size();
  auto density = [](const Vec2& x) {
    const double q = 1 + x.squaredNorm();
    return 4 / (q * q);
  };
  for (size_t k = 0; k < m; ++k) {
    const Vec2 a = P.p[k] - site, b = P.p[k + 1 == m ? 0 : k + 1] - site;
    const double jac = cross(a, b);  // twice the signed area
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) {
        const double u = kGaussX[i], v = kGaussX[j];
        const Vec2 x = site + u * ((1 - v) * a + v * b);
        const double w = kGaussW[i] * kGaussW[j] * u * jac * density(x);
        out.m.area += w;
        out.sphere_first += w * to_sphere(x);
      }
    if (P.label[k] >= 0) {
      const double len = (b - a).norm();
      double edge = 0;
      for (int i = 0; i < 4; ++i) edge += kGaussW[i] * density(site + a + kGaussX[i] * (b - a));
      out.slot_length[P.label[k]] += len * edge;
    }
  }
}

void integrate_sphere(const LabelledPolygon& P, const Vec2& site, CellResult& out) {
  const size_t m = P.p.size();
  double radius = 0;
  for (const Vec2& q : P.p) radius = std::max(radius, (q - site).norm());
  const double r = site.norm();
  if (2 * radius * (1 + 4 * r) / (1 + r * r) < 0.05) return integrate_sphere_small(P, site, out);
  const Eigen::Vector3d pole(0, 0, 1);
  for (size_t k = 0; k < m; ++k) {
    const Vec2& a = P.p[k];
    const Vec2& b = P.p[k + 1 == m ? 0 : k + 1];
    const double len = (b - a).norm();
    if (!(len > 0)) continue;
    const Vec2 e = (b - a) / len;
    // (From the end nearer the origin: from the far end of a ray, 1e9 out, a x e would
    // cancel down to ~1e-7.)
    const double d = cross(a.squaredNorm() <= b.squaredNorm() ? a : b, e), ta = a.dot(e), tb = b.dot(e);
    const double s2 = 1 + d * d, s = std::sqrt(s2);
    const double atan_a = std::atan(ta / s), atan_b = std::atan(tb / s);
    out.m.area += 2 * d / s * (atan_b - atan_a);
    if (P.label[k] >= 0) {
      auto F = [&](double t, double at) { return 2 * (t / (s2 * (s2 + t * t)) + at / (s2 * s)); };
      out.slot_length[P.label[k]] += F(tb, atan_b) - F(ta, atan_a);
    }
    const Eigen::Vector3d N = Eigen::Vector3d(e.y(), -e.x(), d) / s, c = (d / s) * N;
    const Eigen::Vector3d Xa = to_sphere(a), Xb = to_sphere(b);
    const Eigen::Vector3d u = Xa - c, v = Xb - c, z = pole - c;
    auto angle = [&](const Eigen::Vector3d& p, const Eigen::Vector3d& q) {
      return std::atan2(N.dot(p.cross(q)), p.dot(q));
    };
    double dphi = angle(u, v);
    const double phi_pole = angle(u, z);
    if (dphi > 0 && phi_pole > 0 && phi_pole < dphi) dphi -= 2 * std::numbers::pi;
    if (dphi < 0 && phi_pole < 0 && phi_pole > dphi) dphi += 2 * std::numbers::pi;
    out.sphere_first -= 0.5 * (c.cross(Xb - Xa) + (dphi / s2) * N);
  }
}

// Regular triangulation of the weighted points (y_i, 2 psi_i), psi the offsets of
// PowerDiagrams (power weight |y_i|^2 + 2 h_i = 2 psi_i, exact), inserted in `order`:
// its adjacency is the power diagram's; hidden points have empty cells. A hidden point
// stays hidden as more are inserted (the lifted lower hull only descends), so with
// `fail_if_hidden` it stops, returning false, at the first one found.
bool triangulate(const Points& sites, const Eigen::VectorXd& psi, const std::vector<int>& order, bool fail_if_hidden,
                 RT& rt) {
  const int n = static_cast<int>(sites.rows());
  RT::Face_handle hint;
  const int check_every = std::max(256, n / 64);
  for (int k = 0; k < n; ++k) {
    const int i = order[k];
    const WP p(K::Point_2(sites(i, 0), sites(i, 1)), 2 * psi[i]);
    RT::Vertex_handle v = rt.insert(p, hint);
    if (v == RT::Vertex_handle()) continue;
    v->info() = i;
    hint = v->face();
    if (fail_if_hidden && (k + 1) % check_every == 0 && rt.number_of_hidden_vertices() > 0) return false;
  }
  return !(fail_if_hidden && rt.number_of_hidden_vertices() > 0);
}

// Lawson's flips for regular triangulations: from a regular triangulation of all the sites
// for the previous heights, with the sites' weights set to the new ones, flip every edge
// whose opposite vertex is strictly inside the power circle of its face (the edge is not
// locally regular) while the quadrilateral is strictly convex. A triangulation of every
// site that is locally regular at every edge is the regular triangulation (Edelsbrunner
// and Shah 1996): the lifted points then form a locally convex, hence convex, surface, and
// no site is hidden. Sites do not move, so the convex hull and the edges on it stay. When
// edges remain that cannot be flipped -- a site that has to be hidden, or a flip sequence
// that is stuck -- every flip is undone and the weights restored, and the caller builds
// the triangulation anew. A Newton step moves few edges: at 10K sites a new triangulation
// took ~7 ms, mostly CGAL's insertions; the flips take a fraction of it.
enum class Reweighted { kRegular, kHidden, kStuck };

// A vertex of degree 3 whose lifted point lies above the plane through its three
// neighbours' is above the lower convex hull of the lifted sites: its site is hidden for
// certain, whatever the rest of the triangulation.
bool surely_hidden(const RT& rt, RT::Vertex_handle v, const PowerTest& power) {
  RT::Vertex_circulator w = rt.incident_vertices(v), end = w;
  RT::Vertex_handle around[3];
  int k = 0;
  do {
    if (k == 3 || rt.is_infinite(w)) return false;
    around[k++] = w;
  } while (++w != end);
  return k == 3 && power(around[0]->point(), around[1]->point(), around[2]->point(), v->point()) ==
                       CGAL::ON_NEGATIVE_SIDE;
}

Reweighted reweight_by_flips(RT& rt, const std::vector<RT::Vertex_handle>& vertex, const Points& sites,
                             const Eigen::VectorXd& old_psi, const Eigen::VectorXd& psi, bool stop_if_hidden) {
  const int n = static_cast<int>(sites.rows());
  if (rt.dimension() != 2) return Reweighted::kStuck;
  auto set_weights = [&](const Eigen::VectorXd& offsets) {
    for (int i = 0; i < n; ++i) vertex[i]->point() = WP(vertex[i]->point().point(), 2 * offsets[i]);
  };
  set_weights(psi);
  const PowerTest power;
  const auto orientation = Traits().orientation_2_object();
  using Edge = std::pair<RT::Vertex_handle, RT::Vertex_handle>;
  // Whether edge e is still there, between two finite faces, with the vertex across from
  // face f strictly inside f's power circle (f, i: the edge as face and opposite index).
  auto violates = [&](const Edge& e, RT::Face_handle& f, int& i) {
    if (!rt.is_edge(e.first, e.second, f, i)) return false;
    const RT::Face_handle g = f->neighbor(i);
    if (rt.is_infinite(f) || rt.is_infinite(g)) return false;  // a hull edge stays
    return power(f->vertex(0)->point(), f->vertex(1)->point(), f->vertex(2)->point(),
                 g->vertex(rt.mirror_index(f, i))->point()) == CGAL::ON_POSITIVE_SIDE;
  };
  std::vector<Edge> queue, stuck, flipped;
  queue.reserve(3 * static_cast<size_t>(n));
  for (auto e = rt.finite_edges_begin(); e != rt.finite_edges_end(); ++e)
    queue.emplace_back(e->first->vertex(RT::cw(e->second)), e->first->vertex(RT::ccw(e->second)));
  const size_t max_flips = 20 * static_cast<size_t>(n) + 1000;
  bool ok = true, hidden = false;
  while (ok && !queue.empty()) {
    const size_t flips_before = flipped.size();
    while (ok && !queue.empty()) {
      const Edge e = queue.back();
      queue.pop_back();
      RT::Face_handle f;
      int i;
      if (!violates(e, f, i)) continue;
      const RT::Vertex_handle c = f->vertex(i), a = f->vertex(RT::ccw(i)), b = f->vertex(RT::cw(i));
      const RT::Vertex_handle d = f->neighbor(i)->vertex(rt.mirror_index(f, i));
      if (orientation(c->point().point(), a->point().point(), d->point().point()) != CGAL::POSITIVE ||
          orientation(c->point().point(), d->point().point(), b->point().point()) != CGAL::POSITIVE) {
        // Not convex: the reflex corner a or b may be a site to hide (no flip can).
        if (stop_if_hidden && (surely_hidden(rt, a, power) || surely_hidden(rt, b, power))) {
          hidden = true;
          ok = false;
        }
        stuck.push_back(e);
        continue;
      }
      rt.flip(f, i);
      flipped.emplace_back(c, d);
      if (flipped.size() > max_flips) ok = false;
      queue.emplace_back(c, a);
      queue.emplace_back(a, d);
      queue.emplace_back(d, b);
      queue.emplace_back(b, c);
    }
    // Edges that could not be flipped may have become regular or flippable since.
    if (!stuck.empty()) {
      if (flipped.size() == flips_before) {
        for (const Edge& e : stuck) {
          RT::Face_handle f;
          int i;
          if (violates(e, f, i)) ok = false;
        }
        stuck.clear();
      } else {
        queue.swap(stuck);
        stuck.clear();
      }
    }
  }
  if (ok) return Reweighted::kRegular;
  for (auto e = flipped.rbegin(); e != flipped.rend(); ++e) {
    RT::Face_handle f;
    int i;
    const bool found = rt.is_edge(e->first, e->second, f, i);
    BRENIER_CHECK(found, "an edge flipped by the power-diagram update has disappeared");
    rt.flip(f, i);
  }
  set_weights(old_psi);
  return hidden ? Reweighted::kHidden : Reweighted::kStuck;
}

}  // namespace

struct PowerDiagrams::Triangulation {
  RT rt;
  std::vector<RT::Vertex_handle> vertex;  // by site
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
  // Triangle adjacency across edges (an edge used twice the same way round means the
  // triangles overlap: not a triangulation).
  dm->neighbour.setConstant(nf, 3, -1);
  std::vector<std::tuple<int, int, int>> half;  // (min vertex, max vertex, 3 f + k)
  half.reserve(3 * static_cast<size_t>(nf));
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) {
      const int a = dm->faces(f, k), b = dm->faces(f, (k + 1) % 3);
      half.emplace_back(std::min(a, b), std::max(a, b), 3 * f + k);
    }
  std::sort(half.begin(), half.end());
  for (size_t k = 0; k + 1 < half.size(); ++k) {
    auto [a0, b0, h0] = half[k];
    auto [a1, b1, h1] = half[k + 1];
    if (a0 != a1 || b0 != b1) continue;
    if (k + 2 < half.size() && std::get<0>(half[k + 2]) == a0 && std::get<1>(half[k + 2]) == b0)
      invalid("the density mesh's edge (" + std::to_string(a0) + ", " + std::to_string(b0) + ") has more than two triangles");
    dm->neighbour(h0 / 3, h0 % 3) = h1 / 3;
    dm->neighbour(h1 / 3, h1 % 3) = h0 / 3;
    ++k;
  }
  d.density = dm;
  return d;
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
  // (A lambda's own type, not a std::function: the sort reads the map O(n log n) times.)
  auto at = [this](int i) { return K::Point_2(sites_(i, 0), sites_(i, 1)); };
  using Map = boost::function_property_map<decltype(at), int, K::Point_2>;
  const CGAL::Spatial_sort_traits_adapter_2<K, Map> traits{Map{at}};
  // Plain Hilbert order (no random rounds of CGAL's spatial_sort): deterministic.
  CGAL::hilbert_sort(order_.begin(), order_.end(), traits);
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

std::optional<PowerCells> PowerDiagrams::build(const Eigen::VectorXd& psi, const Eigen::VectorXd& lo,
                                               bool fail_if_hidden) const {
  const Domain& domain = domain_;
  const Points& sites = sites_;
  const int n = static_cast<int>(sites.rows());
  if (psi.size() != n || (lo.size() != 0 && lo.size() != n))
    invalid("offsets: " + std::to_string(psi.size()) + " for " + std::to_string(n) + " sites");
  if (!psi.allFinite() || !lo.allFinite()) invalid("heights must be finite");
  const bool has_lo = lo.size() != 0;
  // The kept triangulation updated by flips, or a new one (kept when it holds every site).
  RT fresh;
  const RT* rt_used = nullptr;
  const Reweighted flipped =
      last_ ? reweight_by_flips(last_->rt, last_->vertex, sites, last_->psi, psi, fail_if_hidden) : Reweighted::kStuck;
  if (flipped == Reweighted::kHidden) return std::nullopt;
  if (flipped == Reweighted::kRegular) {
    last_->psi = psi;
    rt_used = &last_->rt;
  } else {
    if (!triangulate(sites, psi, order_, fail_if_hidden, fresh)) return std::nullopt;
    if (fresh.number_of_hidden_vertices() == 0 && static_cast<int>(fresh.number_of_vertices()) == n &&
        fresh.dimension() == 2) {
      if (!last_) last_ = std::make_unique<Triangulation>();
      last_->rt.swap(fresh);
      last_->vertex.assign(n, RT::Vertex_handle());
      for (auto v = last_->rt.finite_vertices_begin(); v != last_->rt.finite_vertices_end(); ++v)
        last_->vertex[v->info()] = v;
      last_->psi = psi;
      rt_used = &last_->rt;
    } else {
      rt_used = &fresh;
    }
  }
  const RT& rt = *rt_used;
  if (domain.density && start_triangle_.size() != static_cast<size_t>(n)) start_triangle_.assign(n, -1);
  // Neighbour lists (CSR) from one pass over the triangulation's edges.
  std::vector<char> present(n, 0);
  for (auto v = rt.finite_vertices_begin(); v != rt.finite_vertices_end(); ++v) present[v->info()] = 1;
  std::vector<std::pair<int, int>> adjacent;
  adjacent.reserve(3 * static_cast<size_t>(n));
  for (auto e = rt.finite_edges_begin(); e != rt.finite_edges_end(); ++e)
    adjacent.emplace_back(e->first->vertex(RT::cw(e->second))->info(), e->first->vertex(RT::ccw(e->second))->info());
  std::vector<int> start, nbr;
  neighbour_lists(n, adjacent, start, nbr);
  PowerCells out;
  out.mass = Eigen::VectorXd::Zero(n);
  out.centroid = sites;
  out.second_moment = Eigen::VectorXd::Zero(n);
  if (domain.is_sphere) {
    out.sphere_centroid.resize(n, 3);
    for (int i = 0; i < n; ++i) out.sphere_centroid.row(i) = to_sphere(sites.row(i)).transpose();
  }
  std::vector<double> slot_length(nbr.size(), 0.0);
  std::vector<Vec2> corners;
  if (domain.is_disk) {
    const double r = domain.radius;
    corners = {Vec2(-r, -r), Vec2(r, -r), Vec2(r, r), Vec2(-r, r)};
  } else {
    for (int k = 0; k < domain.polygon.rows(); ++k) corners.push_back(domain.polygon.row(k));
  }
  // A polygon of many sides (the hull of a conformal image: every boundary vertex a corner)
  // would make every cell start with hundreds of vertices. Cells start from its bounding box
  // instead and are cut by the polygon's sides afterwards, only those near the outline: a
  // cell whose corners all lie within the polygon's inscribed circle about its vertex mean
  // is inside (measured: a 5K-site diagram on a 240-gon spent a third of its time clipping).
  const bool late_outline = !domain.is_disk && corners.size() > 8;
  LabelledPolygon outline_polygon = outline(corners);
  Vec2 centre = Vec2::Zero();
  double inscribed = 0;
  std::vector<double> corner_angle;
  if (late_outline) {
    for (const Vec2& x : corners) centre += x;
    centre /= static_cast<double>(corners.size());
    inscribed = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < corners.size(); ++k) {
      const Eigen::Vector3d& ln = outline_polygon.line[k];
      inscribed = std::min(inscribed, (ln.head<2>().dot(centre) + ln.z()) / ln.head<2>().norm());
    }
    inscribed *= 1 - 1e-12;
    // The corners' angles about the centre, increasing from the first's (the outline is
    // convex and counter-clockwise about it).
    for (const Vec2& x : corners) {
      double a = std::atan2(x.y() - centre.y(), x.x() - centre.x());
      while (!corner_angle.empty() && a < corner_angle.front()) a += 2 * std::numbers::pi;
      corner_angle.push_back(a);
    }
    Vec2 lo = corners.front(), hi = lo;
    for (const Vec2& x : corners) lo = lo.cwiseMin(x), hi = hi.cwiseMax(x);
    const Vec2 pad = 1e-9 * (hi - lo) + Vec2::Constant(1e-300);
    lo -= pad, hi += pad;
    corners = {lo, Vec2(hi.x(), lo.y()), hi, Vec2(lo.x(), hi.y())};
  }
  const LabelledPolygon start_polygon = outline(corners);

#pragma omp parallel
  {
    LabelledPolygon P, scratch;
    TrianglePiece piece;
    if (domain.density) {
      piece.stamp.assign(domain.density->vertices.rows(), -1);
      piece.mask.resize(domain.density->vertices.rows());
    }
    DiskBoundary q;
    std::vector<int> stamp(domain.density ? domain.density->faces.rows() : 0, -1), queue;
#pragma omp for schedule(dynamic, 256)
    for (int i = 0; i < n; ++i) {
      if (!present[i]) continue;
      P = start_polygon;
      const Vec2 yi = sites.row(i);
      for (int k = start[i]; k < start[i + 1] && !P.p.empty(); ++k) {
        const int j = nbr[k];
        const Vec2 yj = sites.row(j);
        // W_i: <x, y_i> + h_i >= <x, y_j> + h_j, with h_i - h_j = psi_i - psi_j - <y_i - y_j, y_i + y_j> / 2:
        // the difference of the squares as a product keeps its relative precision for
        // sites close together (h_i itself carries the round-off of |y_i|^2).
        const double low = has_lo ? lo[i] - lo[j] : 0.0;
        clip(P, yi - yj, ((psi[i] - psi[j]) + low) - 0.5 * (yi - yj).dot(yi + yj), k, scratch);
      }
      if (late_outline) {
        bool inside = true;
        for (const Vec2& x : P.p) inside = inside && (x - centre).squaredNorm() <= inscribed * inscribed;
        // Each point of P outside the outline is outside the side its angle about the
        // centre falls in, so the sides whose angular spans meet P's suffice (one more at
        // either end against round-off); P spanning 3 radians or more (about the centre)
        // is cut by every side. (Trying all ~240 sides of a 5K image's outline on each
        // cell near it cost a 5K pair 3-5 %.)
        const int sides = static_cast<int>(outline_polygon.line.size());
        int first = 0, count = inside ? 0 : sides;
        if (!inside) {
          const Vec2 u0 = P.p.front() - centre;
          double dmin = 0, dmax = 0;
          for (const Vec2& x : P.p) {
            const Vec2 u = x - centre;
            const double d = std::atan2(cross(u0, u), u0.dot(u));
            dmin = std::min(dmin, d), dmax = std::max(dmax, d);
          }
          if (dmax - dmin < 3) {
            double a = std::atan2(u0.y(), u0.x()) + dmin;
            while (a < corner_angle.front()) a += 2 * std::numbers::pi;
            while (a >= corner_angle.front() + 2 * std::numbers::pi) a -= 2 * std::numbers::pi;
            const int k0 = static_cast<int>(std::upper_bound(corner_angle.begin(), corner_angle.end(), a) -
                                            corner_angle.begin()) - 1;
            const double end = a + (dmax - dmin);
            int k = k0 + 1;
            auto angle = [&](int j) { return corner_angle[j % sides] + (j >= sides ? 2 * std::numbers::pi : 0.0); };
            while (k < k0 + sides && angle(k) < end) ++k;
            first = (k0 - 1 + sides) % sides;
            count = std::min(sides, k - k0 + 2);
          }
        }
        for (int q = 0; q < count && P.p.size() >= 3; ++q) {
          const size_t e = static_cast<size_t>((first + q) % sides);
          const Eigen::Vector3d& ln = outline_polygon.line[e];
          bool cuts = false;
          for (const Vec2& x : P.p) cuts = cuts || ln.head<2>().dot(x) + ln.z() < 0;
          if (cuts) clip(P, ln.head<2>(), ln.z(), -1, scratch);
        }
      }
      if (P.p.size() < 3) continue;
      CellResult cr;
      cr.slot_length = slot_length.data();
      if (domain.is_sphere)
        integrate_sphere(P, yi, cr);
      else if (domain.density)
        integrate_density(P, *domain.density, yi, i, stamp, queue, start_triangle_[i], piece, cr);
      else if (domain.is_disk)
        integrate_disk(P, domain.radius, yi, q, cr);
      else
        integrate_polygon(P, yi, cr);
      if (!(cr.m.area > 0)) continue;
      out.mass[i] = cr.m.area;
      if (domain.is_sphere) {
        const double norm = cr.sphere_first.norm();
        // (A cell that is the whole sphere but for a null set has no direction.)
        const Eigen::Vector3d C = norm > 1e-300 ? Eigen::Vector3d(cr.sphere_first / norm) : to_sphere(yi);
        out.sphere_centroid.row(i) = C.transpose();
        out.centroid.row(i) << C.x() / (1 - C.z()), C.y() / (1 - C.z());
        out.second_moment[i] = 2 * cr.m.area - 2 * cr.sphere_first.dot(to_sphere(yi));
        continue;
      }
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

std::vector<int> PowerDiagrams::locate(const Eigen::VectorXd& h, const Points& queries) const {
  const int n = static_cast<int>(sites_.rows());
  if (h.size() != n) invalid("heights: " + std::to_string(h.size()) + " for " + std::to_string(n) + " sites");
  if (!h.allFinite()) invalid("heights must be finite");
  if (!queries.allFinite()) invalid("query points must be finite");
  RT rt;
  triangulate(sites_, offsets(h), order_, false, rt);
  std::vector<int> out(queries.rows(), -1);
  if (rt.number_of_vertices() == 0) return out;
  // Greedy walk (as CGAL's nearest_power_vertex, but from the previous answer): move to a
  // neighbour of smaller power distance until none is; on a regular triangulation the local
  // minimum is the global one. Exact predicates decide every comparison.
  const auto closer = K().compare_power_distance_2_object();
  RT::Vertex_handle v = rt.finite_vertices_begin();
  for (Eigen::Index q = 0; q < queries.rows(); ++q) {
    const K::Point_2 p(queries(q, 0), queries(q, 1));
    for (bool moved = true; moved;) {
      moved = false;
      RT::Vertex_circulator c = rt.incident_vertices(v), first = c;
      if (c == nullptr) break;
      do {
        if (!rt.is_infinite(c) && closer(p, c->point(), v->point()) == CGAL::SMALLER) {
          v = c;
          moved = true;
          break;
        }
      } while (++c != first);
    }
    out[q] = v->info();
  }
  return out;
}

namespace detail {
namespace {
WP weighted(const double a[3]) { return WP(K::Point_2(a[0], a[1]), a[2]); }
}  // namespace
int power_side(const double p[3], const double q[3], const double r[3], const double t[3]) {
  return static_cast<int>(PowerTest()(weighted(p), weighted(q), weighted(r), weighted(t)));
}
int power_side_exact(const double p[3], const double q[3], const double r[3], const double t[3]) {
  return static_cast<int>(PowerTest::Exact()(weighted(p), weighted(q), weighted(r), weighted(t)));
}
}  // namespace detail

PowerCells power_cells(const Domain& domain, const Points& sites, const Eigen::VectorXd& h, bool check_distinct) {
  return PowerDiagrams(domain, sites, check_distinct)(h);
}

}  // namespace brenier::omt

// The geometry of power cells, apart from the triangulation that says which sites are
// neighbours (regular_triangulation.hpp): convex cells cut out of a starting polygon by
// half-planes (cell_clipping.cpp), and their integrals under each source measure -- the
// uniform disk with exact circular arcs, convex polygons, the sphere's measure on its
// stereographic plane (cell_integrals.cpp), and piecewise-constant densities on triangles
// (density_cells.cpp). Dissertation sec. 3.2.2-3.2.5 and 6.2.2: the cell masses (eq. 3.27)
// and the dual-edge lengths of the Hessian (eq. 3.28). Internal to core/omt.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include "omt/power_diagram.hpp"

namespace brenier::omt::cells {

using Vec2 = Eigen::Vector2d;
inline double cross(const Vec2& a, const Vec2& b) { return a.x() * b.y() - a.y() * b.x(); }

inline constexpr double kSphereFar = 1e9;  // half side of the box the unbounded sphere cells are cut by

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

/// The polygon of the given counter-clockwise corners, every side labelled -1.
LabelledPolygon outline(const std::vector<Vec2>& corners);
// Keeps the part where <x, n> + c >= 0 (Sutherland-Hodgman); the new side is labelled j.
void clip(LabelledPolygon& P, const Vec2& n, double c, int j, LabelledPolygon& out);

struct CellResult {
  Moments m;  // about the site (sphere: m.area only)
  Eigen::Vector3d sphere_first = Eigen::Vector3d::Zero();  // sphere: ∫ X dA
  double* slot_length = nullptr;  // per neighbour slot (the polygon labels): its edge length
};

enum BoundaryKind { kCorner, kEntry, kExit };
using DiskBoundary = std::vector<std::pair<Vec2, BoundaryKind>>;

// Integrates polygon ∩ disk(R) about the local origin c; dual-edge lengths per label. `q`
// is scratch (the boundary of P ∩ D in order: corners inside, entry and exit points).
void integrate_disk(const LabelledPolygon& P, double R, const Vec2& c, DiskBoundary& q, CellResult& out);

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


// The inverse stereographic projection (north pole = infinity).
inline Eigen::Vector3d to_sphere(const Vec2& x) {
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
// vertex's sides found once per cell, costs a third less (bench/RESULTS.md).
void integrate_density(const LabelledPolygon& P, const DensityMesh& dm, const Vec2& c, int cell_id,
                       std::vector<int>& stamp, std::vector<int>& queue, int& start, TrianglePiece& T,
                       CellResult& out);

}  // namespace brenier::omt::cells

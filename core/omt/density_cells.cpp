// Cells under a piecewise-constant density on triangles (the conformal image of a mesh
// with its area ratios): each cell integrated exactly over the triangles it overlaps, and
// the density mesh itself (Domain::piecewise_constant); cell_geometry.hpp.
#include <algorithm>
#include <bit>
#include <cmath>
#include <string>
#include <tuple>

#include "common/check.hpp"
#include "common/error.hpp"
#include "omt/cell_geometry.hpp"

namespace brenier::omt {
namespace cells {
namespace {

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

}  // namespace

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

}  // namespace cells

using cells::cross;
using cells::Vec2;

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

}  // namespace brenier::omt

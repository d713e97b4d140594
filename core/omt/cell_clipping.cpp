// Convex cells cut by half-planes (Sutherland-Hodgman), their sides labelled by the
// neighbour whose bisector made them (cell_geometry.hpp).
#include <algorithm>
#include <cmath>

#include "omt/cell_geometry.hpp"

namespace brenier::omt::cells {
namespace {

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

}  // namespace

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


}  // namespace brenier::omt::cells

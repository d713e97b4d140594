// Cell integrals under the uniform disk (exact circular arcs) and the sphere's measure on
// its stereographic plane (closed forms, or quadrature for small cells); cell_geometry.hpp.
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>

#include "omt/cell_geometry.hpp"

namespace brenier::omt::cells {
namespace {

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

}  // namespace

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




// Gauss-Legendre, 4 points on [0, 1].
constexpr double kGaussX[4] = {0.0694318442029737, 0.3300094782075719, 0.6699905217924281, 0.9305681557970263};
constexpr double kGaussW[4] = {0.1739274225687269, 0.3260725774312731, 0.3260725774312731, 0.1739274225687269};

// The same integrals over a cell that is small beside the scale on which the density
// varies: each fan triangle (site, a, b) by a collapsed 4 x 4 Gauss rule (exact to degree
// 7; the density's relative variation over the cell is below 0.05, so the relative error
// stays ~1e-11), each edge by 4-point Gauss.
namespace {

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

}  // namespace

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


}  // namespace brenier::omt::cells

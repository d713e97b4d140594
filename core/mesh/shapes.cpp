#include "mesh/shapes.hpp"

#include <array>
#include <cmath>
#include <map>
#include <numbers>
#include <vector>

#include "common/check.hpp"

namespace brenier::mesh {
namespace {

TriMesh from_lists(const std::vector<Eigen::Vector3d>& v, const std::vector<std::array<int, 3>>& f) {
  TriMesh m;
  m.V.resize(static_cast<Eigen::Index>(v.size()), 3);
  for (size_t i = 0; i < v.size(); ++i) m.V.row(i) = v[i].transpose();
  m.F.resize(static_cast<Eigen::Index>(f.size()), 3);
  for (size_t i = 0; i < f.size(); ++i) m.F.row(i) << f[i][0], f[i][1], f[i][2];
  return m;
}

// Concentric rings: centre vertex 0, ring k (1..rings) with 6k vertices at radius k/rings
// and angle 2 pi j / (6k). `lift` maps (x, y) in the unit disk to a 3-D point.
template <typename Lift>
TriMesh ring_mesh(int rings, Lift lift) {
  BRENIER_CHECK(rings >= 1, "rings must be >= 1, got " << rings);
  std::vector<Eigen::Vector3d> v;
  std::vector<std::array<int, 3>> f;
  v.push_back(lift(0.0, 0.0));
  std::vector<int> start(rings + 1, 0);
  for (int k = 1; k <= rings; ++k) {
    start[k] = static_cast<int>(v.size());
    for (int j = 0; j < 6 * k; ++j) {
      double a = 2 * std::numbers::pi * j / (6 * k), r = static_cast<double>(k) / rings;
      v.push_back(lift(r * std::cos(a), r * std::sin(a)));
    }
  }
  auto idx = [&](int k, int j) { return k == 0 ? 0 : start[k] + ((j % (6 * k)) + 6 * k) % (6 * k); };
  for (int k = 1; k <= rings; ++k) {
    // Between ring k-1 (6(k-1) vertices) and ring k (6k vertices): six sectors, sector s has
    // k outer and k-1 inner vertices (plus the next sector's first).
    for (int s = 0; s < 6; ++s) {
      for (int t = 0; t < k; ++t) {
        int o0 = idx(k, s * k + t), o1 = idx(k, s * k + t + 1);
        int i0 = idx(k - 1, s * (k - 1) + t);
        f.push_back({o0, o1, i0});
        if (t < k - 1) {
          int i1 = idx(k - 1, s * (k - 1) + t + 1);
          f.push_back({o1, i1, i0});
        }
      }
    }
  }
  return from_lists(v, f);
}

}  // namespace

TriMesh make_grid(int n) {
  BRENIER_CHECK(n >= 2, "grid needs n >= 2, got " << n);
  std::vector<Eigen::Vector3d> v;
  std::vector<std::array<int, 3>> f;
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) v.emplace_back(double(x) / (n - 1), double(y) / (n - 1), 0.0);
  for (int y = 0; y + 1 < n; ++y)
    for (int x = 0; x + 1 < n; ++x) {
      int a = y * n + x, b = a + 1, c = a + n + 1, d = a + n;
      f.push_back({a, b, c});
      f.push_back({a, c, d});
    }
  return from_lists(v, f);
}

TriMesh make_disk(int rings) {
  return ring_mesh(rings, [](double x, double y) { return Eigen::Vector3d(x, y, 0.0); });
}

TriMesh make_hemisphere(int rings) {
  // Ring k at polar angle (pi/2) k / rings: equal spacing in latitude.
  return ring_mesh(rings, [](double x, double y) {
    double r = std::hypot(x, y);
    if (r == 0) return Eigen::Vector3d(0, 0, 1);
    double theta = r * std::numbers::pi / 2;
    return Eigen::Vector3d(std::sin(theta) * x / r, std::sin(theta) * y / r, std::cos(theta));
  });
}

TriMesh make_icosphere(int level) {
  BRENIER_CHECK(level >= 0 && level <= 8, "icosphere level must be in [0, 8], got " << level);
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Eigen::Vector3d> v = {{-1, t, 0}, {1, t, 0},  {-1, -t, 0}, {1, -t, 0},
                                    {0, -1, t}, {0, 1, t},  {0, -1, -t}, {0, 1, -t},
                                    {t, 0, -1}, {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  std::vector<std::array<int, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                       {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                       {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                       {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (auto& p : v) p.normalize();
  for (int l = 0; l < level; ++l) {
    std::map<std::pair<int, int>, int> mid;
    auto midpoint = [&](int a, int b) {
      auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back((v[a] + v[b]).normalized());
      int id = static_cast<int>(v.size()) - 1;
      mid.emplace(key, id);
      return id;
    };
    std::vector<std::array<int, 3>> nf;
    nf.reserve(f.size() * 4);
    for (auto [a, b, c] : f) {
      int ab = midpoint(a, b), bc = midpoint(b, c), ca = midpoint(c, a);
      nf.push_back({a, ab, ca});
      nf.push_back({b, bc, ab});
      nf.push_back({c, ca, bc});
      nf.push_back({ab, bc, ca});
    }
    f = std::move(nf);
  }
  return from_lists(v, f);
}

TriMesh make_torus(int n, int m, double R, double r) {
  BRENIER_CHECK(n >= 3 && m >= 3, "torus needs n, m >= 3");
  std::vector<Eigen::Vector3d> v;
  std::vector<std::array<int, 3>> f;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < m; ++j) {
      double u = 2 * std::numbers::pi * i / n, w = 2 * std::numbers::pi * j / m;
      v.emplace_back((R + r * std::cos(w)) * std::cos(u), (R + r * std::cos(w)) * std::sin(u),
                     r * std::sin(w));
    }
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < m; ++j) {
      int a = i * m + j, b = ((i + 1) % n) * m + j, c = ((i + 1) % n) * m + (j + 1) % m,
          d = i * m + (j + 1) % m;
      f.push_back({a, b, c});
      f.push_back({a, c, d});
    }
  return from_lists(v, f);
}

TriMesh make_cylinder(int around, int rings, double radius, double height, bool cap_bottom) {
  BRENIER_CHECK(around >= 3 && rings >= 2, "cylinder needs around >= 3 and rings >= 2");
  std::vector<Eigen::Vector3d> v;
  std::vector<std::array<int, 3>> f;
  for (int k = 0; k < rings; ++k)
    for (int j = 0; j < around; ++j) {
      double a = 2 * std::numbers::pi * j / around;
      v.emplace_back(radius * std::cos(a), radius * std::sin(a), height * k / (rings - 1));
    }
  for (int k = 0; k + 1 < rings; ++k)
    for (int j = 0; j < around; ++j) {
      int a = k * around + j, b = k * around + (j + 1) % around, c = b + around, d = a + around;
      f.push_back({a, b, c});
      f.push_back({a, c, d});
    }
  if (cap_bottom) {
    v.emplace_back(0, 0, 0);
    int centre = static_cast<int>(v.size()) - 1;
    for (int j = 0; j < around; ++j) f.push_back({centre, (j + 1) % around, j});
  }
  return from_lists(v, f);
}

TriMesh subdivide_midpoint(const TriMesh& m) {
  std::vector<Eigen::Vector3d> v;
  for (int i = 0; i < m.V.rows(); ++i) v.push_back(m.V.row(i).transpose());
  std::map<std::pair<int, int>, int> mid;
  auto midpoint = [&](int a, int b) {
    auto key = std::minmax(a, b);
    auto it = mid.find(key);
    if (it != mid.end()) return it->second;
    v.push_back(0.5 * (v[a] + v[b]));
    int id = static_cast<int>(v.size()) - 1;
    mid.emplace(key, id);
    return id;
  };
  std::vector<std::array<int, 3>> f;
  for (int t = 0; t < m.F.rows(); ++t) {
    int a = m.F(t, 0), b = m.F(t, 1), c = m.F(t, 2);
    int ab = midpoint(a, b), bc = midpoint(b, c), ca = midpoint(c, a);
    f.push_back({a, ab, ca});
    f.push_back({b, bc, ab});
    f.push_back({c, ca, bc});
    f.push_back({ab, bc, ca});
  }
  return from_lists(v, f);
}

}  // namespace brenier::mesh

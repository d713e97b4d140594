// Riemannian optimal mass transport on a surface (geodesic_omt.hpp; dissertation Alg. 4).
#include "omt/geodesic_omt.hpp"

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCore>
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cmath>
#include <limits>
#include <span>
#include <string>

#include "common/error.hpp"
#include "common/parallel.hpp"
#include "mesh/geodesics.hpp"
#include "mesh/geometry.hpp"
#include "mesh/shapes.hpp"
#include "mesh/topology.hpp"
#include "omt/newton_step.hpp"
#include "omt/surface_cells.hpp"

namespace brenier::omt {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// A point of face t in the face's child after subdivide_midpoint, which splits (a, b, c)
// into [a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca] as faces 4t .. 4t + 3.
mesh::SurfacePoint into_child(const mesh::SurfacePoint& p) {
  const double a = p.bary[0], b = p.bary[1], c = p.bary[2];
  mesh::SurfacePoint q;
  if (a >= 0.5) {
    q = {4 * p.face, {2 * a - 1, 2 * b, 2 * c}};
  } else if (b >= 0.5) {
    q = {4 * p.face + 1, {2 * b - 1, 2 * c, 2 * a}};
  } else if (c >= 0.5) {
    q = {4 * p.face + 2, {2 * c - 1, 2 * a, 2 * b}};
  } else {
    q = {4 * p.face + 3, {1 - 2 * c, 1 - 2 * a, 1 - 2 * b}};
  }
  q.bary = q.bary.cwiseMax(0.0);
  q.bary /= q.bary.sum();
  return q;
}

// One site's stored squared distance at a vertex.
// Single precision (1e-7 relative, far below the distances' own error): the lists are the
// solver's largest memory.
struct Near {
  int site;
  float d2;
};

// The pieces one face contributes: its cells' areas (times the face density), costs and the
// sides between them.
struct FacePieces {
  std::vector<std::pair<int, double>> mass;  // site, rho * area
  std::vector<double> cost;                  // rho * int d_site^2
  std::vector<DualEdge> sides;               // i < j, rho * length / |grad(d_i^2 - d_j^2)|
  bool certified = true;
  double envelope = 0;  // an upper bound of the lower envelope on the face (inf: no candidate)
};

struct Cells {
  Eigen::VectorXd mass, cost;
  std::vector<DualEdge> sides;
  std::vector<int> face_cell;
  Eigen::VectorXd face_share;
  bool certified = true;
  double needed = -std::numeric_limits<double>::infinity();  // the highest envelope of an uncertified face
  double needed_diameter = 0;  // the largest uncertified face's diameter
};

// A convex polygon in the face's barycentric chart (s, t): x = a + s (b - a) + t (c - a);
// label[k]: the site whose side the edge from corner k to k + 1 lies on (-1: the face's own
// edge).
struct Polygon {
  std::vector<Eigen::Vector2d> p;
  std::vector<int> label;
};

// Keeps the part of `poly` where the affine g(s, t) = g0 + s (g1 - g0) + t (g2 - g0) <= 0;
// the new edge is labelled `site`.
Polygon clip(const Polygon& poly, const Eigen::Vector3d& g, int site) {
  auto value = [&](const Eigen::Vector2d& q) { return g[0] + q.x() * (g[1] - g[0]) + q.y() * (g[2] - g[0]); };
  Polygon out;
  const size_t n = poly.p.size();
  for (size_t k = 0; k < n; ++k) {
    const Eigen::Vector2d& a = poly.p[k];
    const Eigen::Vector2d& b = poly.p[(k + 1) % n];
    const double ga = value(a), gb = value(b);
    if (ga <= 0) {
      out.p.push_back(a);
      out.label.push_back(poly.label[k]);
    }
    if ((ga <= 0) != (gb <= 0)) {
      const double s = ga / (ga - gb);
      out.p.push_back(a + s * (b - a));
      // Leaving the kept side: the new point starts the cut edge; entering: the old edge.
      out.label.push_back(ga <= 0 ? site : poly.label[k]);
    }
  }
  return out;
}

// One thread's reused buffers for Transport::face: per site, the stamp of the last face whose
// corner 1 (in1) and corners 1 and 2 (in2) keep it, with its squared distances there; the
// face's live sites.
using LiveSites = std::vector<std::pair<int, Eigen::Vector3d>>;  // site, psi = d^2 - h at the corners
struct FaceScratch {
  std::vector<uint64_t> in1, in2;
  std::vector<float> d1, d2;
  uint64_t stamp = 0;
  LiveSites live;
};

class Transport {
 public:
  Transport(const mesh::TriMesh& m, const std::vector<mesh::SurfacePoint>& sites, const Eigen::VectorXd& rho,
            const Eigen::VectorXd& nu, GeodesicMethod method)
      : m_(m), sites_(sites), rho_(rho), nu_(nu), method_(method) {
    const int nf = m.num_faces();
    area_ = mesh::face_areas(m);
    face_diameter_.resize(nf);
    for (int f = 0; f < nf; ++f) {
      face_diameter_[f] = 0;
      for (int k = 0; k < 3; ++k)
        face_diameter_[f] = std::max(face_diameter_[f], (m.V.row(m.F(f, k)) - m.V.row(m.F(f, (k + 1) % 3))).norm());
    }
    // Radii on the grid base * 1.25^level, so that the certificate groups the sites by a
    // few levels: three cell radii (of the larger of the cell's target and the mean) plus
    // two mean face diameters.
    const double mean_rho = rho_.dot(area_) / area_.sum(), slack = 2 * face_diameter_.mean();
    Eigen::VectorXd want(static_cast<Eigen::Index>(sites.size()));
    for (Eigen::Index i = 0; i < want.size(); ++i)
      want[i] = 3 * std::sqrt(std::max(nu_[i], nu_.mean()) / (M_PI * mean_rho)) + slack;
    base_ = want.minCoeff();
    level_.resize(sites.size());
    for (Eigen::Index i = 0; i < want.size(); ++i) level_[static_cast<size_t>(i)] = level_for(want[i]);
    complete_.assign(sites.size(), 0);
    if (method_ == GeodesicMethod::kHeat) heat_ = std::make_unique<mesh::HeatGeodesics>(m_);
  }

  // Alg. 4's geodesics from the sites `which` (all when empty), each kept within a reserve of
  // 2.5 times its radius (a radius that grows within it needs no new geodesics); then the
  // per-vertex lists.
  void compute_distances(std::vector<int> which = {}) {
    ++rounds_;
    const int nv = m_.num_vertices(), ns = static_cast<int>(sites_.size());
    if (which.empty())
      for (int i = 0; i < ns; ++i) which.push_back(i);
    kept_.resize(static_cast<size_t>(ns));
    reserve_.resize(static_cast<size_t>(ns), 0);
    farthest_.resize(static_cast<size_t>(ns), 0);
    constexpr int kBlock = 32;
    Eigen::MatrixXd D;  // one block's distances, its buffer reused
    for (size_t first = 0; first < which.size(); first += kBlock) {
      const int b = static_cast<int>(std::min<size_t>(kBlock, which.size() - first));
      std::vector<mesh::SurfacePoint> from;
      for (int c = 0; c < b; ++c) from.push_back(sites_[static_cast<size_t>(which[first + static_cast<size_t>(c)])]);
      if (heat_) {
        heat_->distances(from, D);
      } else {
        D.resize(nv, b);
#pragma omp parallel for schedule(dynamic, 1)
        for (int c = 0; c < b; ++c) D.col(c) = mesh::exact_distances(m_, from[static_cast<size_t>(c)]);
      }
#pragma omp parallel for schedule(dynamic, 1)
      for (int c = 0; c < b; ++c) {
        const size_t i = static_cast<size_t>(which[first + static_cast<size_t>(c)]);
        reserve_[i] = 2.5 * radius(static_cast<Eigen::Index>(i));
        farthest_[i] = D.col(c).maxCoeff();
        auto& list = kept_[i];
        list.clear();
        list.reserve(static_cast<size_t>((D.col(c).array() <= reserve_[i]).count()));
        for (int v = 0; v < nv; ++v)
          if (D(v, c) <= reserve_[i]) list.push_back({v, static_cast<float>(D(v, c) * D(v, c))});
      }
    }
    index_vertices();
  }

  // The per-vertex lists of the sites within their radii, sorted by site, in one array
  // (vertex v's: near_start_[v] .. near_start_[v + 1]). Blocks of vertices are counted and
  // filled in parallel; a site's kept list is sorted by vertex, so each block reads only its
  // part of it (random sites on a 133K-vertex mesh: 86M entries, 3.6 s in per-vertex vectors).
  void index_vertices() {
    const int ns = static_cast<int>(sites_.size()), nv = m_.num_vertices();
    std::vector<double> R2(static_cast<size_t>(ns));
    for (int i = 0; i < ns; ++i) {
      const double R = radius(i);
      R2[static_cast<size_t>(i)] = R * R;
      complete_[static_cast<size_t>(i)] = farthest_[static_cast<size_t>(i)] <= R;
    }
    const int blocks = std::max(1, std::min(nv, 64));
    // Visits, in site order, every kept entry of vertices [lo, hi) within its site's radius.
    auto for_block = [&](int b, auto&& visit) {
      const int lo = static_cast<int>(static_cast<long>(nv) * b / blocks), hi = static_cast<int>(static_cast<long>(nv) * (b + 1) / blocks);
      for (int i = 0; i < ns; ++i) {
        const auto& list = kept_[static_cast<size_t>(i)];
        auto e = std::lower_bound(list.begin(), list.end(), lo, [](const Kept& k, int v) { return k.vertex < v; });
        for (; e != list.end() && e->vertex < hi; ++e)
          if (e->d2 <= R2[static_cast<size_t>(i)]) visit(i, *e);
      }
    };
    near_start_.assign(static_cast<size_t>(nv) + 1, 0);
#pragma omp parallel for schedule(dynamic, 1)
    for (int b = 0; b < blocks; ++b) for_block(b, [&](int, const Kept& e) { ++near_start_[static_cast<size_t>(e.vertex) + 1]; });
    for (size_t v = 0; v < static_cast<size_t>(nv); ++v) near_start_[v + 1] += near_start_[v];
    near_.resize(near_start_.back());
    std::vector<size_t> at(near_start_.begin(), near_start_.end() - 1);
#pragma omp parallel for schedule(dynamic, 1)
    for (int b = 0; b < blocks; ++b)
      for_block(b, [&](int i, const Kept& e) { near_[at[static_cast<size_t>(e.vertex)]++] = {i, e.d2}; });
  }
  std::span<const Near> near(int v) const {
    return {near_.data() + near_start_[static_cast<size_t>(v)], near_start_[static_cast<size_t>(v) + 1] - near_start_[static_cast<size_t>(v)]};
  }

  // Where the certificate failed at heights h (`needed`: the highest envelope of a face
  // that failed, `diameter`: the largest such face's): the incomplete sites that could reach
  // below it there move up the grid until they cannot, with a margin; those beyond their
  // reserve get new geodesics.
  void grow_radii(const Eigen::VectorXd& h, double needed, double diameter) {
    std::vector<int> grow;
    for (Eigen::Index i = 0; i < h.size() && std::isfinite(needed); ++i) {
      const size_t si = static_cast<size_t>(i);
      if (complete_[si] || std::pow(std::max(0.0, radius(i) - diameter), 2) - h[i] > needed) continue;
      level_[si] = std::max(level_[si] + 1, level_for(1.2 * (std::sqrt(std::max(0.0, needed + h[i])) + diameter)));
      grow.push_back(static_cast<int>(i));
    }
    if (grow.empty())  // faces without candidates (needed is infinite): every incomplete radius grows
      for (Eigen::Index i = 0; i < h.size(); ++i)
        if (!complete_[static_cast<size_t>(i)]) {
          ++level_[static_cast<size_t>(i)];
          grow.push_back(static_cast<int>(i));
        }
    std::vector<int> recompute;
    for (int i : grow)
      if (radius(i) > reserve_[static_cast<size_t>(i)] && farthest_[static_cast<size_t>(i)] > reserve_[static_cast<size_t>(i)])
        recompute.push_back(i);
    ++grown_;
    if (recompute.empty()) {
      index_vertices();
    } else {
      compute_distances(recompute);
    }
  }
  int rounds() const { return rounds_; }
  int grown() const { return grown_; }

  // Radii for a start h0 whose lower envelope is estimated at `envelope`: each site reaches
  // where its power distance could still be below it, with a margin (the estimate is
  // chordal, and geodesics are longer); before compute_distances().
  void plan_radii(const Eigen::VectorXd& h0, double envelope) {
    const double slack = 2 * face_diameter_.mean();
    for (Eigen::Index i = 0; i < h0.size(); ++i) {
      const double want = 1.3 * std::sqrt(std::max(0.0, envelope + h0[i])) + slack;
      level_[static_cast<size_t>(i)] = std::max(level_[static_cast<size_t>(i)], level_for(want));
    }
  }

  Cells cells(const Eigen::VectorXd& h) const {
    const int nf = m_.num_faces(), ns = static_cast<int>(sites_.size());
    // The certificate: a site j missing at a corner of face T is at least R_j - diam T from
    // every point of T, so its power distance there is at least (R_j - diam T)^2 - h_j; per
    // radius level, the highest height of its incomplete sites.
    std::vector<std::pair<double, double>> levels;  // radius, highest height
    {
      std::vector<double> top;
      for (int j = 0; j < ns; ++j) {
        if (complete_[static_cast<size_t>(j)]) continue;
        const size_t l = static_cast<size_t>(level_[static_cast<size_t>(j)]);
        if (top.size() <= l) top.resize(l + 1, -std::numeric_limits<double>::infinity());
        top[l] = std::max(top[l], h[j]);
      }
      for (size_t l = 0; l < top.size(); ++l)
        if (top[l] > -std::numeric_limits<double>::infinity()) levels.emplace_back(radius_at(static_cast<int>(l)), top[l]);
    }
    auto bound = [&levels](double diameter) {
      double b = std::numeric_limits<double>::infinity();
      for (const auto& [R, top] : levels) b = std::min(b, std::pow(std::max(0.0, R - diameter), 2) - top);
      return b;
    };
    const LowLists low = low_lists(h);
    std::vector<FacePieces> pieces(static_cast<size_t>(nf));
#pragma omp parallel for schedule(dynamic, 512)
    for (int f = 0; f < nf; ++f) pieces[static_cast<size_t>(f)] = face(f, h, bound(face_diameter_[f]), low);
    Cells out;
    out.mass = Eigen::VectorXd::Zero(ns);
    out.cost = Eigen::VectorXd::Zero(ns);
    out.face_cell.assign(static_cast<size_t>(nf), -1);
    out.face_share = Eigen::VectorXd::Zero(nf);
    for (int f = 0; f < nf; ++f) {  // sums in face order: the same on any thread count
      const FacePieces& p = pieces[static_cast<size_t>(f)];
      out.certified = out.certified && p.certified;
      if (!p.certified) {
        out.needed = std::max(out.needed, p.envelope);
        out.needed_diameter = std::max(out.needed_diameter, face_diameter_[f]);
      }
      double total = 0, best = -1;
      for (size_t k = 0; k < p.mass.size(); ++k) {
        out.mass[p.mass[k].first] += p.mass[k].second;
        out.cost[p.mass[k].first] += p.cost[k];
        total += p.mass[k].second;
        if (p.mass[k].second > best) {
          best = p.mass[k].second;
          out.face_cell[static_cast<size_t>(f)] = p.mass[k].first;
        }
      }
      out.face_share[f] = total > 0 ? best / total : 0;
      out.sides.insert(out.sides.end(), p.sides.begin(), p.sides.end());
    }
    return out;
  }

 private:
  // Per vertex, the sites that can matter on its faces at heights h: those whose power
  // distance psi = d^2 - h there is at most t_v, the highest over v's faces T of an upper
  // bound U_T of T's lower envelope (the lowest highest corner among the corners' own nearest
  // sites that are kept at all three corners). Every face's envelope site has all three
  // corners at most E_T <= U_T, and every live site one corner, so face() finds both among
  // its corners' short lists; a vertex whose list would pass kLow sites, or next to a face
  // without a bound, is marked full and its faces scan the whole lists.
  struct LowLists {
    std::vector<Near> entry;      // kLow per vertex, sorted by site
    std::vector<uint8_t> count;   // per vertex; kFull: use the whole list
  };
  static constexpr int kLow = 24;
  static constexpr uint8_t kFull = 255;

  LowLists low_lists(const Eigen::VectorXd& h) const {
    const int nv = m_.num_vertices(), nf = m_.num_faces();
    auto psi = [&h](const Near& n) { return static_cast<double>(n.d2) - h[n.site]; };
    std::vector<int> owner(static_cast<size_t>(nv), -1);
#pragma omp parallel for schedule(static)
    for (int v = 0; v < nv; ++v) {
      double best = std::numeric_limits<double>::infinity();
      for (const Near& n : near(v))
        if (psi(n) < best) {
          best = psi(n);
          owner[static_cast<size_t>(v)] = n.site;
        }
    }
    std::vector<double> upper(static_cast<size_t>(nf));
#pragma omp parallel for schedule(static)
    for (int f = 0; f < nf; ++f) {
      double U = std::numeric_limits<double>::infinity();
      for (int k = 0; k < 3; ++k) {
        const int s = owner[static_cast<size_t>(m_.F(f, k))];
        double top = -std::numeric_limits<double>::infinity();
        for (int j = 0; j < 3 && s >= 0; ++j) {
          const Near* n = find(m_.F(f, j), s);
          top = n ? std::max(top, psi(*n)) : std::numeric_limits<double>::infinity();
        }
        if (s >= 0) U = std::min(U, top);
      }
      upper[static_cast<size_t>(f)] = U;
    }
    std::vector<double> t(static_cast<size_t>(nv), -std::numeric_limits<double>::infinity());
    for (int f = 0; f < nf; ++f)
      for (int k = 0; k < 3; ++k) t[static_cast<size_t>(m_.F(f, k))] = std::max(t[static_cast<size_t>(m_.F(f, k))], upper[static_cast<size_t>(f)]);
    LowLists low;
    low.entry.resize(static_cast<size_t>(nv) * kLow);
    low.count.assign(static_cast<size_t>(nv), kFull);
#pragma omp parallel for schedule(static)
    for (int v = 0; v < nv; ++v) {
      const double tv = t[static_cast<size_t>(v)];
      if (!std::isfinite(tv)) continue;
      int c = 0;
      for (const Near& n : near(v))
        if (psi(n) <= tv) {
          if (c == kLow) {
            c = kFull;
            break;
          }
          low.entry[static_cast<size_t>(v) * kLow + static_cast<size_t>(c++)] = n;
        }
      low.count[static_cast<size_t>(v)] = static_cast<uint8_t>(c);
    }
    return low;
  }

  // Site s's entry in vertex v's list, or null.
  const Near* find(int v, int s) const {
    const std::span<const Near> l = near(v);
    auto it = std::lower_bound(l.begin(), l.end(), s, [](const Near& n, int site) { return n.site < site; });
    return it != l.end() && it->site == s ? &*it : nullptr;
  }

  // The face's candidates offered in site order, each with psi at the three corners: the
  // envelope E is the lowest highest corner among them, and the live sites those whose lowest
  // corner is at most E. E only falls along the pass, so a live site is at most E where it
  // is offered: each is kept then, and the ones above the final E are dropped at the end.
  struct LowerEnvelope {
    LiveSites& live;
    double value = std::numeric_limits<double>::infinity();
    explicit LowerEnvelope(LiveSites& out) : live(out) { live.clear(); }
    void offer(int site, const Eigen::Vector3d& psi) {
      value = std::min(value, psi.maxCoeff());
      if (psi.minCoeff() <= value) live.emplace_back(site, psi);
    }
    double finish() {
      const double e = value;
      live.erase(std::remove_if(live.begin(), live.end(), [e](const auto& c) { return c.second.minCoeff() > e; }),
                 live.end());
      return e;
    }
  };

  // The face's live sites (those whose lowest corner is at most the envelope), in site order,
  // with psi at the corners, and the envelope E (the lowest highest corner among the sites kept
  // at all three corners, the candidates; sites above it nowhere win): from the corners' short
  // lists (LowerEnvelope). False where a corner's list is full.
  bool live_from_short_lists(const int corner[3], const Eigen::VectorXd& h, const LowLists& low,
                             LiveSites& live, double& envelope) const {
    const Near* list[3];
    int size[3], at[3] = {0, 0, 0};
    for (int k = 0; k < 3; ++k) {
      size[k] = low.count[static_cast<size_t>(corner[k])];
      if (size[k] == kFull) return false;
      list[k] = low.entry.data() + static_cast<size_t>(corner[k]) * kLow;
    }
    LowerEnvelope env(live);
    for (;;) {
      int s = std::numeric_limits<int>::max();
      for (int k = 0; k < 3; ++k)
        if (at[k] < size[k]) s = std::min(s, list[k][at[k]].site);
      if (s == std::numeric_limits<int>::max()) break;
      Eigen::Vector3d d;
      bool candidate = true;
      for (int k = 0; k < 3; ++k) {
        if (at[k] < size[k] && list[k][at[k]].site == s) {
          d[k] = list[k][at[k]++].d2;
        } else if (const Near* n = candidate ? find(corner[k], s) : nullptr) {
          d[k] = n->d2;
        } else {
          candidate = false;
        }
      }
      if (candidate) env.offer(s, d.array() - h[s]);
    }
    envelope = env.finish();
    return std::isfinite(envelope);
  }

  // The same from the whole lists. Candidates: sites kept at all three corners, in site order
  // (that of corner 0's list); corner 1's and 2's lists are marked in the thread's per-site
  // scratch (random sites on a 133K-vertex mesh keep ~650 sites per vertex; a merge of the
  // sorted lists took 2-3 times as long). False: no candidate.
  bool live_from_whole_lists(const int corner[3], const Eigen::VectorXd& h, FaceScratch& S, double& envelope) const {
    const size_t ns = sites_.size();
    if (S.in1.size() < ns) {
      S.in1.assign(ns, 0);
      S.in2.assign(ns, 0);
      S.d1.resize(ns);
      S.d2.resize(ns);
    }
    const uint64_t stamp = ++S.stamp;
    for (const Near& n : near(corner[1])) {
      S.in1[static_cast<size_t>(n.site)] = stamp;
      S.d1[static_cast<size_t>(n.site)] = n.d2;
    }
    for (const Near& n : near(corner[2]))
      if (S.in1[static_cast<size_t>(n.site)] == stamp) {
        S.in2[static_cast<size_t>(n.site)] = stamp;
        S.d2[static_cast<size_t>(n.site)] = n.d2;
      }
    LowerEnvelope env(S.live);
    bool any = false;
    for (const Near& n : near(corner[0])) {
      const size_t s = static_cast<size_t>(n.site);
      if (S.in2[s] != stamp) continue;
      any = true;
      env.offer(n.site, Eigen::Vector3d(n.d2, S.d1[s], S.d2[s]).array() - h[n.site]);
    }
    envelope = env.finish();
    return any;
  }

  // The cells' pieces on face f at heights h.
  FacePieces face(int f, const Eigen::VectorXd& h, double bound, const LowLists& low) const {
    FacePieces out;
    const int corner[3] = {m_.F(f, 0), m_.F(f, 1), m_.F(f, 2)};
    static thread_local FaceScratch S;
    double envelope = std::numeric_limits<double>::infinity();
    const bool any = live_from_short_lists(corner, h, low, S.live, envelope) || live_from_whole_lists(corner, h, S, envelope);
    const auto& live = S.live;  // site, psi = d^2 - h at the corners
    out.certified = any && envelope < bound;
    out.envelope = envelope;
    const double rho = rho_[f], A = area_[f];
    const Eigen::Vector3d a = m_.V.row(corner[0]).transpose(), b = m_.V.row(corner[1]).transpose(),
                          c = m_.V.row(corner[2]).transpose();
    auto point = [&](const Eigen::Vector2d& q) -> Eigen::Vector3d { return a + q.x() * (b - a) + q.y() * (c - a); };
    auto linear = [](const Eigen::Vector3d& v, const Eigen::Vector2d& q) { return v[0] + q.x() * (v[1] - v[0]) + q.y() * (v[2] - v[0]); };
    const Eigen::Vector3d n = (b - a).cross(c - a).normalized();
    const Eigen::Vector3d grad_lambda[3] = {n.cross(c - b) / (2 * A), n.cross(a - c) / (2 * A), n.cross(b - a) / (2 * A)};
    for (size_t i = 0; i < live.size(); ++i) {
      Polygon poly{{{0, 0}, {1, 0}, {0, 1}}, {-1, -1, -1}};
      for (size_t j = 0; j < live.size() && poly.p.size() >= 3; ++j)
        if (j != i) poly = clip(poly, live[i].second - live[j].second, static_cast<int>(j));
      if (poly.p.size() < 3) continue;
      double twice = 0;  // twice the chart area
      Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
      for (size_t k = 0; k < poly.p.size(); ++k) {
        const Eigen::Vector2d& p = poly.p[k];
        const Eigen::Vector2d& q = poly.p[(k + 1) % poly.p.size()];
        const double cr = p.x() * q.y() - p.y() * q.x();
        twice += cr;
        centroid += cr * (p + q);
      }
      if (!(twice > 0)) continue;
      centroid /= 3 * twice;
      const double piece = rho * A * twice;  // the chart's triangle has area 1/2
      const int site = live[i].first;
      out.mass.emplace_back(site, piece);
      // d_i^2 is linear on the face, so its mean over the piece is its value at the centroid.
      out.cost.push_back(piece * linear(live[i].second + Eigen::Vector3d::Constant(h[site]), centroid));
      for (size_t k = 0; k < poly.p.size(); ++k) {
        const int j = poly.label[k];
        if (j < 0 || live[static_cast<size_t>(j)].first < site) continue;  // each side once, from its lower site
        const Eigen::Vector3d g = live[i].second - live[static_cast<size_t>(j)].second;
        const Eigen::Vector3d grad = g[0] * grad_lambda[0] + g[1] * grad_lambda[1] + g[2] * grad_lambda[2];
        const double len = (point(poly.p[(k + 1) % poly.p.size()]) - point(poly.p[k])).norm();
        if (grad.norm() > 0 && len > 0) out.sides.push_back({site, live[static_cast<size_t>(j)].first, rho * len / grad.norm()});
      }
    }
    return out;
  }

  const mesh::TriMesh& m_;
  const std::vector<mesh::SurfacePoint>& sites_;
  const Eigen::VectorXd& rho_;  // per face
  const Eigen::VectorXd& nu_;
  GeodesicMethod method_;
  double radius_at(int level) const { return base_ * std::pow(1.25, level); }
  double radius(Eigen::Index i) const { return radius_at(level_[static_cast<size_t>(i)]); }
  int level_for(double r) const { return std::max(0, static_cast<int>(std::ceil(std::log(r / base_) / std::log(1.25) - 1e-9))); }

  Eigen::VectorXd area_, face_diameter_;  // per face; a face's diameter is its longest edge
  double base_ = 0;                       // the radii's grid: base * 1.25^level
  std::vector<int> level_;                // per site
  std::vector<char> complete_;  // site i's distances are kept everywhere
  std::vector<Near> near_;  // per vertex, sorted by site
  std::vector<size_t> near_start_;  // vertex v's part of near_ starts at near_start_[v]
  struct Kept {
    int vertex;
    float d2;  // single precision: 1e-7 relative, below the distances' own error
  };
  std::vector<std::vector<Kept>> kept_;  // per site: within its reserve
  std::vector<double> reserve_, farthest_;  // per site: the reserve's radius, the farthest vertex's distance
  int grown_ = 0;
  std::unique_ptr<mesh::HeatGeodesics> heat_;
  int rounds_ = 0;
};

// The working mesh and its per-face density: the input midpoint-subdivided `levels` times,
// the density interpolated linearly at the new vertices and averaged on each face.
void subdivide(const mesh::TriMesh& in, const Eigen::VectorXd& vertex_density, int levels, mesh::TriMesh& out,
               Eigen::VectorXd& face_density) {
  out = in;
  mesh::TriMesh carried = in;  // the density rides along as a coordinate
  carried.V.setZero();
  carried.V.col(0) = vertex_density;
  for (int l = 0; l < levels; ++l) {
    out = mesh::subdivide_midpoint(out);
    carried = mesh::subdivide_midpoint(carried);
  }
  face_density.resize(out.num_faces());
  for (int f = 0; f < out.num_faces(); ++f)
    face_density[f] = (carried.V(out.F(f, 0), 0) + carried.V(out.F(f, 1), 0) + carried.V(out.F(f, 2), 0)) / 3;
}

void check_input(const mesh::TriMesh& m, const std::vector<mesh::SurfacePoint>& sites, const Eigen::VectorXd& masses,
                 const Eigen::VectorXd& density) {
  const int k = static_cast<int>(sites.size());
  if (k < 1) invalid("Riemannian OMT: no sites");
  if (masses.size() != 0 && masses.size() != k)
    invalid("Riemannian OMT: " + std::to_string(masses.size()) + " masses for " + std::to_string(k) + " sites");
  if (masses.size() != 0 && (!(masses.array() > 0).all() || !masses.allFinite() || !std::isfinite(masses.sum())))
    invalid("Riemannian OMT: the masses must be positive finite numbers with a finite sum");
  if (density.size() != 0 && density.size() != m.num_vertices())
    invalid("Riemannian OMT: " + std::to_string(density.size()) + " density values for " +
            std::to_string(m.num_vertices()) + " vertices");
  if (density.size() != 0 && (!(density.array() >= 0).all() || !density.allFinite() || !(density.maxCoeff() > 0)))
    invalid("Riemannian OMT: the density must be non-negative, finite and not all zero");
  if (mesh::compute_topology(m).components != 1) invalid("Riemannian OMT: the mesh is not connected");
  for (int i = 0; i < k; ++i) {
    const auto& p = sites[static_cast<size_t>(i)];
    if (p.face < 0 || p.face >= m.num_faces() || !p.bary.allFinite() || (p.bary.array() < -1e-12).any() ||
        std::abs(p.bary.sum() - 1) > 1e-9)
      invalid("Riemannian OMT: site " + std::to_string(i) + " is not a point of the mesh");
  }
}


// A start for the heights: the transport of the same measure to the same sites with the
// squared Euclidean (chordal) cost restricted to the surface (surface_cells.hpp, solved to 5 %
// per cell), whose cells are close to the geodesic ones where the cells are small against the
// surface's curvature: its power weights |y_i|^2 + 2 h_i are the geodesic heights' start.
// Also the start's lower envelope max_x min_i (|x - y_i|^2 - h0_i) over the vertices, which
// sizes the distance radii. False when the chordal solve fails (then the start is 0).
bool chordal_start(const mesh::TriMesh& m, const Eigen::VectorXd& rho, const mesh::Vertices& y, const Eigen::VectorXd& nu,
                   Eigen::VectorXd& h0, double& envelope) {
  SurfaceDensity S;
  S.vertices = m.V;
  S.faces = m.F;
  S.density = rho;
  OmtOptions o;
  o.tolerance = 0.05;
  o.max_iterations = 30;
  o.initial_h = -0.5 * y.rowwise().squaredNorm();  // the Voronoi diagram of the sites (h = 0 is, only on a sphere)
  try {
    const SurfaceOmtResult c = solve_surface_omt(S, y, nu, o);
    if (c.cells.empty_cells > 0) return false;
    h0 = y.rowwise().squaredNorm() + 2 * c.h;
  } catch (const Error&) {
    return false;
  }
  h0.array() -= h0.mean();
  envelope = -std::numeric_limits<double>::infinity();
#pragma omp parallel for reduction(max : envelope)
  for (Eigen::Index v = 0; v < m.V.rows(); ++v)
    envelope = std::max(envelope, ((y.rowwise() - m.V.row(v)).rowwise().squaredNorm() - h0).minCoeff());
  return true;
}


// The problem on the working mesh: the subdivisions (opt's, or the fewest that give
// faces_per_cell faces per site), the mesh and its per-face density, the sites on it and
// their positions, and the targets scaled to the source's mass. Refuses two sites at one point.
mesh::Vertices prepare(const mesh::TriMesh& input, const std::vector<mesh::SurfacePoint>& input_sites,
                       const Eigen::VectorXd& masses, const Eigen::VectorXd& vertex_density,
                       const GeodesicOmtOptions& opt, GeodesicOmtResult& r, Eigen::VectorXd& rho) {
  const int k = static_cast<int>(input_sites.size());
  r.subdivisions = opt.subdivisions;
  if (r.subdivisions < 0) {
    r.subdivisions = 0;
    for (long faces = input.num_faces(); r.subdivisions < 4 && faces < static_cast<long>(opt.faces_per_cell) * k &&
                                         faces * 4 <= 4'000'000;
         faces *= 4)
      ++r.subdivisions;
  }
  if (r.subdivisions > 6 || static_cast<double>(input.num_faces()) * std::pow(4.0, r.subdivisions) > 16e6)
    invalid("Riemannian OMT: " + std::to_string(r.subdivisions) + " subdivisions of " + std::to_string(input.num_faces()) +
            " faces: at most 6 subdivisions and 16M faces");
  subdivide(input, vertex_density.size() ? vertex_density : Eigen::VectorXd::Ones(input.num_vertices()),
            r.subdivisions, r.mesh, rho);
  r.sites = input_sites;
  for (int l = 0; l < r.subdivisions; ++l)
    for (auto& p : r.sites) p = into_child(p);
  mesh::Vertices at(k, 3);
  for (int i = 0; i < k; ++i) {
    const auto& p = r.sites[static_cast<size_t>(i)];
    at.row(i).setZero();
    for (int c = 0; c < 3; ++c) at.row(i) += p.bary[c] * r.mesh.V.row(r.mesh.F(p.face, c));
  }
  // Two sites in one point: their cells could not be told apart. Sorted by x, each site is
  // compared with those within the resolution in x only.
  const Eigen::VectorXd area = mesh::face_areas(r.mesh);
  const double mu = rho.dot(area), resolution = 1e-9 * std::sqrt(area.sum());
  if (!std::isfinite(mu)) invalid("Riemannian OMT: the source density's total mass is not finite");
  std::vector<int> order(static_cast<size_t>(k));
  for (int i = 0; i < k; ++i) order[static_cast<size_t>(i)] = i;
  std::sort(order.begin(), order.end(), [&](int a, int b) { return at(a, 0) < at(b, 0); });
  for (size_t x = 0; x < order.size(); ++x)
    for (size_t y = x + 1; y < order.size() && at(order[y], 0) - at(order[x], 0) <= resolution; ++y)
      if ((at.row(order[x]) - at.row(order[y])).norm() <= resolution)
        invalid("Riemannian OMT: sites " + std::to_string(std::min(order[x], order[y])) + " and " +
                std::to_string(std::max(order[x], order[y])) + " are at one point");
  r.target = masses.size() ? Eigen::VectorXd(masses * (mu / masses.sum())) : Eigen::VectorXd::Constant(k, mu / k);
  return at;
}

}  // namespace

GeodesicOmtResult solve_geodesic_omt(const mesh::TriMesh& input, const std::vector<mesh::SurfacePoint>& input_sites,
                                     const Eigen::VectorXd& masses, const Eigen::VectorXd& vertex_density,
                                     const GeodesicOmtOptions& opt) {
  check_input(input, input_sites, masses, vertex_density);
  if (!(opt.tolerance > 0)) invalid("Riemannian OMT: the tolerance must be positive");
  const int k = static_cast<int>(input_sites.size());
  GeodesicOmtResult r;
  Eigen::VectorXd rho;
  const mesh::Vertices at = prepare(input, input_sites, masses, vertex_density, opt, r, rho);
  const Eigen::VectorXd& nu = r.target;

  auto t0 = std::chrono::steady_clock::now();
  Transport T(r.mesh, r.sites, rho, nu, opt.geodesics);
  Eigen::VectorXd h = Eigen::VectorXd::Zero(k);
  double envelope = 0;
  if (k > 1 && chordal_start(r.mesh, rho, at, nu, h, envelope)) {
    r.chordal_start = true;
    T.plan_radii(h, envelope);
  }
  T.compute_distances();
  r.seconds_geodesics = seconds_since(t0);
  // The cells at h, the distances recomputed with larger radii until certified.
  auto cells_at = [&](const Eigen::VectorXd& h) {
    Cells c = T.cells(h);
    while (!c.certified && T.grown() < 12) {
      const auto t1 = std::chrono::steady_clock::now();
        T.grow_radii(h, c.needed, c.needed_diameter);
      r.seconds_geodesics += seconds_since(t1);
      c = T.cells(h);
    }
    if (!c.certified) fail(ErrorCode::kNotConverged, "Riemannian OMT: the cells stay uncertified after 12 rounds of geodesics");
    return c;
  };
  const auto t2 = std::chrono::steady_clock::now();
  Cells cells = cells_at(h);
  // Where the chordal start leaves a geodesic cell empty, it is scaled toward the Voronoi
  // diagram (h = 0) until none is.
  for (int halving = 0; r.chordal_start && cells.mass.minCoeff() <= 0; ++halving) {
    h *= halving < 3 ? 0.5 : 0.0;
    r.chordal_start = halving < 3;
    cells = cells_at(h);
  }
  auto max_relative = [&](const Eigen::VectorXd& m) { return ((m - nu).array().abs() / nu.array()).maxCoeff(); };
  auto relative_norm = [&](const Eigen::VectorXd& g) { return (g.array() / nu.array()).matrix().norm(); };
  r.max_relative_error = max_relative(cells.mass);
  // Kitagawa-Merigot-Thibert damping: every cell keeps at least eps0.
  const double eps0 = 0.5 * std::min(nu.minCoeff(), cells.mass.minCoeff());
  if (!(eps0 > 0)) {
    Eigen::Index empty = 0;
    cells.mass.minCoeff(&empty);
    invalid("Riemannian OMT: site " + std::to_string(empty) +
            " has an empty geodesic Voronoi cell (sites closer than the mesh resolves: subdivide more)");
  }
  Eigen::Index held = 0;
  nu.maxCoeff(&held);  // F(h + constant) = F(h): one height is held
  single_threaded_blas();
  detail::NewtonFactor llt;
  llt.setMode(Eigen::CholmodSimplicialLLt);
  llt.cholmod().print = 0;
  double last_t = 1;
  for (r.iterations = 0; k > 1 && r.iterations < opt.max_iterations && r.max_relative_error > opt.tolerance; ++r.iterations) {
    const Eigen::VectorXd g = cells.mass - nu;
    const std::optional<Eigen::VectorXd> step = detail::newton_direction(cells.sides, g, held, llt);
    if (!step)
      fail(ErrorCode::kNotConverged, "Riemannian OMT: the Hessian is singular at iteration " + std::to_string(r.iterations));
    const Eigen::VectorXd& dh = *step;
    const double gnorm = relative_norm(g);
    bool accepted = false;
    for (double t = std::min(1.0, 4 * last_t); t > 1e-9 && !accepted; t *= 0.5) {
      const Eigen::VectorXd trial = h + t * dh;
      Cells c = cells_at(trial);
      if (c.mass.minCoeff() < eps0) continue;
      if (relative_norm(c.mass - nu) <= (1 - 0.5 * t) * gnorm || max_relative(c.mass) <= opt.tolerance) {
        h = trial;
        cells = std::move(c);
        accepted = true;
        last_t = t;
      }
    }
    r.max_relative_error = max_relative(cells.mass);
    if (opt.progress && !opt.progress(r.iterations + 1, r.max_relative_error))
      fail(ErrorCode::kCancelled, "Riemannian OMT cancelled");
    if (!accepted) {
      ++r.iterations;
      break;  // the round-off floor: no step improves any more
    }
  }
  r.seconds_transport = seconds_since(t2);
  r.converged = r.max_relative_error <= opt.tolerance;
  r.h = h.array() - h.mean();
  r.mass = cells.mass;
  r.cost = cells.cost;
  r.transport_cost = cells.cost.sum();
  r.face_cell = std::move(cells.face_cell);
  r.face_share = std::move(cells.face_share);
  r.distance_rounds = T.rounds();
  return r;
}

}  // namespace brenier::omt

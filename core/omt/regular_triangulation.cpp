#include "omt/regular_triangulation.hpp"

#include <algorithm>
#include <utility>

#include "common/check.hpp"

namespace brenier::omt {
namespace regular {
namespace {

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

}  // namespace

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

Reweighted reweight_by_flips(RT& rt, std::vector<RT::Face_handle>& faces, const Points& sites,
                             const Eigen::VectorXd& old_psi, const Eigen::VectorXd& psi,
                             bool stop_if_hidden) {
  const int n = static_cast<int>(sites.rows());
  if (rt.dimension() != 2) return Reweighted::kStuck;
  // In the vertices' memory order (the offsets are the smaller array to read at random).
  auto set_weights = [&](const Eigen::VectorXd& offsets) {
    for (auto v = rt.finite_vertices_begin(); v != rt.finite_vertices_end(); ++v)
      v->point() = WP(v->point().point(), 2 * offsets[v->info()]);
  };
  set_weights(psi);
  const PowerTest power;
  const auto orientation = Traits().orientation_2_object();
  using Edge = std::pair<RT::Vertex_handle, RT::Vertex_handle>;
  // Whether edge (f, i) -- the edge as face and opposite index -- lies between two finite
  // faces with the vertex across from f strictly inside f's power circle.
  auto irregular_at = [&](RT::Face_handle f, int i) {
    const RT::Face_handle g = f->neighbor(i);
    if (rt.is_infinite(f) || rt.is_infinite(g)) return false;  // a hull edge stays
    return power(f->vertex(0)->point(), f->vertex(1)->point(), f->vertex(2)->point(),
                 g->vertex(rt.mirror_index(f, i))->point()) == CGAL::ON_POSITIVE_SIDE;
  };
  // Whether edge e is still there, and irregular (f, i: where it is).
  auto violates = [&](const Edge& e, RT::Face_handle& f, int& i) {
    return rt.is_edge(e.first, e.second, f, i) && irregular_at(f, i);
  };
  // The first pass reads each interior edge once from the faces (no edge lookup), on every
  // core, and queues only those the new weights made irregular, in the faces' order. An
  // edge's regularity depends on its two faces alone, and a flip queues the four edges whose
  // faces it changed, so no other edge can turn irregular later without being queued.
  if (faces.empty()) {
    faces.reserve(rt.number_of_faces());
    for (auto f = rt.finite_faces_begin(); f != rt.finite_faces_end(); ++f) faces.push_back(f);
  }
  const long nf = static_cast<long>(faces.size());
  std::vector<char> irregular(3 * faces.size(), 0);
#pragma omp parallel for schedule(static)
  for (long k = 0; k < nf; ++k) {
    const RT::Face_handle f = faces[k];
    // Each edge from one side: the face along whose counter-clockwise order its endpoints'
    // site numbers rise (not the faces' addresses, which differ between processes: the
    // queue's order, and so the flips', is the same in brenierd as in brenier-compute).
    for (int i = 0; i < 3; ++i)
      if (f->vertex(RT::ccw(i))->info() < f->vertex(RT::cw(i))->info()) irregular[3 * k + i] = irregular_at(f, i);
  }
  std::vector<Edge> queue, stuck, flipped;
  for (long k = 0; k < nf; ++k)
    for (int i = 0; i < 3; ++i)
      if (irregular[3 * k + i]) queue.emplace_back(faces[k]->vertex(RT::cw(i)), faces[k]->vertex(RT::ccw(i)));
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

}  // namespace regular

namespace detail {
using regular::K;
using regular::PowerTest;
using regular::WP;
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


}  // namespace brenier::omt

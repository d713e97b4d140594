#include "omt/surface_cells.hpp"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Regular_triangulation_3.h>
#include <CGAL/Regular_triangulation_cell_base_3.h>
#include <CGAL/Regular_triangulation_vertex_base_3.h>
#include <CGAL/Triangulation_vertex_base_with_info_3.h>

#include <Eigen/CholmodSupport>
#include <Eigen/Geometry>
#include <Eigen/SparseCore>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>
#include <omp.h>
#include <optional>
#include <string>
#include <utility>

#include "common/error.hpp"
#include "common/parallel.hpp"
#include "omt/coarse_to_fine.hpp"
#include "omt/newton_step.hpp"

namespace brenier::omt {

namespace {

using K = CGAL::Exact_predicates_inexact_constructions_kernel;
using Vb = CGAL::Triangulation_vertex_base_with_info_3<int, K, CGAL::Regular_triangulation_vertex_base_3<K>>;
// Hidden points are not kept in the cells (CGAL's default keeps a list per cell): only the
// triangulation's edges and vertices are read.
using Cb = CGAL::Regular_triangulation_cell_base_3<K, CGAL::Triangulation_cell_base_3<K>, CGAL::Discard_hidden_points>;
using RT3 = CGAL::Regular_triangulation_3<K, CGAL::Triangulation_data_structure_3<Vb, Cb>>;
using Vec3 = Eigen::Vector3d;

// A convex polygon of a triangle's plane; label[k]: the neighbour slot of side k -> k + 1
// (-1: a side of the triangle).
struct Piece {
  std::vector<Vec3> p, p_next;
  std::vector<int> label, label_next;
  std::vector<double> f;
  // Keeps <x, d> + c >= 0 (Sutherland-Hodgman); the new side is labelled j.
  void cut(const Vec3& d, double c, int j) {
    const size_t m = p.size();
    f.resize(m);
    bool whole = true;
    for (size_t k = 0; k < m; ++k) {
      f[k] = p[k].dot(d) + c;
      whole = whole && !(f[k] < 0);
    }
    if (whole) return;
    p_next.clear();
    label_next.clear();
    for (size_t k = 0; k < m; ++k) {
      const size_t k1 = k + 1 == m ? 0 : k + 1;
      if (f[k] >= 0) {
        p_next.push_back(p[k]);
        label_next.push_back(label[k]);
        if (f[k1] < 0) {
          p_next.push_back(p[k] + (f[k] / (f[k] - f[k1])) * (p[k1] - p[k]));
          label_next.push_back(j);
        }
      } else if (f[k1] >= 0) {
        p_next.push_back(p[k] + (f[k] / (f[k] - f[k1])) * (p[k1] - p[k]));
        label_next.push_back(label[k]);
      }
    }
    p.swap(p_next);
    label.swap(label_next);
  }
};

// What one triangle gives one cell: its piece's integrals and, per side on a neighbour's
// plane, the side's Hessian weight.
struct Contribution {
  int cell;
  double mass, second;
  Vec3 first;
  int slots_begin, slots_end;  // into the thread's slot list
};

// One thread's pieces, triangle after triangle: a list per thread, not two per triangle
// (malloc and free held about a tenth of perf's samples on armadillo's sphere pair).
struct ThreadPieces {
  std::vector<Contribution> parts;
  std::vector<std::pair<int, double>> slots;  // (CSR slot of the cell's neighbour, weight)
};

// Where triangle f's pieces are: thread `thread`'s parts [begin, end).
struct PieceRange {
  int thread = 0, begin = 0, end = 0;
};

}  // namespace

void SurfaceDensity::check() const {
  const long nv = vertices.rows(), nf = faces.rows();
  if (nf == 0) invalid("the surface has no triangles");
  if (density.size() != nf)
    invalid("density: " + std::to_string(density.size()) + " values for " + std::to_string(nf) + " triangles");
  if (!vertices.allFinite()) invalid("the surface has non-finite vertices");
  for (long f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k)
      if (faces(f, k) < 0 || faces(f, k) >= nv) invalid("triangle " + std::to_string(f) + " has a vertex out of range");
    if (!(density[f] >= 0) || !std::isfinite(density[f]))
      invalid("the density of triangle " + std::to_string(f) + " must be finite and >= 0");
    const Vec3 a = vertices.row(faces(f, 0)), b = vertices.row(faces(f, 1)), c = vertices.row(faces(f, 2));
    if (!((b - a).cross(c - a).norm() > 0)) invalid("triangle " + std::to_string(f) + " has no area");
  }
}

double SurfaceDensity::mass() const {
  double m = 0;
  for (long f = 0; f < faces.rows(); ++f) {
    const Vec3 a = vertices.row(faces(f, 0)), b = vertices.row(faces(f, 1)), c = vertices.row(faces(f, 2));
    m += density[f] * 0.5 * (b - a).cross(c - a).norm();
  }
  return m;
}

namespace {

// The 3-D regular triangulation of the weighted sites: power weight |y_i|^2 + 2 h_i (CGAL's
// power distance |x - y_i|^2 - w_i is then |x|^2 - 2 (<x, y_i> + h_i)). Its edges are the
// candidate neighbours of every cell (a superset of the surface's: cutting by more
// half-spaces than needed is harmless); hidden sites have no cell.
//
// With `centre_height`, a further point at the origin with that height (number n, no mass):
// the sites of a sphere map lie on one sphere, nearly cospherical, and their triangulation
// fills the ball with long tetrahedra between far sites, which slows CGAL's insertions and
// gives every site nearly twice its neighbours on the surface (10-11 against 6 on armadillo's
// pair). Where the centre's cell holds the ball's inside but meets no triangle of the
// surface (centre_height between every site's height, the score at the origin, and a lower
// bound of the scores on the surface: surface_centre_height), the long tetrahedra give way to
// ones on the centre: on armadillo's pair 9 neighbours a site and 70 ms instead of 85 for the
// 25K sites (thin tetrahedra between near sites remain). The cells on the surface are the
// same, and the pieces are cut without the centre.
struct Diagram3 {
  RT3 rt;
  std::vector<int> start, nbr;  // CSR neighbour lists (the centre's too, when there is one)
  std::vector<char> present;
  int centre = -1;  // the centre's number (n), or -1
  double centre_height = 0;

  Diagram3(const Points3& sites, const Eigen::VectorXd& h, std::optional<double> with_centre = std::nullopt) {
    const int n = static_cast<int>(sites.rows());
    std::vector<std::pair<RT3::Weighted_point, int>> points(n);
    for (int i = 0; i < n; ++i)
      points[i] = {RT3::Weighted_point(K::Point_3(sites(i, 0), sites(i, 1), sites(i, 2)),
                                       sites.row(i).squaredNorm() + 2 * h[i]),
                   i};
    if (with_centre) {  // first: the sites then go in around it, each with a local conflict zone
      centre = n;
      centre_height = *with_centre;
      rt.insert(RT3::Weighted_point(K::Point_3(0, 0, 0), 2 * centre_height))->info() = n;
    }
    rt.insert(points.begin(), points.end());
    if (rt.dimension() == 3) {
      cell_neighbours(n + (centre >= 0));
    } else {
      std::vector<std::pair<int, int>> adjacent;
      for (auto e = rt.finite_edges_begin(); e != rt.finite_edges_end(); ++e)
        adjacent.emplace_back(e->first->vertex(e->second)->info(), e->first->vertex(e->third)->info());
      neighbour_lists(n + (centre >= 0), adjacent, start, nbr);
    }
    present.assign(n, 0);
    for (auto v = rt.finite_vertices_begin(); v != rt.finite_vertices_end(); ++v)
      if (v->info() < n) present[v->info()] = 1;
  }

  // The neighbour lists (sorted, as neighbour_lists makes them) from the finite cells' six
  // edges each: the cells' corners read once into a plain array, every site's list filled
  // with its repeats, which a stamp per site drops before the few left are sorted (each
  // neighbour comes about six times over). CGAL's edge iterator circulates around every edge
  // to find its canonical cell, which cost more.
  void cell_neighbours(int n) {
    std::vector<std::array<int, 4>> corners;
    corners.reserve(rt.number_of_finite_cells());
    for (auto c = rt.finite_cells_begin(); c != rt.finite_cells_end(); ++c)
      corners.push_back({c->vertex(0)->info(), c->vertex(1)->info(), c->vertex(2)->info(), c->vertex(3)->info()});
    start.assign(n + 1, 0);
    for (const auto& c : corners)
      for (int a = 0; a < 4; ++a) start[c[a] + 1] += 3;
    for (int i = 0; i < n; ++i) start[i + 1] += start[i];
    nbr.resize(start[n]);
    std::vector<int> fill(start.begin(), start.end() - 1);
    for (const auto& c : corners)
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b)
          if (a != b) nbr[fill[c[a]]++] = c[b];
    std::vector<int> stamp(n, -1);
    int out = 0;
    for (int i = 0; i < n; ++i) {
      const int first = out;
      for (int k = start[i]; k < start[i + 1]; ++k)
        if (const int j = nbr[k]; stamp[j] != i) stamp[j] = i, nbr[out++] = j;
      std::sort(nbr.begin() + first, nbr.begin() + out);
      start[i] = first;
    }
    start[n] = out;
    nbr.resize(out);
  }
};

// The owner of point g (the site maximizing <g, y_j> + h_j): a greedy walk over the
// triangulation's edges from site `from` (a site whose cell misses g has a neighbour scoring
// higher there: the segment from its cell to g leaves it through a neighbour's facet, where
// the two scores' affine difference changes sign), in doubles.
// The centre, where there is one, takes part in the walk (its score is its height) but never
// ends it on the surface, where its height is below some site's score.
int greedy_owner(const Vec3& g, const Points3& sites, const Eigen::VectorXd& h, const Diagram3& d, int from) {
  auto score = [&](int j) { return j == d.centre ? d.centre_height : g.dot(Vec3(sites.row(j))) + h[j]; };
  int owner = from;
  for (double best = score(owner);;) {
    from = owner;
    for (int k = d.start[from]; k < d.start[from + 1]; ++k)
      if (const double sj = score(d.nbr[k]); sj > best) best = sj, owner = d.nbr[k];
    if (owner == from) return owner;
  }
}

// The cells' pieces of each triangle of the surface: the cells meeting a triangle T tile it
// (the 3-D diagram cut by T's plane is a power diagram of that plane), so they are connected
// through their sides in T: a flood fill from the owner of T's centroid, each piece's
// labelled sides naming the cells to visit.
class TriangleCells {
 public:
  TriangleCells(const SurfaceDensity& surface, const Points3& sites, const Eigen::VectorXd& h, const Diagram3& d)
      : surface_(surface), sites_(sites), h_(h), d_(d), stamp_(sites.rows(), -1) {
    last_owner_ = static_cast<int>(std::find(d.present.begin(), d.present.end(), 1) - d.present.begin());
  }

  // hint: a cell near the triangle, where the walk starts (-1: none; then from the last
  // triangle's owner).
  PieceRange run(int f, int hint, int thread, ThreadPieces& out) {
    const int first = static_cast<int>(out.parts.size());
    const size_t first_slot = out.slots.size();
    const double rho = surface_.density[f];
    if (!(rho > 0)) return {thread, first, first};
    for (int v = 0; v < 3; ++v) corner_[v] = surface_.vertices.row(surface_.faces(f, v));
    normal_ = (corner_[1] - corner_[0]).cross(corner_[2] - corner_[0]).normalized();
    const Vec3 g = (corner_[0] + corner_[1] + corner_[2]) / 3;
    const bool hinted = hint >= 0 && hint < static_cast<int>(d_.present.size()) && d_.present[hint];
    int owner = greedy_owner(g, sites_, h_, d_, hinted ? hint : last_owner_);
    for (int attempt = 0; attempt < 2 && static_cast<int>(out.parts.size()) == first; ++attempt) {
      if (attempt == 1) {
        // CGAL's exact nearest_power_vertex, whose exact fallbacks on cospherical sites took
        // a third of the time, only where the walk's owner gets no piece (round-off at a tie).
        const RT3::Vertex_handle v = d_.rt.nearest_power_vertex(K::Point_3(g.x(), g.y(), g.z()));
        if (v == RT3::Vertex_handle() || v->info() == owner) break;
        if (v->info() == d_.centre) fail(ErrorCode::kInternal, "the surface cells' centre point owns a triangle's centroid");
        owner = v->info();
        out.slots.resize(first_slot);
      }
      last_owner_ = owner;
      flood(owner, 2 * f + attempt, rho, out);
    }
    return {thread, first, static_cast<int>(out.parts.size())};
  }

 private:
  void flood(int owner, int mark, double rho, ThreadPieces& out) {
    queue_.assign(1, owner);
    stamp_[owner] = mark;
    for (size_t q = 0; q < queue_.size(); ++q) {
      const int i = queue_[q];
      const Vec3 yi = sites_.row(i);
      piece_.p.assign(corner_, corner_ + 3);
      piece_.label.assign(3, -1);
      for (int k = d_.start[i]; k < d_.start[i + 1] && piece_.p.size() >= 3; ++k) {
        const int j = d_.nbr[k];
        if (j == d_.centre) continue;  // its cell meets no triangle
        piece_.cut(yi - Vec3(sites_.row(j)), h_[i] - h_[j], k);
      }
      if (piece_.p.size() < 3) continue;
      out.parts.push_back(integrate(i, yi, rho, mark, out));
    }
  }

  // The piece's integrals about site i, and per side on a neighbour's plane its weight in
  // the Hessian: rho |side| / |P_T (y_i - y_j)|; the neighbours across its sides of
  // positive length go on the flood's queue.
  Contribution integrate(int i, const Vec3& yi, double rho, int mark, ThreadPieces& out) {
    const size_t m = piece_.p.size();
    Contribution c{i, 0, 0, Vec3::Zero(), static_cast<int>(out.slots.size()), 0};
    const Vec3& p0 = piece_.p[0];
    for (size_t k = 1; k + 1 < m; ++k) {
      const Vec3 &p1 = piece_.p[k], &p2 = piece_.p[k + 1];
      const double area = 0.5 * normal_.dot((p1 - p0).cross(p2 - p0));
      const Vec3 u = p0 - yi, v = p1 - yi, w = p2 - yi;
      c.mass += rho * area;
      c.first += rho * area * (p0 + p1 + p2) / 3;
      c.second += rho * area * (u.squaredNorm() + v.squaredNorm() + w.squaredNorm() + u.dot(v) + v.dot(w) + w.dot(u)) / 6;
    }
    for (size_t k = 0; k < m; ++k) {
      const int slot = piece_.label[k];
      if (slot < 0) continue;
      const double length = (piece_.p[k + 1 == m ? 0 : k + 1] - piece_.p[k]).norm();
      if (!(length > 0)) continue;
      const Vec3 d = yi - Vec3(sites_.row(d_.nbr[slot]));
      const double speed = (d - d.dot(normal_) * normal_).norm();  // |P_T (y_i - y_j)|
      if (speed > 0) out.slots.emplace_back(slot, rho * length / speed);
      const int j = d_.nbr[slot];
      if (stamp_[j] != mark) {
        stamp_[j] = mark;
        queue_.push_back(j);
      }
    }
    c.slots_end = static_cast<int>(out.slots.size());
    return c;
  }

  const SurfaceDensity& surface_;
  const Points3& sites_;
  const Eigen::VectorXd& h_;
  const Diagram3& d_;
  Piece piece_;
  std::vector<int> stamp_, queue_;
  int last_owner_ = 0;
  Vec3 corner_[3], normal_;
};

// The height of Diagram3's centre point, or nothing. On a triangle T whose hint names site v,
// every point x of T scores at least <x, y_v> + h_v (the cells' score is the maximum over
// the sites), and that is linear on T: its least corner value bounds the surface's scores
// from below. At the origin every site scores its height. A centre height halfway between
// the largest height and that bound gives the centre a cell inside the ball that meets no
// triangle; nothing where the two are not apart or a triangle with mass has no hint.
std::optional<double> surface_centre_height(const SurfaceDensity& surface, const Points3& sites,
                                            const Eigen::VectorXd& h, std::span<const int> hint) {
  const int n = static_cast<int>(sites.rows());
  if (hint.empty()) return std::nullopt;
  double low = std::numeric_limits<double>::infinity();
  for (long f = 0; f < surface.faces.rows(); ++f) {
    if (!(surface.density[f] > 0)) continue;
    const int v = hint[f];
    if (v < 0 || v >= n) return std::nullopt;
    for (int k = 0; k < 3; ++k)
      low = std::min(low, surface.vertices.row(surface.faces(f, k)).dot(sites.row(v)) + h[v]);
  }
  const double high = h.maxCoeff();
  if (!(low - high > 1e-6)) return std::nullopt;  // (on the unit sphere: about 0.85 on real pairs)
  return 0.5 * (low + high);
}

}  // namespace

SurfaceCells surface_power_cells(const SurfaceDensity& surface, const Points3& sites, const Eigen::VectorXd& h,
                                 std::span<const int> hint) {
  surface.check();
  const int n = static_cast<int>(sites.rows());
  if (n == 0) invalid("no sites");
  if (h.size() != n) invalid("heights: " + std::to_string(h.size()) + " for " + std::to_string(n) + " sites");
  if (!sites.allFinite() || !h.allFinite()) invalid("sites and heights must be finite");
  const int nf = static_cast<int>(surface.faces.rows());
  if (!hint.empty() && static_cast<int>(hint.size()) != nf)
    invalid("owner hints: " + std::to_string(hint.size()) + " for " + std::to_string(nf) + " triangles");
  const Diagram3 d(sites, h, surface_centre_height(surface, sites, h, hint));
  std::vector<ThreadPieces> pieces(omp_get_max_threads());
  std::vector<PieceRange> range(nf);
#pragma omp parallel
  {
    TriangleCells cells(surface, sites, h, d);
    const int thread = omp_get_thread_num();
#pragma omp for schedule(dynamic, 64)
    for (int f = 0; f < nf; ++f) range[f] = cells.run(f, hint.empty() ? -1 : hint[f], thread, pieces[thread]);
  }
  // Sums in triangle order: the same bits on any number of threads.
  SurfaceCells cells;
  cells.owner.resize(nf);
  for (int f = 0; f < nf; ++f)
    cells.owner[f] = range[f].begin == range[f].end ? -1 : pieces[range[f].thread].parts[range[f].begin].cell;
  cells.mass = Eigen::VectorXd::Zero(n);
  cells.second_moment = Eigen::VectorXd::Zero(n);
  cells.first = Points3::Zero(n, 3);
  std::vector<double> slot_weight(d.nbr.size(), 0.0);
  for (const PieceRange& at : range) {
    const ThreadPieces& r = pieces[at.thread];
    for (int p = at.begin; p < at.end; ++p) {
      const Contribution& c = r.parts[p];
      cells.mass[c.cell] += c.mass;
      cells.second_moment[c.cell] += c.second;
      cells.first.row(c.cell) += c.first.transpose();
      for (int s = c.slots_begin; s < c.slots_end; ++s) slot_weight[r.slots[s].first] += r.slots[s].second;
    }
  }
  for (int i = 0; i < n; ++i) {
    if (!d.present[i] || !(cells.mass[i] > 0)) ++cells.empty_cells;
    for (int k = d.start[i]; k < d.start[i + 1]; ++k)
      if (i < d.nbr[k] && slot_weight[k] > 0) cells.edges.push_back({i, d.nbr[k], slot_weight[k]});
  }
  return cells;
}

namespace {

// OmtOptions::multilevel on a surface (the sphere's distances): the coarse-to-fine start of
// multilevel.cpp with the surface's own cells. An eighth of the sites (as on the plane; a
// quarter until session 39: over 18 real sphere pairs 1,832 -> 1,594 Newton iterations,
// 13 pairs fewer, 4 more by at most 4; bench/RESULTS.md) carries the masses of the sites
// nearest each (the owner under zero heights, found by the greedy walk); its
// solution's smoothed Legendre transform gives the fine heights, with eps = 2 pi / sqrt(n m):
// half a coarse cell's size times a site spacing on the unit sphere. Wider smoothing left
// the fine starts further off (four times this: a third more Newton iterations on the real
// pairs); a quarter of it stalled one pair (bench/RESULTS.md, session 21). Nothing where
// the coarse solve fails.
std::optional<Eigen::VectorXd> surface_coarse_to_fine(const SurfaceDensity& surface, const Points3& sites,
                                                      const Eigen::VectorXd& nu, const OmtOptions& opt,
                                                      SurfaceOmtResult& r) {
  const int n = static_cast<int>(sites.rows());
  const std::vector<int> keep = detail::coarse_subset(n, detail::kCoarseRatio);
  const int m = static_cast<int>(keep.size());
  Points3 coarse(m, 3);
  for (int k = 0; k < m; ++k) coarse.row(k) = sites.row(keep[k]);
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(m);
  const Diagram3 d(coarse, zero);
  Eigen::VectorXd coarse_nu = Eigen::VectorXd::Zero(m);
  for (int i = 0, at = 0; i < n; ++i) {
    at = greedy_owner(sites.row(i).transpose(), coarse, zero, d, at);
    coarse_nu[at] += nu[i];
  }
  SurfaceOmtResult c;
  try {
    c = solve_surface_omt(surface, coarse, coarse_nu, detail::coarse_options(opt, keep, n));
  } catch (const Error& e) {
    if (e.code() != ErrorCode::kNotConverged) throw;
    return std::nullopt;
  }
  r.coarse_iterations += c.iterations;
  if (!c.converged) return std::nullopt;
  r.levels = c.levels + 1;
  Points3 centroid(m, 3);
  for (int j = 0; j < m; ++j) centroid.row(j) = c.cells.first.row(j) / c.cells.mass[j];
  const double eps = 2 * std::numbers::pi / std::sqrt(static_cast<double>(n) * m);
  return detail::smoothed_dual(coarse, centroid, c.h, c.cells.mass, sites, eps, 0.03);
}

// The coarse-to-fine start, taken where it leaves no cell empty (h and r.cells move to it).
void surface_coarse_start(const SurfaceDensity& surface, const Points3& sites, const OmtOptions& opt,
                          Eigen::VectorXd& h, SurfaceOmtResult& r) {
  std::optional<Eigen::VectorXd> start = surface_coarse_to_fine(surface, sites, r.target, opt, r);
  if (!start) return;
  SurfaceCells c = surface_power_cells(surface, sites, *start, r.cells.owner);
  if (c.empty_cells > 0) {
    r.levels = 1;
    return;
  }
  h = std::move(*start);
  r.cells = std::move(c);
}

// One Newton iteration's step along dh, Kitagawa-Merigot-Thibert damped: the largest
// t = 2^-k, k < 30, whose cells pass `passes(t, cells)` (every cell above the floor, the
// gradient norm cut by t/2); h, cells and last_t move to it. False where none passes.
template <class Passes>
bool damped_step(const SurfaceDensity& surface, const Points3& sites, const Eigen::VectorXd& dh, bool first,
                 const Passes& passes, Eigen::VectorXd& h, SurfaceCells& cells, double& last_t) {
  auto take = [&](double t, SurfaceCells&& c) {
    h += t * dh;
    cells = std::move(c);
    last_t = t;
    return true;
  };
  if (first) {
    // A level's first step has no last step to start from, and from a coarse-to-fine start
    // it is often tiny: 2^-13 to 2^-24 on camel's and cow x bull's levels (bench/RESULTS.md,
    // session 61), 14-25 trials one by one. So t = 1, 1/4, then a sixteenth of the last down
    // to the first t that passes, and a bisection of the exponent between it and the refused
    // one above: 7 trials for 2^-13, 10 for 2^-24. Where passing is monotone in t (a smaller
    // step empties no cell a larger one kept) the step is the halving's own: on five real
    // pairs the same iterations and distances, with 5-9 % fewer sets of cells (session 62).
    int refused = -1, passed = -1;
    SurfaceCells best;
    auto judge = [&](int k) {  // t = 2^-k: true where it passes (its cells then in best)
      SurfaceCells c = surface_power_cells(surface, sites, h + std::ldexp(1.0, -k) * dh, cells.owner);
      if (!passes(std::ldexp(1.0, -k), c)) return refused = k, false;
      passed = k;
      best = std::move(c);
      return true;
    };
    for (const int k : {0, 2, 6, 10, 14, 18, 22, 26, 29})
      if (judge(k)) break;
    if (passed < 0) return false;
    while (passed - refused > 1) judge((passed + refused) / 2);
    return take(std::ldexp(1.0, -passed), std::move(best));
  }
  // Otherwise the halving starts at four times the last step: where the steps stay short for
  // many iterations (measured: oblong's density to retinal's vertices, 100 iterations at
  // t ~ 1/256) each then costs two or three sets of cells instead of nine, and a run of full
  // steps comes back within a few iterations.
  double t = std::min(1.0, 4 * last_t);
  // Where the steps are damped and a second core is free (two OpenMP threads here: the
  // solve runs alone, or take_idle_workers gave it a finished worker's core), the trials
  // are set up two at a time, t and t/2, one per core, and judged in order as one by one:
  // the same step is taken, and a damped iteration's usual two or three refused-or-taken
  // trials cost one or two sets of cells' time instead of three.
  const int round = last_t < 1 && omp_get_max_threads() >= 2 ? 2 : 1;
  for (int halvings = 0; halvings < 30;) {
    const int count = std::min(round, 30 - halvings);
    Eigen::VectorXd trial[2];
    SurfaceCells c[2];
    for (int k = 0; k < count; ++k) trial[k] = h + (t * std::ldexp(1.0, -k)) * dh;
    if (count == 2)
      parallel_for(2, 2, [&](int k) { c[k] = surface_power_cells(surface, sites, trial[k], cells.owner); });
    else
      c[0] = surface_power_cells(surface, sites, trial[0], cells.owner);
    for (int k = 0; k < count; ++k, ++halvings, t *= 0.5)
      if (passes(t, c[k])) return take(t, std::move(c[k]));
  }
  return false;
}

SurfaceOmtResult solve_surface(const SurfaceDensity& surface, const Points3& sites, const Eigen::VectorXd& nu_in,
                               const OmtOptions& opt) {
  const int n = static_cast<int>(sites.rows());
  check_transport_input(n, nu_in, opt);
  surface.check();
  SurfaceOmtResult r;
  r.target = nu_in * (surface.mass() / nu_in.sum());
  const Eigen::VectorXd& nu = r.target;
  Eigen::VectorXd h = Eigen::VectorXd::Zero(n);
  if (opt.initial_h.size() != 0) {
    if (opt.initial_h.size() != n || !opt.initial_h.allFinite())
      invalid("initial heights: " + std::to_string(n) + " finite values needed");
    h = opt.initial_h;
  }
  auto max_relative = [&](const Eigen::VectorXd& m) { return ((m - nu).array().abs() / nu.array()).maxCoeff(); };
  auto relative_norm = [&](const Eigen::VectorXd& g) { return (g.array() / nu.array()).matrix().norm(); };
  r.cells = surface_power_cells(surface, sites, h);
  r.max_relative_error = max_relative(r.cells.mass);
  if (opt.multilevel && n >= 1000 && r.max_relative_error > 10) {
    surface_coarse_start(surface, sites, opt, h, r);
    r.max_relative_error = max_relative(r.cells.mass);
  }
  // Kitagawa-Merigot-Thibert damping: every cell keeps at least eps0.
  const double eps0 = 0.5 * std::min(nu.minCoeff(), r.cells.mass.minCoeff());
  if (!(eps0 > 0))
    fail(ErrorCode::kNotConverged, std::to_string(r.cells.empty_cells) + " of " + std::to_string(n) +
                                       " sites have empty cells on the surface at the start");
  int held = 0;
  nu.maxCoeff(&held);  // its height is held: the energy is invariant under h + constant
  single_threaded_blas();  // before CHOLMOD reaches OpenBLAS
  detail::NewtonFactor llt;
  llt.setMode(Eigen::CholmodSimplicialLLt);
  llt.cholmod().print = 0;
  double last_t = 1;
  bool gap_closed = false;
  detail::StallWatch stall(opt.stall_window);
  // The Kantorovich dual at h: sum_i int_{W_i} |x - y_i|^2 - sum_i w_i (m_i - nu_i).
  auto dual_at = [&](const Eigen::VectorXd& heights, const SurfaceCells& cells) {
    Eigen::VectorXd w(n);
    for (int i = 0; i < n; ++i) w[i] = sites.row(i).squaredNorm() + 2 * heights[i];
    return cells.second_moment.sum() - w.dot(cells.mass - nu);
  };
  for (r.iterations = 0; r.iterations < opt.max_iterations && r.max_relative_error > opt.tolerance; ++r.iterations) {
    if (opt.abandon && (r.abandoned = opt.abandon(dual_at(h, r.cells)))) break;  // OmtOptions::abandon
    take_idle_workers();  // the cores of a pool whose other tasks are done
    // The Jacobian of the masses (eq. 3.28 on the surface): the weighted graph Laplacian of
    // the cells' sides, dm_i/dh_j = -w_ij, dm_i/dh_i = sum_j w_ij; without the held height.
    const Eigen::VectorXd g = r.cells.mass - nu;
    const std::optional<Eigen::VectorXd> step = detail::newton_direction(r.cells.edges, g, held, llt);
    if (!step)
      fail(ErrorCode::kNotConverged, "the surface transport's Hessian is singular at iteration " +
                                         std::to_string(r.iterations) + " (a cell without neighbours)");
    const Eigen::VectorXd& dh = *step;
    // The dual gap test (OmtOptions::dual_gap_tolerance), as on the disk: the dual D(h) is
    // concave with gradient -2 g and Hessian -2 H, so the Newton step's predicted rise of D
    // to its maximum is -g . dh; once that is within the tolerance of D, the cost is known.
    if (opt.dual_gap_tolerance > 0 && r.max_relative_error <= 0.25) {
      const double rise = -g.dot(dh), value = dual_at(h, r.cells);
      if (rise >= 0 && rise <= opt.dual_gap_tolerance * std::abs(value)) {
        r.dual_rise = rise;
        gap_closed = true;
        break;
      }
    }
    const double gnorm = relative_norm(g);
    // OmtOptions::stall_window: the accepted steps have barely moved the gradient for a whole
    // window.
    if (stall.stalled(gnorm)) {
      r.stalled = true;
      break;
    }
    auto passes = [&](double t, const SurfaceCells& c) {
      return c.empty_cells == 0 && c.mass.minCoeff() >= eps0 &&
             (relative_norm(c.mass - nu) <= (1 - 0.5 * t) * gnorm || max_relative(c.mass) <= opt.tolerance);
    };
    const bool accepted = damped_step(surface, sites, dh, r.iterations == 0, passes, h, r.cells, last_t);
    r.max_relative_error = max_relative(r.cells.mass);
    if (opt.progress && !opt.progress(r.iterations + 1, r.max_relative_error))
      fail(ErrorCode::kCancelled, "optimal transport cancelled");
    if (!accepted) {
      ++r.iterations;
      break;  // round-off floor: no step improves any more
    }
  }
  r.dual_value = dual_at(h, r.cells);
  r.h = h.array() - h.mean();
  r.converged = (r.max_relative_error <= opt.tolerance || gap_closed) && !r.abandoned && !r.stalled;
  r.iterations += r.coarse_iterations;
  return r;
}

}  // namespace

SurfaceOmtResult solve_surface_omt(const SurfaceDensity& surface, const Points3& sites, const Eigen::VectorXd& nu,
                                   const OmtOptions& opt) {
  return detail::with_plain_fallback(
      opt, [&](const OmtOptions& o) { return solve_surface(surface, sites, nu, o); }, detail::AfterStall::kReturn);
}

}  // namespace brenier::omt

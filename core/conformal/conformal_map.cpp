#include "conformal/conformal_map.hpp"

#include <Eigen/Dense>
#include <Eigen/UmfPackSupport>
#include <limits>
#include <map>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <queue>
#include <vector>

#include "common/check.hpp"
#include "common/error.hpp"
#include "conformal/mobius.hpp"
#include "mesh/geometry.hpp"
#include "mesh/topology.hpp"
#include "quality/quality.hpp"

namespace brenier::conformal {

// Boundary targets that make the boundary a polygon inscribed in a circle. For boundary
// edge lengths L_i, the circle radius R solves sum_i 2 asin(L_i / 2R) = 2 pi (a decreasing
// function of R, solved by bisection on log R); edge i then subtends the central angle
// a_i = 2 asin(L_i / 2R), and the turning angle (the curvature of Def. 3.2 at a boundary
// vertex) of an inscribed polygon at vertex i is (a_{i-1} + a_i) / 2. These sum to 2 pi
// (Gauss-Bonnet for the disk, chi = 1). A fixed point of "curvature = these targets" is a
// flat metric whose boundary is exactly a cyclic polygon: its layout has every boundary
// vertex on one circle.
// Also returns tau_i = tan(a_i / 2), which gives the targets'
// derivative: with s_i = du(b_i) + du(b_{i+1}), da_i = tau_i (s_i - sum_j tau_j s_j / sum_j tau_j),
// so dKbar/du = (1/2) S^T diag(tau) S - (1/2) w w^T / sum(tau), w = S^T tau, where S is the
// boundary-edge-by-vertex incidence (both endpoints 1).
void inscribed_targets(const std::vector<double>& L, std::vector<double>& turning,
                       std::vector<double>& tau) {
  tau.clear();
  const size_t m = L.size();
  double lmax = 0, lsum = 0;
  for (double l : L) {
    lmax = std::max(lmax, l);
    lsum += l;
  }
  turning.resize(m);
  auto total = [&](double R) {
    double s = 0;
    for (double l : L) s += 2 * std::asin(std::min(1.0, l / (2 * R)));
    return s;
  };
  // Usually the centre is inside the polygon and every a_i = 2 asin(L_i / 2R) <= pi. When
  // the longest edge is longer than the rest can balance (total(lmax / 2) < 2 pi), the
  // centre is outside and that edge subtends the major arc 2 pi - 2 asin(L / 2R); the
  // turning-angle formula and the derivative below hold unchanged (tan(a/2) < 0 there).
  size_t imax = static_cast<size_t>(std::max_element(L.begin(), L.end()) - L.begin());
  const bool major = total(lmax / 2) < 2 * std::numbers::pi;
  auto excess = [&](double R) {  // increasing in R in the major case
    double s = 0;
    for (size_t i = 0; i < m; ++i)
      if (i != imax) s += 2 * std::asin(std::min(1.0, L[i] / (2 * R)));
    return s - 2 * std::asin(std::min(1.0, L[imax] / (2 * R)));
  };
  double lo = lmax / 2, hi = lsum;
  if (major) {
    hi = lmax;
    for (int k = 0; k < 200 && excess(hi) < 0; ++k) hi *= 2;
  }
  for (int it = 0; it < 200 && hi - lo > 1e-15 * hi; ++it) {
    double mid = std::sqrt(lo * hi);
    bool go_up = major ? excess(mid) < 0 : total(mid) > 2 * std::numbers::pi;
    (go_up ? lo : hi) = mid;
  }
  double R = 0.5 * (lo + hi);
  std::vector<double> a(m);
  double sum = 0;
  for (size_t i = 0; i < m; ++i) {
    a[i] = 2 * std::asin(std::min(1.0, L[i] / (2 * R)));
    if (major && i == imax) a[i] = 2 * std::numbers::pi - a[i];
    sum += a[i];
  }
  for (size_t i = 0; i < m; ++i) a[i] *= 2 * std::numbers::pi / sum;  // exact Gauss-Bonnet
  for (size_t i = 0; i < m; ++i) turning[i] = 0.5 * (a[(i + m - 1) % m] + a[i]);
  tau.resize(m);
  for (size_t i = 0; i < m; ++i) tau[i] = std::tan(0.5 * a[i]);
}

namespace {

// Lays out a flat intrinsic triangulation in the plane face by face (breadth-first), placing
// each new vertex from the two of its face that are already placed and its two edge lengths.
std::vector<Complex> layout(const IntrinsicTriangulation& T, const Eigen::VectorXd& u) {
  const int nv = T.num_vertices(), nf = T.num_faces();
  std::vector<Complex> pos(nv);
  std::vector<char> placed(nv, 0), done(nf, 0);
  auto third = [&](int h) {
    // Face of h: p = origin(h), q = origin(next h), r = origin(next next h), counter-clockwise.
    int hn = T.next(h), hp = T.next(hn);
    int p = T.origin(h), q = T.origin(hn), r = T.origin(hp);
    double a = T.length(h, u), b = T.length(hn, u), c = T.length(hp, u);
    double alpha = corner_angle(b, a, c);  // angle at p, opposite the side q-r
    Complex dir = pos[q] - pos[p];
    double n = std::abs(dir);
    if (!(n > 0) || !std::isfinite(n))
      fail(ErrorCode::kNotConverged,
           "the conformal map squeezes part of the surface below double precision (length "
           "scales span a factor of " +
               std::to_string(std::exp(0.5 * (u.maxCoeff() - u.minCoeff()))) +
               "), so it cannot be written as coordinates; a hole or puncture nearer to the "
               "long protrusions helps ({hole_vertex})");
    dir /= n;
    pos[r] = pos[p] + c * dir * std::polar(1.0, alpha);
    placed[r] = 1;
  };
  int h0 = T.face_halfedge(0);
  pos[T.origin(h0)] = 0;
  pos[T.origin(T.next(h0))] = T.length(h0, u);
  placed[T.origin(h0)] = placed[T.origin(T.next(h0))] = 1;
  third(h0);
  std::queue<int> q;
  q.push(0);
  done[0] = 1;
  while (!q.empty()) {
    int f = q.front();
    q.pop();
    int h = T.face_halfedge(f);
    for (int k = 0; k < 3; ++k, h = T.next(h)) {
      int t = T.twin(h);
      if (t < 0 || done[T.face(t)]) continue;
      done[T.face(t)] = 1;
      if (!placed[T.origin(T.next(T.next(t)))]) third(t);
      q.push(T.face(t));
    }
  }
  return pos;
}

// Least-squares circle through points (Kasa): x^2 + y^2 = 2 a x + 2 b y + c.
std::pair<Complex, double> fit_circle(const std::vector<Complex>& p) {
  Eigen::MatrixXd A(p.size(), 3);
  Eigen::VectorXd rhs(p.size());
  for (size_t i = 0; i < p.size(); ++i) {
    A.row(i) << 2 * p[i].real(), 2 * p[i].imag(), 1.0;
    rhs[i] = std::norm(p[i]);
  }
  Eigen::Vector3d s = A.colPivHouseholderQr().solve(rhs);
  return {Complex(s[0], s[1]), std::sqrt(s[2] + s[0] * s[0] + s[1] * s[1])};
}

Eigen::VectorXd lambda_from_areas(const mesh::TriMesh& surface, const mesh::TriMesh& image) {
  Eigen::VectorXd a = mesh::vertex_areas(surface), b = mesh::vertex_areas(image);
  return (0.5 * (a.array() / b.array()).log()).matrix();
}

}  // namespace

bool face_folded(const mesh::TriMesh& m, const mesh::Vertices& X, int f, bool sphere) {
  Eigen::Vector3d a = X.row(m.F(f, 0)), b = X.row(m.F(f, 1)), c = X.row(m.F(f, 2));
  Eigen::Vector3d n = (b - a).cross(c - a);
  return sphere ? !(n.dot(a + b + c) > 0) : !(n.z() > 0);
}

int untangle(const mesh::TriMesh& m, mesh::Vertices& X, bool sphere, const std::vector<char>& fixed,
             int& folded, int max_rounds, bool keep_longest_edges) {
  const int nv = m.num_vertices();
  std::vector<std::vector<int>> ring(nv), star(nv);
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) {
      ring[m.F(f, k)].push_back(m.F(f, (k + 1) % 3));
      star[m.F(f, k)].push_back(f);
    }
  auto folded_around = [&](int v) {
    int n = 0;
    for (int f : star[v]) n += face_folded(m, X, f, sphere);
    return n;
  };
  // On the sphere, the signed area of v's star: a move may change it only by round-off.
  // Any position of v leaves it the same modulo 4 pi (the link is held), and a change of
  // 4 pi means the star now wraps around the sphere with its faces turned outward: fewer
  // folds, but a map of degree 2 (cactus and u came out covering the sphere 4 times).
  auto star_area = [&](int v) {
    double a = 0;
    for (int f : star[v])
      a += quality::geodesic_triangle_area(X.row(m.F(f, 0)), X.row(m.F(f, 1)), X.row(m.F(f, 2)));
    return a;
  };
  std::vector<char> moved(nv, 0);
  int count = 0;
  // Candidate positions for a vertex v of folded face f: its mirror image across the line
  // (plane) of the other two corners, which unfolds f exactly, or the average of its
  // neighbours (a Tutte step). The first that lowers the folds around v is kept, else one
  // that does not raise them.
  auto mirror = [&](int v, int f) {
    int k = m.F(f, 0) == v ? 0 : m.F(f, 1) == v ? 1 : 2;
    Eigen::RowVector3d p = X.row(v), a = X.row(m.F(f, (k + 1) % 3)), b = X.row(m.F(f, (k + 2) % 3));
    if (sphere) {
      Eigen::RowVector3d n = a.cross(b).normalized();
      return Eigen::RowVector3d(p - 2 * p.dot(n) * n);
    }
    Eigen::RowVector3d d = (b - a).normalized();
    Eigen::RowVector3d foot = a + (p - a).dot(d) * d;
    return Eigen::RowVector3d(2 * foot - p);
  };
  auto average = [&](int v) {
    Eigen::RowVector3d avg = Eigen::RowVector3d::Zero();
    for (int w : ring[v]) avg += X.row(w);
    avg /= static_cast<double>(ring[v].size());
    return sphere ? Eigen::RowVector3d(avg.normalized()) : avg;
  };
  for (int round = 0; round <= max_rounds; ++round) {
    std::vector<std::pair<int, int>> todo;  // (vertex, its folded face)
    folded = 0;
    for (int f = 0; f < m.num_faces(); ++f)
      if (face_folded(m, X, f, sphere)) {
        ++folded;
        for (int k = 0; k < 3; ++k)
          if (!fixed[m.F(f, k)]) todo.push_back({m.F(f, k), f});
      }
    if (folded == 0 || todo.empty() || round == max_rounds) break;
    bool any = false;
    for (const auto& corner : todo) {
      // Named copies, not a structured binding: C++20 lambdas (longest, below) may not
      // capture structured bindings (clang 14 refuses them).
      const int v = corner.first, f = corner.second;
      if (!face_folded(m, X, f, sphere)) continue;  // fixed meanwhile
      const Eigen::RowVector3d old = X.row(v);
      const int before = folded_around(v);
      const double area_before = sphere ? star_area(v) : 0;
      Eigen::RowVector3d best = old;
      int best_n = before;
      // With keep_longest_edges a move may not lengthen v's longest edge: a mirror across a
      // face torn open by a spreading stage would throw v across the sphere and tear its
      // other faces (man: vertices moved 1.9 apart, faces 1e3 times their targets).
      auto longest = [&] {
        double l = 0;
        for (int w : ring[v]) l = std::max(l, (X.row(w) - X.row(v)).norm());
        return l;
      };
      const double longest_before = keep_longest_edges ? longest() : 0;
      for (const Eigen::RowVector3d& cand : {mirror(v, f), average(v)}) {
        if (!cand.allFinite()) continue;
        X.row(v) = cand;
        if (keep_longest_edges && longest() > longest_before) continue;
        if (sphere && std::abs(star_area(v) - area_before) > std::numbers::pi) continue;
        int n = folded_around(v);
        // Strict improvements always; sideways moves on odd rounds, to get out of a knot.
        if (n < best_n || (n == best_n && best == old && (round & 1))) {
          best = cand;
          best_n = n;
        }
      }
      X.row(v) = best;
      if (best != old) {
        any = true;
        if (!moved[v]) {
          moved[v] = 1;
          ++count;
        }
      }
    }
    if (!any && !(round & 1)) continue;  // try a round of sideways moves first
    if (!any) break;
  }
  return count;
}

namespace {

// Disk maps: a Tutte embedding that reproduces the conformal map wherever it is already
// unfolded (Floater's mean value coordinates of each interior vertex with respect to its
// mapped one-ring are positive there and have linear precision), with the 3-D surface's own
// mean value coordinates where they are not. All weights positive and the boundary on a
// convex polygon (inscribed in the circle): by Tutte's and Floater's theorems the result has
// no folded face. Returns the number of vertices whose weights were replaced.
// Oriented one-rings: fan[v] lists the (a, b) of every face (v, a, b) around v.
using Fans = std::vector<std::vector<std::pair<int, int>>>;
Fans oriented_fans(const mesh::TriMesh& m) {
  Fans fan(m.num_vertices());
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) fan[m.F(f, k)].push_back({m.F(f, (k + 1) % 3), m.F(f, (k + 2) % 3)});
  return fan;
}

int count_planar_folds(const mesh::TriMesh& m, const mesh::Vertices& X) {
  int n = 0;
  for (int f = 0; f < m.num_faces(); ++f) n += face_folded(m, X, f, false);
  return n;
}

// Floater's mean value coordinates of v among its ring (Floater 2003): each fan triangle
// (v, a, b) adds tan(alpha/2) / |a - v| to a and to b, alpha = angle a-v-b (signed in the
// plane: a folded or reflex ring gives some weight <= 0). Returns the angle sum.
double mean_value_weights(const std::vector<std::pair<int, int>>& fan, int v, const mesh::Vertices& pos,
                          bool planar, std::vector<std::pair<int, double>>& w) {
  w.clear();
  double total_angle = 0;
  auto add = [&](int k, double x) {
    for (auto& [j, y] : w)
      if (j == k) {
        y += x;
        return;
      }
    w.push_back({k, x});
  };
  for (auto [a, b] : fan) {
    Eigen::Vector3d pv = pos.row(v).transpose(), pa = pos.row(a).transpose(), pb = pos.row(b).transpose();
    Eigen::Vector3d da = pa - pv, db = pb - pv;
    double alpha = planar ? std::atan2(da.x() * db.y() - da.y() * db.x(), da.dot(db))
                          : std::atan2(da.cross(db).norm(), da.dot(db));
    total_angle += alpha;
    double t = std::tan(alpha / 2);
    add(a, t / da.norm());
    add(b, t / db.norm());
  }
  return total_angle;
}

// Tutte embedding of the vertices marked in `region` (the others stay where X has them):
// each region vertex becomes the weighted mean of its ring with the mean value coordinates
// of the conformal map itself where its ring there is an embedded star (linear precision:
// the map is reproduced), the surface's own MVC where it is folded (always positive). With
// a convex fixed outline (the disk's boundary) and positive weights Floater's theorem
// guarantees an embedding; on a region inside, the map around it plays the outline.
// Returns the vertices whose weights were replaced, -1 when the solve failed.
// With surface_weights, every region vertex takes the surface's own MVC (the map's
// positions of the region are not looked at).
int tutte_repair(const mesh::TriMesh& m, const Fans& fan, mesh::Vertices& X, const std::vector<char>& region,
                 bool surface_weights = false) {
  const int nv = m.num_vertices();
  std::vector<int> index(nv, -1);
  int n = 0;
  for (int v = 0; v < nv; ++v)
    if (region[v]) index[v] = n++;
  if (n == 0) return 0;
  std::vector<Eigen::Triplet<double>> trip;
  Eigen::MatrixXd rhs = Eigen::MatrixXd::Zero(n, 2);
  std::vector<std::pair<int, double>> w;
  int replaced = 0;
  for (int v = 0; v < nv; ++v) {
    if (index[v] < 0) continue;
    bool good = !surface_weights;
    if (good) {
      const double total = mean_value_weights(fan[v], v, X, true, w);
      good = std::abs(total - 2 * std::numbers::pi) < 1e-9;
      for (auto [k, x] : w) good = good && x > 0 && std::isfinite(x);
    }
    if (!good) {
      mean_value_weights(fan[v], v, m.V, false, w);
      ++replaced;
    }
    double sum = 0;
    for (auto [k, x] : w) sum += x;
    trip.emplace_back(index[v], index[v], 1.0);
    for (auto [k, x] : w) {
      if (index[k] >= 0)
        trip.emplace_back(index[v], index[k], -x / sum);
      else
        rhs.row(index[v]) += (x / sum) * X.row(k).head<2>();
    }
  }
  Eigen::SparseMatrix<double> A(n, n);
  A.setFromTriplets(trip.begin(), trip.end());
  // Sparse LU (UMFPACK, SuiteSparse) of the non-symmetric Tutte matrix.
  Eigen::UmfPackLU<Eigen::SparseMatrix<double>> lu;
  lu.compute(A);
  if (lu.info() != Eigen::Success) return -1;
  Eigen::MatrixXd sol = lu.solve(rhs);
  if (!sol.allFinite()) return -1;
  for (int v = 0; v < nv; ++v)
    if (index[v] >= 0) X.row(v).head<2>() = sol.row(index[v]);
  return replaced;
}


// Where the conformal map compresses the boundary below ~1e-8 (the tips of long
// protrusions), a boundary "ear" -- a face whose three corners are consecutive boundary
// vertices, all on the unit circle -- has an area of about d^3 / 4 for a spacing d, far
// below the round-off of its cross product (~1e-16 d): its sign is noise, and no placement
// of the three points exactly on the circle can be told apart from a fold in doubles. The
// corner is moved radially by the fewest units in the last place (|z| = 1 +- O(1e-15)) that
// leave every face around it positively oriented, which resolves the ear as the triangle it
// is. Returns the ears fixed.
int fix_round_off_ears(const mesh::TriMesh& m, mesh::Vertices& X, const std::vector<char>& boundary) {
  std::vector<std::vector<int>> faces_of(m.num_vertices());
  std::vector<int> ears;
  for (int f = 0; f < m.num_faces(); ++f)
    if (face_folded(m, X, f, false) && boundary[m.F(f, 0)] && boundary[m.F(f, 1)] && boundary[m.F(f, 2)])
      ears.push_back(f);
  if (ears.empty()) return 0;
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) faces_of[m.F(f, k)].push_back(f);
  int fixed = 0;
  for (int f : ears) {
    bool done = false;
    for (int k = 0; k < 3 && !done; ++k) {
      const int v = m.F(f, k);
      const Eigen::RowVector3d keep = X.row(v);
      for (int ulps = 1; ulps <= 32 && !done; ++ulps)
        for (int sign : {1, -1}) {
          X.row(v) = keep * (1.0 + sign * ulps * std::numeric_limits<double>::epsilon());
          done = std::none_of(faces_of[v].begin(), faces_of[v].end(), [&](int g) { return face_folded(m, X, g, false); });
          if (done) break;
        }
      if (!done) X.row(v) = keep;
    }
    fixed += done;
  }
  return fixed;
}

}  // namespace

bool tutte_fill(const mesh::TriMesh& m, mesh::Vertices& X, const std::vector<char>& region) {
  return tutte_repair(m, oriented_fans(m), X, region, /*surface_weights=*/true) >= 0;
}

// Planar positions X (#V by 3, z = 0) of `m`: folded faces are repaired by a Tutte
// embedding of the free vertices within a few rings of them, the region doubling until no
// fold is left (the last region is every vertex not `fixed`: with a convex fixed outline,
// Floater's guarantee). A repair is kept only if it folds fewer faces. Returns the vertices
// whose weights were replaced (0 if unused); `folded` gets the folds left.
int repair_planar_folds(const mesh::TriMesh& m, mesh::Vertices& X, const std::vector<char>& fixed,
                        int& folded) {
  folded = count_planar_folds(m, X);
  if (folded == 0) return 0;
  const int nv = m.num_vertices();
  const Fans fan = oriented_fans(m);
  int replaced_total = 0;
  for (int rings = 3;; rings *= 2) {
    // Breadth-first from the corners of the folded faces, `rings` steps, fixed ones excluded.
    std::vector<int> dist(nv, -1), frontier;
    for (int f = 0; f < m.num_faces(); ++f)
      if (face_folded(m, X, f, false))
        for (int k = 0; k < 3; ++k)
          if (dist[m.F(f, k)] < 0) {
            dist[m.F(f, k)] = 0;
            frontier.push_back(m.F(f, k));
          }
    for (size_t q = 0; q < frontier.size(); ++q) {
      int v = frontier[q];
      if (dist[v] >= rings) continue;
      for (auto [a, b] : fan[v])
        for (int k : {a, b})
          if (dist[k] < 0) {
            dist[k] = dist[v] + 1;
            frontier.push_back(k);
          }
    }
    std::vector<char> region(nv, 0);
    bool everything = true;
    for (int v = 0; v < nv; ++v) {
      region[v] = dist[v] >= 0 && !fixed[v];
      everything = everything && (region[v] || fixed[v]);
    }
    mesh::Vertices trial = X;
    int replaced = tutte_repair(m, fan, trial, region);
    if (replaced >= 0) {
      int after = count_planar_folds(m, trial);
      if (after < folded) {
        X = std::move(trial);
        folded = after;
        replaced_total += replaced;
      }
    }
    if (folded == 0 || everything || rings > nv) break;
  }
  return replaced_total;
}

namespace {

void check_disk_markers(const ConformalOptions& opt, int nv, const std::vector<char>& on_boundary) {
  if (opt.center_vertex) {
    const int c = *opt.center_vertex;
    if (c < 0 || c >= nv) invalid("center vertex " + std::to_string(c) + " is out of range");
    if (on_boundary[c]) invalid("center vertex " + std::to_string(c) + " is on the boundary; it must be interior");
  }
  if (opt.boundary_vertex) {
    const int b = *opt.boundary_vertex;
    if (b < 0 || b >= nv) invalid("boundary marker " + std::to_string(b) + " is out of range");
    if (!on_boundary[b]) invalid("boundary marker " + std::to_string(b) + " is not on the boundary");
  }
}

// The boundary loop of the flow's intrinsic triangulation: its vertices in order (mesh
// vertices, then split points) and each one's boundary half-edge, which keeps its identity
// through flips (only interior edges flip).
struct FlowBoundary {
  std::vector<int> loop;
  std::vector<int> halfedge;  // by vertex

  FlowBoundary(const IntrinsicTriangulation& T, std::vector<int> boundary_loop, int nv)
      : loop(std::move(boundary_loop)), halfedge(nv, -1) {
    for (int h = 0; h < T.num_halfedges(); ++h)
      if (T.on_boundary(h)) halfedge[T.origin(h)] = h;
    for (int v : loop) BRENIER_CHECK(halfedge[v] >= 0, "boundary vertex " << v << " has no boundary edge");
  }

  // A boundary edge facing a nearly flat angle (scanned meshes have 0.03 degree slivers)
  // leaves the flow no room: the triangle cannot be flipped and the smallest change of u
  // breaks its triangle inequality. Such edges are split intrinsically (extra boundary
  // vertices that take part in the flow but not in the output) until every boundary edge
  // faces an angle below `threshold`. Returns the splits made.
  int refine(IntrinsicTriangulation& T, Eigen::VectorXd& u, double threshold) {
    const int nv = static_cast<int>(halfedge.size());
    std::vector<int> refined;
    refined.reserve(loop.size());
    std::vector<int> todo(loop.rbegin(), loop.rend());  // stack of vertices, loop order
    int splits = 0;
    while (!todo.empty()) {
      const int v = todo.back();
      todo.pop_back();
      refined.push_back(v);
      const int h = halfedge[v], h1 = T.next(h), h2 = T.next(h1);
      const double opposite = corner_angle(T.length(h, u), T.length(h1, u), T.length(h2, u));
      if (opposite > threshold && splits < 2 * nv + 64) {
        const int mid = T.split_boundary_edge(h, u);
        ++splits;
        halfedge.push_back(T.num_halfedges() - 2);  // the new mid -> j half-edge
        refined.pop_back();
        todo.push_back(mid);  // re-examine both halves: v's edge now ends at mid
        todo.push_back(v);
      }
    }
    loop = std::move(refined);
    return splits;
  }
};

// Flat inside (Alg. 1 with Kbar = 0) and, on the boundary, the turning angles of the polygon
// inscribed in a circle with the current boundary edge lengths, with its constraint.
TargetCurvature inscribed_boundary_target(const FlowBoundary& boundary) {
  struct Scratch {
    std::vector<double> L, turning, tau;
  };
  auto scratch = std::make_shared<Scratch>();
  return [&boundary, scratch](const IntrinsicTriangulation& tri, const Eigen::VectorXd& u) {
    Target t;
    const int nt = tri.num_vertices();  // mesh vertices, then the boundary split points
    t.K = Eigen::VectorXd::Zero(nt);
    const std::vector<int>& loop = boundary.loop;
    const size_t m = loop.size();
    std::vector<double>& L = scratch->L;
    L.resize(m);
    for (size_t i = 0; i < m; ++i) L[i] = tri.length(boundary.halfedge[loop[i]], u);
    inscribed_targets(L, scratch->turning, scratch->tau);
    for (size_t i = 0; i < m; ++i) t.K[loop[i]] = scratch->turning[i];
    const std::vector<double>& tau = scratch->tau;
    if (tau.empty()) return t;
    t.w = Eigen::VectorXd::Zero(nt);
    double sum = 0;
    for (size_t j = 0; j < m; ++j) {
      const int a = loop[j], b = loop[(j + 1) % m];
      const double h = 0.5 * tau[j];
      t.M.emplace_back(a, a, h);
      t.M.emplace_back(b, b, h);
      t.M.emplace_back(a, b, h);
      t.M.emplace_back(b, a, h);
      t.w[a] += tau[j];
      t.w[b] += tau[j];
      sum += tau[j];
    }
    t.c = 0.5 / sum;
    return t;
  };
}

// The flow in rounds: when it is blocked against a boundary triangle, the boundary is split
// further and the flow resumes from where it stopped.
YamabeResult disk_flow(IntrinsicTriangulation& T, FlowBoundary& boundary, Eigen::VectorXd& u,
                       const ConformalOptions& opt) {
  const TargetCurvature target = inscribed_boundary_target(boundary);
  YamabeOptions yo;
  yo.tolerance = opt.tolerance;
  yo.max_iterations = opt.max_iterations;
  yo.progress = opt.progress;
  // One kept factor for every round: a round restarted after boundary splits preconditions
  // with the last factor (GMRES absorbs the few new vertices) instead of factoring afresh.
  yo.kept_factor = make_kept_factor();
  const int pinned = boundary.loop.front();
  auto pin = [&]() {
    std::vector<char> fixed(T.num_vertices(), 0);
    fixed[pinned] = 1;
    return fixed;
  };
  YamabeResult yr = solve_yamabe(T, target, u, pin(), yo);
  int total_iterations = yr.iterations;
  for (int round = 0; round < 20 && !yr.converged && total_iterations < opt.max_iterations; ++round) {
    u = yr.u;
    yo.max_iterations = opt.max_iterations - total_iterations;
    if (!yr.blocked) break;  // stuck for another reason: report it
    if (boundary.refine(T, u, 2 * std::numbers::pi / 3) == 0 && boundary.refine(T, u, std::numbers::pi / 2) == 0)
      yo.stop_when_blocked = false;  // nothing left to split: take the small steps
    yr = solve_yamabe(T, target, u, pin(), yo);
    total_iterations += yr.iterations;
  }
  yr.iterations = total_iterations;
  return yr;
}

// Layout, then the boundary circle scaled to the unit circle with the boundary put on it
// exactly (the residual moves it by at most about the curvature tolerance). log_scale gets
// the log of the length scale from the surface to the disk at each vertex: e^{u_i} from the
// vertex scaling (l_ij = eta_ij e^{(u_i + u_j) / 2}: an edge with both ends near i scales by
// e^{u_i}) and 1 / R from fitting the unit circle.
mesh::UV disk_layout(const IntrinsicTriangulation& T, const YamabeResult& yr, const std::vector<int>& loop,
                     const std::vector<char>& on_boundary, int nv, Eigen::VectorXd& log_scale) {
  std::vector<Complex> pos = layout(T, yr.u);
  for (int v = 0; v < static_cast<int>(pos.size()); ++v)
    BRENIER_CHECK(std::isfinite(pos[v].real()) && std::isfinite(pos[v].imag()),
                  "layout placed vertex " << v << " at a non-finite point");
  std::vector<Complex> bpos;
  for (int v : loop) bpos.push_back(pos[v]);
  auto [centre, R] = fit_circle(bpos);
  BRENIER_CHECK(std::isfinite(R) && R > 0, "boundary circle fit failed (radius " << R << ")");
  mesh::UV uv(nv, 2);
  for (int v = 0; v < nv; ++v) {
    Complex z = (pos[v] - centre) / R;
    if (on_boundary[v]) z /= std::abs(z);
    uv(v, 0) = z.real();
    uv(v, 1) = z.imag();
  }
  log_scale = (yr.u.head(nv).array() - std::log(R)).matrix();
  return uv;
}

// Moebius normalization (Thm 2.13): the centre vertex (or the area centre of mass) at 0 and
// the boundary marker (or the first boundary vertex) at 1, each map's |M'(z)| added to
// log_scale; returns the normalization in words.
std::string normalize_disk(const mesh::TriMesh& m, const ConformalOptions& opt, const std::vector<int>& loop,
                           int first_boundary, mesh::UV& uv, Eigen::VectorXd& log_scale) {
  const int nv = m.num_vertices();
  std::string said;
  if (opt.center_vertex) {
    apply_disk_mobius(uv, Complex(uv(*opt.center_vertex, 0), uv(*opt.center_vertex, 1)), 0.0, &log_scale);
    said = "center vertex " + std::to_string(*opt.center_vertex) + " at 0";
  } else {
    center_disk(uv, m.F, mesh::face_areas(m), 1e-12, 200, &log_scale);
    said = "area centre of mass at 0";
  }
  BRENIER_CHECK(uv.allFinite(), "Moebius normalization produced non-finite positions");
  const int b = opt.boundary_vertex ? *opt.boundary_vertex : first_boundary;
  apply_disk_mobius(uv, 0.0, -std::atan2(uv(b, 1), uv(b, 0)));
  said += ", boundary vertex " + std::to_string(b) + " at 1";
  for (int v : loop) {  // keep the boundary exactly on the circle after the Moebius maps
    if (v >= nv) continue;  // a split point, not a mesh vertex
    const double r = std::hypot(uv(v, 0), uv(v, 1));
    uv.row(v) /= r;
  }
  return said;
}

}  // namespace

// Alg. 1 onto the disk: the discrete Yamabe flow with the boundary's curvature that of a
// polygon inscribed in a circle, the layout, the Moebius normalization, and the repair of
// folds that round-off leaves.
ConformalMap map_to_disk(const mesh::TriMesh& m, const ConformalOptions& opt) {
  mesh::require_domain(mesh::compute_topology(m), mesh::Domain::kDisk);
  const int nv = m.num_vertices();
  IntrinsicTriangulation T(m);
  const std::vector<char> on_boundary(T.boundary_vertex().begin(), T.boundary_vertex().end());
  check_disk_markers(opt, nv, on_boundary);
  FlowBoundary boundary(T, mesh::boundary_loops(m).at(0), nv);
  const int first_boundary = boundary.loop.front();
  Eigen::VectorXd u = Eigen::VectorXd::Zero(nv);
  boundary.refine(T, u, 2 * std::numbers::pi / 3);
  T.make_delaunay_isometric();
  const YamabeResult yr = disk_flow(T, boundary, u, opt);

  ConformalMap out;
  out.newton_iterations = yr.iterations;
  out.max_curvature_error = yr.residual;
  out.converged = yr.converged;
  out.flips = yr.flips;
  Eigen::VectorXd log_scale;
  mesh::UV uv = disk_layout(T, yr, boundary.loop, on_boundary, nv, log_scale);
  out.normalization = normalize_disk(m, opt, boundary.loop, first_boundary, uv, log_scale);
  out.positions = mesh::Vertices::Zero(nv, 3);
  out.positions.leftCols(2) = uv;
  std::vector<char> fixed(on_boundary.begin(), on_boundary.begin() + nv);
  // Round-off ears first (no Tutte solve can fix those), then true folds, then any ear the
  // repair left.
  fix_round_off_ears(m, out.positions, fixed);
  out.relaxed_vertices = repair_planar_folds(m, out.positions, fixed, out.folded_faces);
  if (out.folded_faces > 0) out.folded_faces -= fix_round_off_ears(m, out.positions, fixed);
  // g_surface = e^{2 lambda} |dz|^2 in the disk: lambda = -log(length scale).
  out.lambda = -log_scale;
  return out;
}

namespace {

// Positions of the punctured surface in the plane, puncture at infinity (sec. 3.2.5 through
// vertex scaling). Sending the puncture p to infinity (u_p -> infinity) keeps the triangles
// around it valid only if e^{u_i / 2} l_pi is the same for every neighbour i of p; in the
// limit they become half-strips and impose exactly this Dirichlet condition on the link:
//     u_i = -2 log l_pi + const,
// while every other vertex is flat (Kbar = 0). The result is the stereographic projection
// (from p) of the conformal map onto the sphere; for a mesh inscribed in a sphere it is the
// stereographic projection of the mesh itself (Moebius invariance of vertex scaling).
// Returns false when the flow is blocked by a degenerate link triangle.
bool punctured_plane(const mesh::TriMesh& m, int p, const mesh::CutHole& cut,
                     const std::vector<int>& link, const ConformalOptions& opt,
                     std::vector<Complex>& z, YamabeResult& yr) {
  const mesh::TriMesh& c = cut.mesh;
  const int nc = c.num_vertices();
  std::vector<char> fixed(nc, 0);
  Eigen::VectorXd u = Eigen::VectorXd::Zero(nc);
  double mean_log = 0;
  for (int i : link) mean_log += std::log((m.V.row(p) - m.V.row(cut.vertex_origin[i])).norm());
  mean_log /= static_cast<double>(link.size());
  for (int i : link) {
    fixed[i] = 1;
    u[i] = -2.0 * (std::log((m.V.row(p) - m.V.row(cut.vertex_origin[i])).norm()) - mean_log);
  }
  IntrinsicTriangulation T(c);
  T.make_delaunay_isometric();
  TargetCurvature flat = [](const IntrinsicTriangulation& tri, const Eigen::VectorXd&) {
    Target t;
    t.K = Eigen::VectorXd::Zero(tri.num_vertices());
    return t;
  };
  YamabeOptions yo;
  yo.tolerance = opt.tolerance;
  yo.max_iterations = opt.max_iterations;
  yo.progress = opt.progress;
  try {
    yr = solve_yamabe(T, flat, u, fixed, yo);
  } catch (const Error& e) {
    if (e.code() == ErrorCode::kCancelled) throw;
    return false;
  }
  if (!yr.converged) return false;  // blocked by a link triangle: the caller falls back
  z = layout(T, yr.u);
  return true;
}

}  // namespace

namespace {

ConformalMap sphere_with_puncture(const mesh::TriMesh& m, const ConformalOptions& opt, int p) {
  const int nv = m.num_vertices();
  mesh::CutHole cut = mesh::cut_hole(m, p);
  const std::vector<int> link = mesh::boundary_loops(cut.mesh).at(0);  // the puncture's link

  // The removed star becomes the cap around the north pole; rho gives the cap the star's
  // share of the area (the Moebius centring below corrects the rest).
  Eigen::VectorXd area = mesh::face_areas(m);
  double star = 0;
  for (int f = 0; f < m.num_faces(); ++f)
    if (m.F(f, 0) == p || m.F(f, 1) == p || m.F(f, 2) == p) star += area[f];
  double share = std::clamp(star / area.sum(), 1e-12, 0.5);
  double h = 1 - 2 * share;
  double rho = std::sqrt((1 + h) / (1 - h));

  ConformalMap out;
  std::vector<Complex> z;
  YamabeResult yr;
  Eigen::VectorXd plane_log_scale;  // log length scale, surface -> plane, per cut vertex
  if (punctured_plane(m, p, cut, link, opt, z, yr)) {
    z.resize(cut.mesh.num_vertices());
    Complex centre = 0;
    for (int i : link) centre += z[i];
    centre /= static_cast<double>(link.size());
    double radius = 0;
    for (int i : link) radius += std::abs(z[i] - centre);
    radius /= static_cast<double>(link.size());
    for (auto& w : z) w = (w - centre) * (rho / radius);
    plane_log_scale = (yr.u.head(cut.mesh.num_vertices()).array() + std::log(rho / radius)).matrix();
    out.newton_iterations = yr.iterations;
    out.max_curvature_error = yr.residual;
    out.converged = yr.converged;
    out.flips = yr.flips;
  } else {
    // Fallback: map the punctured surface onto the disk with its link on a circle (an
    // O(h) approximation near the puncture) and scale the disk to the cap's rim.
    ConformalOptions disk_opt;
    disk_opt.tolerance = opt.tolerance;
    disk_opt.max_iterations = opt.max_iterations;
    disk_opt.progress = opt.progress;
    ConformalMap disk = map_to_disk(cut.mesh, disk_opt);
    z.resize(cut.mesh.num_vertices());
    for (int i = 0; i < cut.mesh.num_vertices(); ++i)
      z[i] = rho * Complex(disk.positions(i, 0), disk.positions(i, 1));
    plane_log_scale = (std::log(rho) - disk.lambda.array()).matrix();
    out.newton_iterations = disk.newton_iterations;
    out.max_curvature_error = disk.max_curvature_error;
    out.converged = disk.converged;
    out.flips = disk.flips;
  }

  // Input faces the intrinsic flow folds are repaired in the plane, before the projection,
  // by the same mean-value Tutte embedding as for the disk (the link polygon held fixed).
  {
    const int nc = cut.mesh.num_vertices();
    mesh::Vertices P = mesh::Vertices::Zero(nc, 3);
    for (int i = 0; i < nc; ++i) P.row(i) << z[i].real(), z[i].imag(), 0.0;
    std::vector<char> fixed(nc, 0);
    for (int i : link) fixed[i] = 1;
    int folds = 0;
    out.relaxed_vertices += repair_planar_folds(cut.mesh, P, fixed, folds);
    for (int i = 0; i < nc; ++i) z[i] = Complex(P(i, 0), P(i, 1));
  }

  mesh::Vertices X(nv, 3);
  X.row(p) = Eigen::RowVector3d(0, 0, 1);
  for (int i = 0; i < cut.mesh.num_vertices(); ++i)
    // conj: the stereographic projection from the north pole reverses orientation, so a
    // counter-clockwise plane lands outward-facing on the sphere only after a reflection.
    X.row(cut.vertex_origin[i]) = inverse_stereographic(std::conj(z[i])).transpose();
  // log length scale, surface -> sphere: the plane's, then the inverse stereographic
  // projection's 2 / (1 + |z|^2), then the centring maps' (the puncture has none: its
  // factor is estimated from areas at the end).
  Eigen::VectorXd log_scale = Eigen::VectorXd::Constant(nv, std::numeric_limits<double>::quiet_NaN());
  for (int i = 0; i < cut.mesh.num_vertices(); ++i)
    log_scale[cut.vertex_origin[i]] = plane_log_scale[i] + std::log(2.0 / (1.0 + std::norm(z[i])));
  if (opt.sphere_markers) {
    auto [a, b, c] = *opt.sphere_markers;
    auto proj = [&](int v) { return stereographic(X.row(v).transpose()); };
    auto at_pole = [&](int v) { return X(v, 2) > 1 - 1e-15; };
    // w = (z - z1)(z2 - z3) / ((z - z3)(z2 - z1)) sends z1, z2, z3 to 0, 1, infinity.
    if (at_pole(a) || at_pole(b) || at_pole(c)) {
      center_sphere(X, m.F, area);  // moves the puncture off the pole
    }
    Complex z1 = proj(a), z2 = proj(b), z3 = proj(c);
    if (std::abs(z1 - z2) < 1e-300 || std::abs(z2 - z3) < 1e-300 || std::abs(z1 - z3) < 1e-300)
      invalid("sphere markers must be three different points");
    for (int v = 0; v < nv; ++v) {
      Complex w;
      if (X(v, 2) > 1 - 1e-15) {
        w = (z2 - z3) / (z2 - z1);
      } else if (v == c) {
        X.row(v) = Eigen::RowVector3d(0, 0, 1);
        continue;
      } else {
        Complex z = proj(v);
        w = (z - z1) * (z2 - z3) / ((z - z3) * (z2 - z1));
      }
      X.row(v) = inverse_stereographic(w).transpose();
    }
    out.normalization = "vertices " + std::to_string(a) + ", " + std::to_string(b) + ", " +
                        std::to_string(c) + " at 0, 1, infinity";
  } else {
    center_sphere(X, m.F, area, 1e-12, 200, &log_scale);
    out.normalization = "area centre of mass at the origin";
  }
  std::vector<char> fixed(nv, 0);
  if (opt.sphere_markers)
    for (int v : *opt.sphere_markers) fixed[v] = 1;
  out.relaxed_vertices += untangle(m, X, true, fixed, out.folded_faces);
  out.positions = X;
  mesh::TriMesh image{X, m.F};
  out.lambda = lambda_from_areas(m, image);
  if (!opt.sphere_markers)  // (with markers the plane Moebius map is not followed)
    for (int v = 0; v < nv; ++v)
      if (std::isfinite(log_scale[v])) out.lambda[v] = -log_scale[v];
  return out;
}

}  // namespace

ConformalMap map_to_sphere(const mesh::TriMesh& m, const ConformalOptions& opt,
                           std::optional<int> puncture) {
  mesh::require_domain(mesh::compute_topology(m), mesh::Domain::kSphere);
  const int nv = m.num_vertices();
  if (opt.sphere_markers)
    for (int v : *opt.sphere_markers)
      if (v < 0 || v >= nv) invalid("sphere marker " + std::to_string(v) + " is out of range");
  if (puncture) {
    if (*puncture < 0 || *puncture >= nv) invalid("puncture vertex " + std::to_string(*puncture) + " is out of range");
    return sphere_with_puncture(m, opt, *puncture);
  }
  // The default puncture first; if the map folds a face (the link of the puncture can come
  // out far from star-shaped, and on a coarse mesh a large triangle can invert under the
  // projection and centring), more candidates are tried -- the vertex of highest degree,
  // then vertices spread over the surface (farthest-point sampling from the first) -- and
  // the best map is kept. Measured on part.off (175 vertices): 98 of its 175 vertices give
  // a map without folds, so a few candidates suffice.
  constexpr int kCandidates = 8;
  int p0 = mesh::default_hole_vertex(m);
  ConformalMap best = sphere_with_puncture(m, opt, p0);
  if (best.folded_faces == 0 && best.converged) return best;
  std::vector<int> degree(nv, 0);
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) ++degree[m.F(f, k)];
  std::vector<int> tried{p0};
  const int p1 = static_cast<int>(std::max_element(degree.begin(), degree.end()) - degree.begin());
  std::vector<double> dist(nv, std::numeric_limits<double>::infinity());
  auto next_candidate = [&]() {
    if (tried.size() == 1 && p1 != p0) return p1;
    for (int v = 0; v < nv; ++v) dist[v] = std::min(dist[v], (m.V.row(v) - m.V.row(tried.back())).norm());
    return static_cast<int>(std::max_element(dist.begin(), dist.end()) - dist.begin());
  };
  for (int v = 0; v < nv; ++v) dist[v] = (m.V.row(v) - m.V.row(p0)).norm();
  while (static_cast<int>(tried.size()) < std::min(kCandidates, nv)) {
    int p = next_candidate();
    if (std::find(tried.begin(), tried.end(), p) != tried.end()) break;
    tried.push_back(p);
    ConformalMap c = sphere_with_puncture(m, opt, p);
    if ((c.converged && !best.converged) ||
        (c.converged == best.converged && c.folded_faces < best.folded_faces))
      best = std::move(c);
    if (best.folded_faces == 0 && best.converged) break;
  }
  return best;
}

}  // namespace brenier::conformal

#include "mesh/validate.hpp"

#include <algorithm>
#include <array>
#include <limits>
#include <cmath>
#include <numeric>
#include <queue>
#include <sstream>
#include <tuple>

#include "common/error.hpp"
#include "mesh/topology.hpp"

namespace brenier::mesh {
namespace {

std::string plural(int64_t n, const char* one, const char* many) {
  return std::to_string(n) + " " + (n == 1 ? one : many);
}

// Face f's triangles after a fan triangulation of polygon (v0, v1, ..., vk-1):
// (v0, vi, vi+1). Exact for convex polygons, which is what OBJ/OFF/PLY quads are in practice;
// the warning tells the user it happened.
void fan_triangulate(const PolygonSoup& soup, int64_t f, std::vector<int>& tris) {
  int64_t b = soup.face_offsets[f], e = soup.face_offsets[f + 1];
  for (int64_t i = b + 1; i + 1 < e; ++i) {
    tris.push_back(static_cast<int>(soup.indices[b]));
    tris.push_back(static_cast<int>(soup.indices[i]));
    tris.push_back(static_cast<int>(soup.indices[i + 1]));
  }
}

// Removes vertices no face uses and renumbers; returns how many were dropped and the first.
std::pair<int64_t, int> compact_vertices(TriMesh& m, std::vector<int>& origin) {
  std::vector<int> remap(m.V.rows(), -1);
  for (int f = 0; f < m.F.rows(); ++f)
    for (int k = 0; k < 3; ++k) remap[m.F(f, k)] = 0;
  int n = 0;
  int64_t dropped = 0;
  int first = -1;
  for (int i = 0; i < m.V.rows(); ++i) {
    if (remap[i] == 0) {
      remap[i] = n++;
    } else {
      ++dropped;
      if (first < 0) first = origin[i];
    }
  }
  if (dropped == 0) return {0, -1};
  Vertices V(n, 3);
  std::vector<int> new_origin(n);
  for (int i = 0; i < m.V.rows(); ++i)
    if (remap[i] >= 0) {
      V.row(remap[i]) = m.V.row(i);
      new_origin[remap[i]] = origin[i];
    }
  for (int f = 0; f < m.F.rows(); ++f)
    for (int k = 0; k < 3; ++k) m.F(f, k) = remap[m.F(f, k)];
  m.V = std::move(V);
  origin = std::move(new_origin);
  return {dropped, first};
}

void keep_faces(CleanMesh& cm, const std::vector<char>& keep) {
  int n = static_cast<int>(std::count(keep.begin(), keep.end(), 1));
  Faces F(n, 3);
  std::vector<int64_t> origin(n);
  int j = 0;
  for (int f = 0; f < cm.mesh.F.rows(); ++f)
    if (keep[f]) {
      F.row(j) = cm.mesh.F.row(f);
      origin[j++] = cm.face_origin[f];
    }
  cm.mesh.F = std::move(F);
  cm.face_origin = std::move(origin);
}

struct UnionFind {
  std::vector<int> parent;
  explicit UnionFind(int n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  int find(int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void unite(int a, int b) { parent[find(a)] = find(b); }
};

// Face and vertex numbers of the input file, as messages give them.
struct Names {
  const CleanMesh& cm;
  std::string face(int f) const { return std::to_string(cm.face_origin[f]); }
  std::string vertex(int v) const { return std::to_string(cm.vertex_origin[v]); }
};

// Components (faces connected through shared vertices). Keeps the largest when asked
// (and returns true: the caller checks the kept one afresh), else reports several.
bool check_components(CleanMesh& cm, const CleanOptions& opt) {
  TriMesh& m = cm.mesh;
  const int nv = static_cast<int>(m.V.rows()), nf = static_cast<int>(m.F.rows());
  UnionFind uf(nv);
  for (int f = 0; f < nf; ++f) {
    uf.unite(m.F(f, 0), m.F(f, 1));
    uf.unite(m.F(f, 1), m.F(f, 2));
  }
  std::vector<int> faces_in(nv, 0);
  for (int f = 0; f < nf; ++f) ++faces_in[uf.find(m.F(f, 0))];
  std::vector<std::pair<int, int>> comps;  // (faces, root)
  for (int v = 0; v < nv; ++v)
    if (uf.find(v) == v && faces_in[v] > 0) comps.push_back({faces_in[v], v});
  if (comps.size() <= 1) return false;
  std::sort(comps.rbegin(), comps.rend());
  std::ostringstream sizes;
  for (size_t i = 0; i < comps.size() && i < 5; ++i) sizes << (i ? ", " : "") << comps[i].first;
  if (comps.size() > 5) sizes << ", ...";
  if (opt.keep_largest_component) {
    const int root = comps[0].second;
    std::vector<char> keep(nf);
    for (int f = 0; f < nf; ++f) keep[f] = uf.find(m.F(f, 0)) == root;
    keep_faces(cm, keep);
    compact_vertices(m, cm.vertex_origin);
    cm.report.warn("components_dropped",
                   "kept the largest of " + std::to_string(comps.size()) + " components (" +
                       std::to_string(comps[0].first) + " faces) and dropped the others (faces: " + sizes.str() + ")",
                   static_cast<int64_t>(comps.size()) - 1);
    return true;
  }
  cm.report.error("several_components",
                  "mesh has " + std::to_string(comps.size()) + " connected components (faces: " + sizes.str() +
                      "); keep the largest with {keep_largest}",
                  static_cast<int64_t>(comps.size()));
  return false;
}

void check_zero_area(CleanMesh& cm, const CleanOptions& opt, const Names& name) {
  const TriMesh& m = cm.mesh;
  int64_t count = 0;
  int first = -1;
  for (int f = 0; f < m.F.rows(); ++f) {
    Eigen::Vector3d p0 = m.V.row(m.F(f, 0)), p1 = m.V.row(m.F(f, 1)), p2 = m.V.row(m.F(f, 2));
    double twice_area = (p1 - p0).cross(p2 - p0).norm();
    double lmax = std::max({(p1 - p0).squaredNorm(), (p2 - p1).squaredNorm(), (p0 - p2).squaredNorm()});
    if (!(twice_area > opt.zero_area_tolerance * lmax)) {
      if (first < 0) first = f;
      ++count;
    }
  }
  if (count > 0)
    cm.report.error("zero_area_face",
                    "face " + name.face(first) + " has zero area (collinear or coincident corners)" +
                        (count > 1 ? "; " + plural(count, "face", "faces") + " in all" : std::string()),
                    count);
}

// Edges used by more than two faces, and pairs of faces that traverse their shared edge in
// the same direction (the first of each, named).
struct EdgeCensus {
  int64_t nonmanifold = 0, same_dir = 0;
  std::string first_nm, first_dir;
};

EdgeCensus count_edges(const std::vector<EdgeUse>& uses, const Names& name) {
  EdgeCensus c;
  for (size_t i = 0; i < uses.size();) {
    size_t j = i;
    while (j < uses.size() && uses[j].a == uses[i].a && uses[j].b == uses[i].b) ++j;
    const size_t k = j - i;
    if (k > 2) {
      if (c.nonmanifold++ == 0) {
        std::ostringstream os;
        os << "edge (" << name.vertex(uses[i].a) << ", " << name.vertex(uses[i].b) << ") is shared by " << k << " faces:";
        for (size_t t = i; t < j && t < i + 6; ++t) os << " " << name.face(uses[t].face);
        c.first_nm = os.str();
      }
    } else if (k == 2 && uses[i].a_to_b == uses[i + 1].a_to_b) {
      if (c.same_dir++ == 0)
        c.first_dir = "faces " + name.face(uses[i].face) + " and " + name.face(uses[i + 1].face) +
                      " traverse their shared edge (" + name.vertex(uses[i].a) + ", " + name.vertex(uses[i].b) +
                      ") in the same direction";
    }
    i = j;
  }
  return c;
}

// Duplicate faces (same three vertices): they make every edge of theirs non-manifold or
// a closed two-face pocket, so name them explicitly.
void check_duplicate_faces(CleanMesh& cm, const Names& name) {
  const TriMesh& m = cm.mesh;
  const int nf = static_cast<int>(m.F.rows());
  std::vector<std::array<int, 4>> keyed(nf);
  for (int f = 0; f < nf; ++f) {
    std::array<int, 3> t = {m.F(f, 0), m.F(f, 1), m.F(f, 2)};
    std::sort(t.begin(), t.end());
    keyed[f] = {t[0], t[1], t[2], f};
  }
  std::sort(keyed.begin(), keyed.end());
  int64_t dups = 0;
  std::string first;
  for (int i = 1; i < nf; ++i)
    if (keyed[i][0] == keyed[i - 1][0] && keyed[i][1] == keyed[i - 1][1] && keyed[i][2] == keyed[i - 1][2]) {
      if (dups++ == 0)
        first = "faces " + name.face(keyed[i - 1][3]) + " and " + name.face(keyed[i][3]) + " have the same three vertices";
    }
  if (dups > 0)
    cm.report.error("duplicate_face", first + (dups > 1 ? "; " + plural(dups, "duplicate", "duplicates") + " in all" : ""),
                    dups);
}

// The number of fans of faces around vertex v (1 for a manifold vertex: one disk or
// half-disk), from the faces `around` it.
int fans_at(const TriMesh& m, int v, const int* around, int deg, std::vector<std::pair<int, int>>& spokes,
            std::vector<int>& parent) {
  spokes.clear();
  for (int t = 0; t < deg; ++t) {
    const int f = around[t];
    for (int k = 0; k < 3; ++k)
      if (m.F(f, k) == v) {
        spokes.push_back({m.F(f, (k + 1) % 3), t});
        spokes.push_back({m.F(f, (k + 2) % 3), t});
      }
  }
  std::sort(spokes.begin(), spokes.end());
  parent.resize(deg);
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (size_t s = 1; s < spokes.size(); ++s)
    if (spokes[s].first == spokes[s - 1].first) parent[find(spokes[s].second)] = find(spokes[s - 1].second);
  int fans = 0;
  for (int t = 0; t < deg; ++t) fans += find(t) == t;
  return fans;
}

// Non-manifold vertices: several fans meeting only at the vertex (a "bowtie").
void check_vertex_fans(CleanMesh& cm, const Names& name) {
  const TriMesh& m = cm.mesh;
  const int nv = static_cast<int>(m.V.rows()), nf = static_cast<int>(m.F.rows());
  std::vector<int> start(nv + 1, 0);
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) ++start[m.F(f, k) + 1];
  std::partial_sum(start.begin(), start.end(), start.begin());
  std::vector<int> around(start[nv]);
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) around[fill[m.F(f, k)]++] = f;
  int64_t bad = 0;
  int first = -1, first_fans = 0;
  std::vector<std::pair<int, int>> spokes;  // (other vertex, local face index)
  std::vector<int> parent;
  for (int v = 0; v < nv; ++v) {
    const int deg = start[v + 1] - start[v];
    if (deg <= 1) continue;
    const int fans = fans_at(m, v, &around[start[v]], deg, spokes, parent);
    if (fans > 1 && bad++ == 0) {
      first = v;
      first_fans = fans;
    }
  }
  if (bad > 0)
    cm.report.error("non_manifold_vertex",
                    "vertex " + name.vertex(first) + " joins " + std::to_string(first_fans) +
                        " separate fans of faces (surfaces touching at a point)" +
                        (bad > 1 ? "; " + plural(bad, "such vertex", "such vertices") + " in all" : std::string()),
                    bad);
}

// Each face's neighbour across each of its manifold edges (3f+k: the edge from corner k),
// and whether the two traverse it in the same direction.
struct FaceGraph {
  std::vector<int> nbr;
  std::vector<char> same;
};

FaceGraph face_graph(const TriMesh& m, const std::vector<EdgeUse>& uses) {
  const size_t nf = static_cast<size_t>(m.F.rows());
  FaceGraph g{std::vector<int>(3 * nf, -1), std::vector<char>(3 * nf, 0)};
  auto slot = [&](int f, int a, int b) {
    for (int k = 0; k < 3; ++k) {
      int u = m.F(f, k), w = m.F(f, (k + 1) % 3);
      if (std::min(u, w) == a && std::max(u, w) == b) return 3 * f + k;
    }
    return -1;
  };
  for (size_t i = 0; i + 1 < uses.size(); ++i)
    if (uses[i].a == uses[i + 1].a && uses[i].b == uses[i + 1].b &&
        (i + 2 >= uses.size() || uses[i + 2].a != uses[i].a || uses[i + 2].b != uses[i].b) &&
        (i == 0 || uses[i - 1].a != uses[i].a || uses[i - 1].b != uses[i].b)) {
      const int f = uses[i].face, h = uses[i + 1].face;
      const bool sd = uses[i].a_to_b == uses[i + 1].a_to_b;
      const int sf = slot(f, uses[i].a, uses[i].b), sh = slot(h, uses[i].a, uses[i].b);
      g.nbr[sf] = h;
      g.same[sf] = sd;
      g.nbr[sh] = f;
      g.same[sh] = sd;
    }
  return g;
}

// A breadth-first walk over faces sharing manifold edges decides, per face, whether it must
// be flipped so that neighbours traverse their shared edge in opposite directions. Returns
// -1 and the flips, or a face where a contradiction shows the surface non-orientable (a
// Moebius band).
int orient_walk(const FaceGraph& g, int nf, std::vector<int>& flip) {
  flip.assign(nf, -1);
  for (int s = 0; s < nf; ++s) {
    if (flip[s] >= 0) continue;
    flip[s] = 0;
    std::queue<int> q;
    q.push(s);
    while (!q.empty()) {
      const int f = q.front();
      q.pop();
      for (int k = 0; k < 3; ++k) {
        const int h = g.nbr[3 * f + k];
        if (h < 0) continue;
        const int want = flip[f] ^ g.same[3 * f + k];
        if (flip[h] < 0) {
          flip[h] = want;
          q.push(h);
        } else if (flip[h] != want) {
          return h;
        }
      }
    }
  }
  return -1;
}

// Flips the minority of each open component, so that most faces keep the input winding, and
// turns each closed component outward (positive enclosed signed volume). Returns the faces
// flipped.
int64_t apply_orientation(TriMesh& m, const FaceGraph& g, const std::vector<int>& flip) {
  const int nf = static_cast<int>(m.F.rows());
  UnionFind uf(nf);
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k)
      if (g.nbr[3 * f + k] >= 0) uf.unite(f, g.nbr[3 * f + k]);
  std::vector<int> flipped(nf, 0), total(nf, 0);
  std::vector<double> volume(nf, 0.0);
  std::vector<char> open(nf, 0);
  for (int f = 0; f < nf; ++f) {
    const int root = uf.find(f);
    ++total[root];
    flipped[root] += flip[f];
    Eigen::Vector3d p0 = m.V.row(m.F(f, 0)), p1 = m.V.row(m.F(f, 1)), p2 = m.V.row(m.F(f, 2));
    const double v = p0.dot(p1.cross(p2)) / 6.0;
    volume[root] += flip[f] ? -v : v;
    for (int k = 0; k < 3; ++k)
      if (g.nbr[3 * f + k] < 0) open[root] = 1;
  }
  int64_t n = 0;
  for (int f = 0; f < nf; ++f) {
    const int root = uf.find(f);
    const bool invert = open[root] ? 2 * flipped[root] > total[root] : volume[root] < 0;
    if (flip[f] != invert) {
      std::swap(m.F(f, 1), m.F(f, 2));
      ++n;
    }
  }
  return n;
}

void check_orientation(CleanMesh& cm, const CleanOptions& opt, const std::vector<EdgeUse>& uses, const EdgeCensus& e,
                       const Names& name) {
  TriMesh& m = cm.mesh;
  const FaceGraph g = face_graph(m, uses);
  std::vector<int> flip;
  const int bad_face = orient_walk(g, static_cast<int>(m.F.rows()), flip);
  if (bad_face >= 0) {
    cm.report.error("non_orientable",
                    "surface is non-orientable (no consistent orientation exists around face " + name.face(bad_face) + ")",
                    1);
  } else if (opt.fix_orientation) {
    const int64_t n = apply_orientation(m, g, flip);
    cm.report.warn("faces_reoriented", "flipped " + plural(n, "face", "faces") + " to orient the surface consistently", n);
  } else {
    cm.report.error("inconsistent_orientation",
                    e.first_dir +
                        (e.same_dir > 1 ? "; " + plural(e.same_dir, "such edge", "such edges") + " in all" : std::string()) +
                        "; fix with {fix_orientation}",
                    e.same_dir);
  }
}

// Checks that need only indices and geometry of a TriMesh with indices in range.
void check_trimesh(CleanMesh& cm, const CleanOptions& opt) {
  if (check_components(cm, opt)) return check_trimesh(cm, opt);  // again, on the kept component
  const Names name{cm};
  check_zero_area(cm, opt, name);
  const std::vector<EdgeUse> uses = sorted_edge_uses(cm.mesh.F);
  const EdgeCensus edges = count_edges(uses, name);
  check_duplicate_faces(cm, name);
  if (edges.nonmanifold > 0)
    cm.report.error("non_manifold_edge",
                    edges.first_nm +
                        (edges.nonmanifold > 1 ? "; " + plural(edges.nonmanifold, "such edge", "such edges") + " in all"
                                               : std::string()),
                    edges.nonmanifold);
  check_vertex_fans(cm, name);
  if (edges.same_dir > 0 && edges.nonmanifold == 0) check_orientation(cm, opt, uses, edges, name);
}

}  // namespace

namespace {

void check_coordinates(const PolygonSoup& soup, Report& r) {
  int64_t count = 0, first = -1;
  for (int64_t i = 0; i < static_cast<int64_t>(soup.positions.size()); ++i)
    if (!soup.positions[i].allFinite()) {
      if (first < 0) first = i;
      ++count;
    }
  if (count > 0)
    r.error("non_finite_coordinate",
            "vertex " + std::to_string(first) + " has a NaN or infinite coordinate" +
                (count > 1 ? "; " + plural(count, "vertex", "vertices") + " in all" : std::string()),
            count);
}

// The soup's faces checked (arity, index range, repeated corners) and triangulated by fans:
// triangles as index triples, with the input face of each.
struct Triangles {
  std::vector<int> corners;
  std::vector<int64_t> origin;
};

Triangles triangulate(const PolygonSoup& soup, Report& r) {
  const int64_t nv = static_cast<int64_t>(soup.positions.size()), nf = soup.num_faces();
  Triangles out;
  out.corners.reserve(static_cast<size_t>(nf) * 3);
  out.origin.reserve(static_cast<size_t>(nf));
  int64_t small = 0, out_of_range = 0, repeated = 0, polygons = 0;
  std::string first_small, first_range, first_repeat, first_poly;
  std::vector<int64_t> corner;
  for (int64_t f = 0; f < nf; ++f) {
    const int64_t b = soup.face_offsets[f], e = soup.face_offsets[f + 1], k = e - b;
    if (k < 3) {
      if (small++ == 0)
        first_small = "face " + std::to_string(f) + " has " + plural(k, "vertex", "vertices") + " (a face needs at least 3)";
      continue;
    }
    const auto bad = std::find_if(soup.indices.begin() + b, soup.indices.begin() + e,
                                  [&](int64_t i) { return i < 0 || i >= nv; });
    if (bad != soup.indices.begin() + e) {
      if (out_of_range++ == 0)
        first_range = "face " + std::to_string(f) + " refers to vertex " + std::to_string(*bad) +
                      " but the mesh has only " + plural(nv, "vertex", "vertices");
      continue;
    }
    corner.assign(soup.indices.begin() + b, soup.indices.begin() + e);
    std::sort(corner.begin(), corner.end());
    if (auto same = std::adjacent_find(corner.begin(), corner.end()); same != corner.end()) {
      if (repeated++ == 0)
        first_repeat = "face " + std::to_string(f) + " uses vertex " + std::to_string(*same) +
                       " more than once (degenerate face)";
      continue;
    }
    if (k > 3 && polygons++ == 0) first_poly = "face " + std::to_string(f) + " has " + std::to_string(k) + " vertices";
    const size_t before = out.corners.size();
    fan_triangulate(soup, f, out.corners);
    for (size_t t = before; t < out.corners.size(); t += 3) out.origin.push_back(f);
  }
  auto tail = [](int64_t n, const char* what) {
    return n > 1 ? "; " + std::to_string(n) + " " + what + " in all" : std::string();
  };
  if (small) r.error("face_too_small", first_small + tail(small, "such faces"), small);
  if (out_of_range) r.error("index_out_of_range", first_range + tail(out_of_range, "such faces"), out_of_range);
  if (repeated) r.error("degenerate_face", first_repeat + tail(repeated, "such faces"), repeated);
  if (polygons)
    r.warn("triangulated",
           "triangulated " + plural(polygons, "polygonal face", "polygonal faces") + " (first: " + first_poly +
               ") into triangles by fans",
           polygons);
  return out;
}

// Duplicate vertices (bit-identical positions): reported, or merged when asked (faces that
// collapse removed).
void check_duplicate_vertices(CleanMesh& cm, const CleanOptions& opt) {
  TriMesh& m = cm.mesh;
  const int64_t nv = m.V.rows();
  std::vector<int> order(nv);
  std::iota(order.begin(), order.end(), 0);
  auto key = [&](int i) { return std::make_tuple(m.V(i, 0), m.V(i, 1), m.V(i, 2)); };
  std::sort(order.begin(), order.end(), [&](int a, int b) { return key(a) != key(b) ? key(a) < key(b) : a < b; });
  std::vector<int> rep(nv);
  std::iota(rep.begin(), rep.end(), 0);
  int64_t dups = 0;
  int fa = -1, fb = -1;
  for (int64_t i = 1; i < nv; ++i)
    if (key(order[i]) == key(order[i - 1])) {
      rep[order[i]] = rep[order[i - 1]];
      if (dups++ == 0) {
        fa = rep[order[i]];
        fb = order[i];
      }
    }
  if (dups == 0) return;
  const std::string first = "vertex " + std::to_string(fb) + " has the same coordinates as vertex " + std::to_string(fa);
  if (!opt.merge_duplicates) {
    cm.report.warn("duplicate_vertices",
                   first + "; " + plural(dups, "duplicate vertex", "duplicate vertices") +
                       " in all (merge them with {merge_duplicates})",
                   dups);
    return;
  }
  for (int f = 0; f < m.F.rows(); ++f)
    for (int k = 0; k < 3; ++k) m.F(f, k) = rep[m.F(f, k)];
  std::vector<char> keep(m.F.rows(), 1);
  int64_t collapsed = 0;
  for (int f = 0; f < m.F.rows(); ++f)
    if (m.F(f, 0) == m.F(f, 1) || m.F(f, 1) == m.F(f, 2) || m.F(f, 2) == m.F(f, 0)) {
      keep[f] = 0;
      ++collapsed;
    }
  if (collapsed) keep_faces(cm, keep);
  cm.report.warn("duplicate_vertices_merged",
                 "merged " + plural(dups, "duplicate vertex", "duplicate vertices") + " (first: " + first + ")" +
                     (collapsed ? "; removed " + plural(collapsed, "face", "faces") + " that collapsed" : std::string()),
                 dups);
}

}  // namespace

CleanMesh clean(const TriMesh& mesh, const CleanOptions& options) {
  PolygonSoup soup;
  for (int i = 0; i < mesh.num_vertices(); ++i) soup.positions.push_back(mesh.V.row(i).transpose());
  for (int f = 0; f < mesh.num_faces(); ++f) {
    for (int k = 0; k < 3; ++k) soup.indices.push_back(mesh.F(f, k));
    soup.face_offsets.push_back(static_cast<int64_t>(soup.indices.size()));
  }
  return clean(soup, options);
}

CleanMesh clean(const PolygonSoup& soup, const CleanOptions& opt) {
  CleanMesh cm;
  Report& r = cm.report;
  const int64_t nv = static_cast<int64_t>(soup.positions.size());
  const int64_t nf = soup.num_faces();
  cm.input_vertices = nv;
  cm.input_faces = nf;
  if (nv == 0 || nf == 0) {
    r.error("empty_mesh", "mesh is empty (" + plural(nv, "vertex", "vertices") + ", " + plural(nf, "face", "faces") + ")");
    return cm;
  }
  if (nv > std::numeric_limits<int>::max() / 2 || nf > std::numeric_limits<int>::max() / 6) {
    r.error("too_large", "mesh is too large (" + std::to_string(nv) + " vertices, " + std::to_string(nf) + " faces)");
    return cm;
  }
  check_coordinates(soup, r);
  Triangles tris = triangulate(soup, r);
  if (r.has_errors()) return cm;

  TriMesh& m = cm.mesh;
  m.V.resize(nv, 3);
  for (int64_t i = 0; i < nv; ++i) m.V.row(i) = soup.positions[i].transpose();
  m.F = Eigen::Map<const Faces>(tris.corners.data(), static_cast<Eigen::Index>(tris.corners.size() / 3), 3);
  cm.vertex_origin.resize(nv);
  std::iota(cm.vertex_origin.begin(), cm.vertex_origin.end(), 0);
  cm.face_origin = std::move(tris.origin);
  check_duplicate_vertices(cm, opt);
  if (m.F.rows() == 0) {
    r.error("empty_mesh", "no face is left after removing collapsed faces");
    return cm;
  }
  // Unreferenced vertices: always dropped (they carry no area and no connectivity).
  auto [dropped, first] = compact_vertices(m, cm.vertex_origin);
  if (dropped > 0)
    r.warn("unreferenced_vertices",
           "dropped " + plural(dropped, "unreferenced vertex", "unreferenced vertices") + " (first: vertex " +
               std::to_string(first) + ")",
           dropped);
  check_trimesh(cm, opt);
  return cm;
}

CleanMesh load_mesh(const std::string& path, const CleanOptions& options,
                    std::optional<Format> format, const ReadLimits& limits) {
  return clean(read_soup_file(path, format, limits), options);
}

void require_valid(const CleanMesh& m, const std::string& what) {
  if (const Problem* p = m.report.first_error()) invalid(what + ": " + p->message);
}

Report validate(const TriMesh& mesh, const CleanOptions& options) {
  PolygonSoup soup;
  soup.positions.reserve(mesh.V.rows());
  for (int i = 0; i < mesh.V.rows(); ++i) soup.positions.push_back(mesh.V.row(i).transpose());
  soup.indices.reserve(static_cast<size_t>(mesh.F.rows()) * 3);
  for (int f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) soup.indices.push_back(mesh.F(f, k));
    soup.face_offsets.push_back(static_cast<int64_t>(soup.indices.size()));
  }
  CleanOptions o = options;
  o.merge_duplicates = false;
  o.keep_largest_component = false;
  o.fix_orientation = false;
  return clean(soup, o).report;
}

}  // namespace brenier::mesh

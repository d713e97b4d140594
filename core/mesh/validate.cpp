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

// Checks that need only indices and geometry of a TriMesh with indices in range.
void check_trimesh(CleanMesh& cm, const CleanOptions& opt) {
  TriMesh& m = cm.mesh;
  Report& r = cm.report;
  const int nv = static_cast<int>(m.V.rows());
  const int nf = static_cast<int>(m.F.rows());
  auto forig = [&](int f) { return std::to_string(cm.face_origin[f]); };
  auto vorig = [&](int v) { return std::to_string(cm.vertex_origin[v]); };

  // Components (faces connected through shared vertices).
  {
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
    if (comps.size() > 1) {
      std::sort(comps.rbegin(), comps.rend());
      std::ostringstream sizes;
      for (size_t i = 0; i < comps.size() && i < 5; ++i)
        sizes << (i ? ", " : "") << comps[i].first;
      if (comps.size() > 5) sizes << ", ...";
      if (opt.keep_largest_component) {
        int root = comps[0].second;
        std::vector<char> keep(nf);
        for (int f = 0; f < nf; ++f) keep[f] = uf.find(m.F(f, 0)) == root;
        keep_faces(cm, keep);
        compact_vertices(m, cm.vertex_origin);
        r.warn("components_dropped",
               "kept the largest of " + std::to_string(comps.size()) + " components (" +
                   std::to_string(comps[0].first) + " faces) and dropped the others (faces: " +
                   sizes.str() + ")",
               static_cast<int64_t>(comps.size()) - 1);
        check_trimesh(cm, opt);  // again, on the kept component
        return;
      }
      r.error("several_components",
              "mesh has " + std::to_string(comps.size()) + " connected components (faces: " +
                  sizes.str() + "); keep the largest with {keep_largest}",
              static_cast<int64_t>(comps.size()));
    }
  }

  // Zero-area faces.
  {
    int64_t count = 0;
    int first = -1;
    for (int f = 0; f < nf; ++f) {
      Eigen::Vector3d p0 = m.V.row(m.F(f, 0)), p1 = m.V.row(m.F(f, 1)), p2 = m.V.row(m.F(f, 2));
      double twice_area = (p1 - p0).cross(p2 - p0).norm();
      double lmax = std::max({(p1 - p0).squaredNorm(), (p2 - p1).squaredNorm(),
                              (p0 - p2).squaredNorm()});
      if (!(twice_area > opt.zero_area_tolerance * lmax)) {
        if (first < 0) first = f;
        ++count;
      }
    }
    if (count > 0)
      r.error("zero_area_face",
              "face " + forig(first) + " has zero area (collinear or coincident corners)" +
                  (count > 1 ? "; " + plural(count, "face", "faces") + " in all" : std::string()),
              count);
  }

  // Edges: duplicate faces, non-manifold edges, orientation.
  std::vector<EdgeUse> uses = sorted_edge_uses(m.F);
  int64_t nonmanifold = 0, same_dir = 0;
  std::string first_nm, first_dir;
  for (size_t i = 0; i < uses.size();) {
    size_t j = i;
    while (j < uses.size() && uses[j].a == uses[i].a && uses[j].b == uses[i].b) ++j;
    size_t k = j - i;
    if (k > 2) {
      if (nonmanifold++ == 0) {
        std::ostringstream os;
        os << "edge (" << vorig(uses[i].a) << ", " << vorig(uses[i].b) << ") is shared by " << k
           << " faces:";
        for (size_t t = i; t < j && t < i + 6; ++t) os << " " << forig(uses[t].face);
        first_nm = os.str();
      }
    } else if (k == 2 && uses[i].a_to_b == uses[i + 1].a_to_b) {
      if (same_dir++ == 0)
        first_dir = "faces " + forig(uses[i].face) + " and " + forig(uses[i + 1].face) +
                    " traverse their shared edge (" + vorig(uses[i].a) + ", " + vorig(uses[i].b) +
                    ") in the same direction";
    }
    i = j;
  }

  // Duplicate faces (same three vertices): they make every edge of theirs non-manifold or
  // a closed two-face pocket, so name them explicitly.
  {
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
      if (keyed[i][0] == keyed[i - 1][0] && keyed[i][1] == keyed[i - 1][1] &&
          keyed[i][2] == keyed[i - 1][2]) {
        if (dups++ == 0)
          first = "faces " + forig(keyed[i - 1][3]) + " and " + forig(keyed[i][3]) +
                  " have the same three vertices";
      }
    if (dups > 0)
      r.error("duplicate_face",
              first + (dups > 1 ? "; " + plural(dups, "duplicate", "duplicates") + " in all" : ""),
              dups);
  }

  if (nonmanifold > 0)
    r.error("non_manifold_edge",
            first_nm + (nonmanifold > 1 ? "; " + plural(nonmanifold, "such edge", "such edges") +
                                              " in all"
                                        : std::string()),
            nonmanifold);

  // Non-manifold vertices: the faces around a manifold vertex form one fan (one disk or
  // half-disk); several fans meeting only at the vertex (a "bowtie") is non-manifold.
  {
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
    std::vector<int> local_parent;
    for (int v = 0; v < nv; ++v) {
      int deg = start[v + 1] - start[v];
      if (deg <= 1) continue;
      spokes.clear();
      for (int t = 0; t < deg; ++t) {
        int f = around[start[v] + t];
        for (int k = 0; k < 3; ++k)
          if (m.F(f, k) == v) {
            spokes.push_back({m.F(f, (k + 1) % 3), t});
            spokes.push_back({m.F(f, (k + 2) % 3), t});
          }
      }
      std::sort(spokes.begin(), spokes.end());
      local_parent.resize(deg);
      std::iota(local_parent.begin(), local_parent.end(), 0);
      auto find = [&](int x) {
        while (local_parent[x] != x) x = local_parent[x] = local_parent[local_parent[x]];
        return x;
      };
      for (size_t s = 1; s < spokes.size(); ++s)
        if (spokes[s].first == spokes[s - 1].first)
          local_parent[find(spokes[s].second)] = find(spokes[s - 1].second);
      int fans = 0;
      for (int t = 0; t < deg; ++t) fans += find(t) == t;
      if (fans > 1) {
        if (bad++ == 0) {
          first = v;
          first_fans = fans;
        }
      }
    }
    if (bad > 0)
      r.error("non_manifold_vertex",
              "vertex " + vorig(first) + " joins " + std::to_string(first_fans) +
                  " separate fans of faces (surfaces touching at a point)" +
                  (bad > 1 ? "; " + plural(bad, "such vertex", "such vertices") + " in all"
                           : std::string()),
              bad);
  }

  // Orientation. A breadth-first walk over faces sharing manifold edges decides, per face,
  // whether it must be flipped so that neighbours traverse their shared edge in opposite
  // directions; a contradiction means the surface is non-orientable (a Moebius band).
  if (same_dir > 0 && nonmanifold == 0) {
    std::vector<int> nbr(3 * static_cast<size_t>(nf), -1);
    std::vector<char> same(3 * static_cast<size_t>(nf), 0);
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
        int f = uses[i].face, g = uses[i + 1].face;
        bool sd = uses[i].a_to_b == uses[i + 1].a_to_b;
        int sf = slot(f, uses[i].a, uses[i].b), sg = slot(g, uses[i].a, uses[i].b);
        nbr[sf] = g;
        same[sf] = sd;
        nbr[sg] = f;
        same[sg] = sd;
      }
    std::vector<int> flip(nf, -1);
    bool orientable = true;
    int bad_face = -1;
    for (int s = 0; s < nf && orientable; ++s) {
      if (flip[s] >= 0) continue;
      flip[s] = 0;
      std::queue<int> q;
      q.push(s);
      while (!q.empty() && orientable) {
        int f = q.front();
        q.pop();
        for (int k = 0; k < 3; ++k) {
          int g = nbr[3 * f + k];
          if (g < 0) continue;
          int want = flip[f] ^ same[3 * f + k];
          if (flip[g] < 0) {
            flip[g] = want;
            q.push(g);
          } else if (flip[g] != want) {
            orientable = false;
            bad_face = g;
            break;
          }
        }
      }
    }
    if (!orientable) {
      r.error("non_orientable",
              "surface is non-orientable (no consistent orientation exists around face " +
                  forig(bad_face) + ")",
              1);
    } else if (opt.fix_orientation) {
      // Flip the minority of each open component so that most faces keep the input winding.
      UnionFind uf(nf);
      for (int f = 0; f < nf; ++f)
        for (int k = 0; k < 3; ++k)
          if (nbr[3 * f + k] >= 0) uf.unite(f, nbr[3 * f + k]);
      std::vector<int> flipped(nf, 0), total(nf, 0);
      for (int f = 0; f < nf; ++f) {
        ++total[uf.find(f)];
        flipped[uf.find(f)] += flip[f];
      }
      // A closed component is then turned outward: positive enclosed (signed) volume.
      std::vector<double> volume(nf, 0.0);
      std::vector<char> open(nf, 0);
      for (int f = 0; f < nf; ++f) {
        Eigen::Vector3d p0 = m.V.row(m.F(f, 0)), p1 = m.V.row(m.F(f, 1)), p2 = m.V.row(m.F(f, 2));
        double v = p0.dot(p1.cross(p2)) / 6.0;
        volume[uf.find(f)] += flip[f] ? -v : v;
        for (int k = 0; k < 3; ++k)
          if (nbr[3 * f + k] < 0) open[uf.find(f)] = 1;
      }
      int64_t n = 0;
      for (int f = 0; f < nf; ++f) {
        int root = uf.find(f);
        bool invert = open[root] ? 2 * flipped[root] > total[root] : volume[root] < 0;
        if (flip[f] != invert) {
          std::swap(m.F(f, 1), m.F(f, 2));
          ++n;
        }
      }
      r.warn("faces_reoriented",
             "flipped " + plural(n, "face", "faces") + " to orient the surface consistently", n);
    } else {
      r.error("inconsistent_orientation",
              first_dir +
                  (same_dir > 1 ? "; " + plural(same_dir, "such edge", "such edges") + " in all"
                                : std::string()) +
                  "; fix with {fix_orientation}",
              same_dir);
    }
  }
}

}  // namespace

CleanMesh clean(const PolygonSoup& soup, const CleanOptions& opt) {
  CleanMesh cm;
  Report& r = cm.report;
  const int64_t nv = static_cast<int64_t>(soup.positions.size());
  const int64_t nf = soup.num_faces();
  cm.input_vertices = nv;
  cm.input_faces = nf;
  if (nv == 0 || nf == 0) {
    r.error("empty_mesh", "mesh is empty (" + plural(nv, "vertex", "vertices") + ", " +
                              plural(nf, "face", "faces") + ")");
    return cm;
  }
  if (nv > std::numeric_limits<int>::max() / 2 || nf > std::numeric_limits<int>::max() / 6) {
    r.error("too_large", "mesh is too large (" + std::to_string(nv) + " vertices, " +
                             std::to_string(nf) + " faces)");
    return cm;
  }

  // Coordinates.
  {
    int64_t count = 0, first = -1;
    for (int64_t i = 0; i < nv; ++i)
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

  // Faces: arity, index range, repeated corners; then triangulation.
  std::vector<int> tris;
  tris.reserve(static_cast<size_t>(nf) * 3);
  std::vector<int64_t> tri_origin;
  tri_origin.reserve(static_cast<size_t>(nf));
  int64_t small = 0, out_of_range = 0, repeated = 0, polygons = 0;
  std::string first_small, first_range, first_repeat, first_poly;
  std::vector<int64_t> corner;
  for (int64_t f = 0; f < nf; ++f) {
    int64_t b = soup.face_offsets[f], e = soup.face_offsets[f + 1];
    int64_t k = e - b;
    if (k < 3) {
      if (small++ == 0)
        first_small = "face " + std::to_string(f) + " has " + plural(k, "vertex", "vertices") +
                      " (a face needs at least 3)";
      continue;
    }
    bool ok = true;
    for (int64_t i = b; i < e; ++i)
      if (soup.indices[i] < 0 || soup.indices[i] >= nv) {
        if (out_of_range++ == 0)
          first_range = "face " + std::to_string(f) + " refers to vertex " +
                        std::to_string(soup.indices[i]) + " but the mesh has only " +
                        plural(nv, "vertex", "vertices");
        ok = false;
        break;
      }
    if (!ok) continue;
    corner.assign(soup.indices.begin() + b, soup.indices.begin() + e);
    std::sort(corner.begin(), corner.end());
    if (std::adjacent_find(corner.begin(), corner.end()) != corner.end()) {
      if (repeated++ == 0)
        first_repeat = "face " + std::to_string(f) + " uses vertex " +
                       std::to_string(*std::adjacent_find(corner.begin(), corner.end())) +
                       " more than once (degenerate face)";
      continue;
    }
    if (k > 3 && polygons++ == 0)
      first_poly = "face " + std::to_string(f) + " has " + std::to_string(k) + " vertices";
    size_t before = tris.size();
    fan_triangulate(soup, f, tris);
    for (size_t t = before; t < tris.size(); t += 3) tri_origin.push_back(f);
  }
  auto tail = [](int64_t n, const char* what) {
    return n > 1 ? "; " + std::to_string(n) + " " + what + " in all" : std::string();
  };
  if (small) r.error("face_too_small", first_small + tail(small, "such faces"), small);
  if (out_of_range)
    r.error("index_out_of_range", first_range + tail(out_of_range, "such faces"), out_of_range);
  if (repeated) r.error("degenerate_face", first_repeat + tail(repeated, "such faces"), repeated);
  if (polygons)
    r.warn("triangulated",
           "triangulated " + plural(polygons, "polygonal face", "polygonal faces") + " (first: " +
               first_poly + ") into triangles by fans",
           polygons);
  if (r.has_errors()) return cm;

  TriMesh& m = cm.mesh;
  m.V.resize(nv, 3);
  for (int64_t i = 0; i < nv; ++i) m.V.row(i) = soup.positions[i].transpose();
  m.F = Eigen::Map<const Faces>(tris.data(), static_cast<Eigen::Index>(tris.size() / 3), 3);
  cm.vertex_origin.resize(nv);
  std::iota(cm.vertex_origin.begin(), cm.vertex_origin.end(), 0);
  cm.face_origin = std::move(tri_origin);

  // Duplicate vertices: bit-identical positions.
  {
    std::vector<int> order(nv);
    std::iota(order.begin(), order.end(), 0);
    auto key = [&](int i) { return std::make_tuple(m.V(i, 0), m.V(i, 1), m.V(i, 2)); };
    std::sort(order.begin(), order.end(), [&](int a, int b) {
      return key(a) != key(b) ? key(a) < key(b) : a < b;
    });
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
    if (dups > 0) {
      std::string first = "vertex " + std::to_string(fb) + " has the same coordinates as vertex " +
                          std::to_string(fa);
      if (opt.merge_duplicates) {
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
        r.warn("duplicate_vertices_merged",
               "merged " + plural(dups, "duplicate vertex", "duplicate vertices") + " (first: " +
                   first + ")" +
                   (collapsed ? "; removed " + plural(collapsed, "face", "faces") +
                                    " that collapsed"
                              : std::string()),
               dups);
      } else {
        r.warn("duplicate_vertices",
               first + "; " + plural(dups, "duplicate vertex", "duplicate vertices") +
                   " in all (merge them with {merge_duplicates})",
               dups);
      }
    }
  }

  if (m.F.rows() == 0) {
    r.error("empty_mesh", "no face is left after removing collapsed faces");
    return cm;
  }

  // Unreferenced vertices: always dropped (they carry no area and no connectivity).
  {
    auto [dropped, first] = compact_vertices(m, cm.vertex_origin);
    if (dropped > 0)
      r.warn("unreferenced_vertices",
             "dropped " + plural(dropped, "unreferenced vertex", "unreferenced vertices") +
                 " (first: vertex " + std::to_string(first) + ")",
             dropped);
  }

  if (r.has_errors()) return cm;  // NaN coordinates: no geometric check makes sense
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

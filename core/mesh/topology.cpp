#include "mesh/topology.hpp"

#include <algorithm>
#include <numeric>
#include <tuple>
#include <unordered_map>

#include "common/error.hpp"

namespace brenier::mesh {

const char* class_name(MeshClass c) {
  switch (c) {
    case MeshClass::kDisk: return "disk";
    case MeshClass::kSphere: return "sphere";
    case MeshClass::kOther: return "other";
  }
  return "other";
}

namespace {

std::vector<std::vector<int>> loops_from(const std::vector<EdgeUse>& h);

}  // namespace

std::vector<EdgeUse> sorted_edge_uses(const Faces& F) {
  int nv = 0;
  for (int f = 0; f < F.rows(); ++f) nv = std::max({nv, F(f, 0) + 1, F(f, 1) + 1, F(f, 2) + 1});
  std::vector<int> start(static_cast<size_t>(nv) + 1, 0);
  for (int f = 0; f < F.rows(); ++f)
    for (int k = 0; k < 3; ++k) ++start[std::min(F(f, k), F(f, (k + 1) % 3)) + 1];
  for (int v = 0; v < nv; ++v) start[v + 1] += start[v];
  std::vector<EdgeUse> h(static_cast<size_t>(F.rows()) * 3);
  std::vector<int> fill(start.begin(), start.end() - 1);
  for (int f = 0; f < F.rows(); ++f)  // faces in order: each bucket is already by face
    for (int k = 0; k < 3; ++k) {
      int u = F(f, k), v = F(f, (k + 1) % 3);
      h[fill[std::min(u, v)]++] = {std::min(u, v), std::max(u, v), f, u < v};
    }
  auto before = [](const EdgeUse& x, const EdgeUse& y) { return x.b < y.b || (x.b == y.b && x.face < y.face); };
  for (int v = 0; v < nv; ++v)
    for (int i = start[v] + 1; i < start[v + 1]; ++i)
      for (int j = i; j > start[v] && before(h[j], h[j - 1]); --j) std::swap(h[j], h[j - 1]);
  return h;
}

std::vector<std::array<int, 3>> face_neighbors(const Faces& F) {
  std::vector<std::array<int, 3>> out(static_cast<size_t>(F.rows()), {-1, -1, -1});
  const std::vector<EdgeUse> h = sorted_edge_uses(F);
  auto slot = [&F](const EdgeUse& e) {  // k with (F(f, k), F(f, k + 1)) the edge (a, b)
    int k = 0;
    while (k < 2 && std::minmax(F(e.face, k), F(e.face, (k + 1) % 3)) != std::minmax(e.a, e.b)) ++k;
    return k;
  };
  for (size_t i = 0; i < h.size();) {
    size_t j = i;
    while (j < h.size() && h[j].a == h[i].a && h[j].b == h[i].b) ++j;
    if (j - i == 2) {
      out[static_cast<size_t>(h[i].face)][static_cast<size_t>(slot(h[i]))] = h[i + 1].face;
      out[static_cast<size_t>(h[i + 1].face)][static_cast<size_t>(slot(h[i + 1]))] = h[i].face;
    }
    i = j;
  }
  return out;
}

Topology compute_topology(const TriMesh& mesh) {
  Topology t;
  t.vertices = mesh.num_vertices();
  t.faces = mesh.num_faces();
  auto h = sorted_edge_uses(mesh.F);
  std::vector<int> used(t.vertices, 0);
  for (int f = 0; f < mesh.F.rows(); ++f)
    for (int k = 0; k < 3; ++k) used[mesh.F(f, k)] = 1;
  for (size_t i = 0; i < h.size();) {
    size_t j = i;
    while (j < h.size() && h[j].a == h[i].a && h[j].b == h[i].b) ++j;
    ++t.edges;
    if (j - i == 1) ++t.boundary_edges;
    if (j - i > 2) t.manifold = false;
    i = j;
  }
  t.euler = t.vertices - t.edges + t.faces;

  // Components over vertices that faces use (isolated vertices are their own components).
  std::vector<int> parent(t.vertices);
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (int f = 0; f < mesh.F.rows(); ++f) {
    parent[find(mesh.F(f, 0))] = find(mesh.F(f, 1));
    parent[find(mesh.F(f, 1))] = find(mesh.F(f, 2));
  }
  for (int v = 0; v < t.vertices; ++v) t.components += find(v) == v;

  if (t.manifold) {
    t.boundary_loops = static_cast<int>(loops_from(h).size());
    int twice_genus = 2 * t.components - t.euler - t.boundary_loops;
    t.genus = twice_genus >= 0 && twice_genus % 2 == 0 ? twice_genus / 2 : -1;
  } else {
    // Count loops as connected pieces of the boundary-edge graph.
    std::vector<int> bp(t.vertices);
    std::iota(bp.begin(), bp.end(), 0);
    auto bfind = [&](int x) {
      while (bp[x] != x) x = bp[x] = bp[bp[x]];
      return x;
    };
    std::vector<char> on_boundary(t.vertices, 0);
    for (size_t i = 0; i < h.size();) {
      size_t j = i;
      while (j < h.size() && h[j].a == h[i].a && h[j].b == h[i].b) ++j;
      if (j - i == 1) {
        bp[bfind(h[i].a)] = bfind(h[i].b);
        on_boundary[h[i].a] = on_boundary[h[i].b] = 1;
      }
      i = j;
    }
    for (int v = 0; v < t.vertices; ++v) t.boundary_loops += on_boundary[v] && bfind(v) == v;
    t.genus = -1;
  }

  if (t.manifold && t.components == 1 && t.genus == 0) {
    if (t.boundary_loops == 0) t.mesh_class = MeshClass::kSphere;
    if (t.boundary_loops == 1) t.mesh_class = MeshClass::kDisk;
  }
  return t;
}

std::vector<std::vector<int>> boundary_loops(const TriMesh& mesh) { return loops_from(sorted_edge_uses(mesh.F)); }

std::vector<char> boundary_flags(const TriMesh& mesh) {
  std::vector<char> flags(static_cast<size_t>(mesh.num_vertices()), 0);
  for (const auto& loop : boundary_loops(mesh))
    for (int v : loop) flags[static_cast<size_t>(v)] = 1;
  return flags;
}

namespace {

std::vector<std::vector<int>> loops_from(const std::vector<EdgeUse>& h) {
  // Boundary half-edges keyed by their start vertex. At a manifold boundary vertex exactly
  // one leaves; at a vertex where two boundary loops touch, several do, and each walk takes
  // the next unused one.
  std::unordered_map<int, std::vector<int>> out;
  std::vector<std::pair<int, int>> bnd;
  for (size_t i = 0; i < h.size();) {
    size_t j = i;
    while (j < h.size() && h[j].a == h[i].a && h[j].b == h[i].b) ++j;
    if (j - i == 1) {
      const int from = h[i].a_to_b ? h[i].a : h[i].b, to = h[i].a_to_b ? h[i].b : h[i].a;
      out[from].push_back(static_cast<int>(bnd.size()));
      bnd.push_back({from, to});
    }
    i = j;
  }
  std::vector<char> used(bnd.size(), 0);
  std::vector<std::vector<int>> loops;
  for (size_t s = 0; s < bnd.size(); ++s) {
    if (used[s]) continue;
    std::vector<int> loop;
    size_t e = s;
    while (!used[e]) {
      used[e] = 1;
      loop.push_back(bnd[e].first);
      auto it = out.find(bnd[e].second);
      if (it == out.end()) break;
      size_t next = e;
      for (int c : it->second)
        if (!used[c]) {
          next = static_cast<size_t>(c);
          break;
        }
      if (next == e) break;
      e = next;
    }
    loops.push_back(std::move(loop));
  }
  std::stable_sort(loops.begin(), loops.end(),
                   [](const auto& x, const auto& y) { return x.size() > y.size(); });
  return loops;
}

}  // namespace

std::string domain_mismatch(const Topology& t, Domain d) {
  auto describe = [&]() {
    if (!t.manifold) return std::string("a non-manifold mesh");
    if (t.components != 1) return "a mesh of " + std::to_string(t.components) + " components";
    return "a surface of genus " + std::to_string(t.genus) + " with " +
           std::to_string(t.boundary_loops) + " boundary loop" +
           (t.boundary_loops == 1 ? "" : "s");
  };
  if (d == Domain::kDisk) {
    if (t.mesh_class == MeshClass::kDisk) return {};
    if (t.mesh_class == MeshClass::kSphere)
      return "the disk domain needs a topological disk but the mesh is a closed genus-0 surface "
             "(open it with {cut_hole})";
    return "the disk domain needs a topological disk (genus 0, one boundary loop) but the mesh is " +
           describe();
  }
  if (t.mesh_class == MeshClass::kSphere) return {};
  return "the sphere domain needs a closed genus-0 surface but the mesh is " + describe();
}

void require_domain(const Topology& t, Domain d) {
  std::string why = domain_mismatch(t, d);
  if (!why.empty()) invalid(why);
}

}  // namespace brenier::mesh

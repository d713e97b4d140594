// CGAL's Surface_mesh from a TriMesh, and a SurfacePoint as CGAL's shortest-path code wants
// it (face and barycentric coordinates in CGAL's own corner order). Internal to the engine:
// included only by .cpp files that link CGAL.
#pragma once

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_shortest_path.h>

#include <string>
#include <utility>
#include <vector>

#include "common/error.hpp"
#include "mesh/mesh.hpp"

namespace brenier::mesh::cgal {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Surface = CGAL::Surface_mesh<Kernel::Point_3>;
using PathTraits = CGAL::Surface_mesh_shortest_path_traits<Kernel, Surface>;
using Paths = CGAL::Surface_mesh_shortest_path<PathTraits>;
using Location = std::pair<Surface::Face_index, PathTraits::Barycentric_coordinates>;

/// Vertex i of `m` is vertex index i of the result, face f face index f.
inline Surface to_surface_mesh(const TriMesh& m) {
  Surface sm;
  std::vector<Surface::Vertex_index> vs;
  for (int i = 0; i < m.num_vertices(); ++i) vs.push_back(sm.add_vertex(Kernel::Point_3(m.V(i, 0), m.V(i, 1), m.V(i, 2))));
  for (int f = 0; f < m.num_faces(); ++f)
    if (sm.add_face(vs[static_cast<size_t>(m.F(f, 0))], vs[static_cast<size_t>(m.F(f, 1))],
                    vs[static_cast<size_t>(m.F(f, 2))]) == Surface::null_face())
      fail(ErrorCode::kInternal, "CGAL surface: face " + std::to_string(f) + " is not manifold");
  return sm;
}

/// `p` (a point of m) as a location of sm = to_surface_mesh(m). CGAL's barycentric
/// coordinates follow its own corner cycle of each face, which may start at another corner:
/// the rotation that reproduces the point is taken.
inline Location location(const Surface& sm, const TriMesh& m, const SurfacePoint& p) {
  const Surface::Face_index f(static_cast<Surface::size_type>(p.face));
  PathTraits::Barycentric_coordinates b = {{0, 0, 0}};
  int k = 0;
  for (auto v : vertices_around_face(sm.halfedge(f), sm)) {
    for (int j = 0; j < 3; ++j)
      if (static_cast<int>(v.idx()) == m.F(p.face, j)) b[static_cast<size_t>(k)] = p.bary[j];
    ++k;
  }
  Eigen::Vector3d want = Eigen::Vector3d::Zero();
  for (int j = 0; j < 3; ++j) want += p.bary[j] * m.V.row(m.F(p.face, j)).transpose();
  for (size_t r = 0; r < 3; ++r) {
    const PathTraits::Barycentric_coordinates c = {{b[r], b[(r + 1) % 3], b[(r + 2) % 3]}};
    const Kernel::Point_3 q = Paths::point(f, c, sm);
    if ((Eigen::Vector3d(q.x(), q.y(), q.z()) - want).norm() <= 1e-9 * (1 + want.norm())) return {f, c};
  }
  fail(ErrorCode::kInternal, "CGAL surface: no corner order of face " + std::to_string(p.face) + " fits");
}

}  // namespace brenier::mesh::cgal

// Combinatorial topology of a triangle mesh: components, boundary loops, Euler
// characteristic, genus, and the class that decides which domain a mesh can be mapped to.
#pragma once

#include <array>
#include <string>
#include <vector>

#include "mesh/domain.hpp"
#include "mesh/mesh.hpp"

namespace brenier::mesh {

enum class MeshClass { kDisk, kSphere, kOther };

const char* class_name(MeshClass c);  // "disk", "sphere", "other"

struct Topology {
  int vertices = 0;
  int edges = 0;
  int faces = 0;
  int components = 0;
  int boundary_loops = 0;
  int boundary_edges = 0;
  int euler = 0;  // V - E + F
  /// Total genus (sum over components) from chi = sum_i (2 - 2 g_i - b_i); -1 when the mesh is
  /// not a manifold (then the formula does not apply).
  int genus = 0;
  bool manifold = true;  // every edge has 1 or 2 faces
  MeshClass mesh_class = MeshClass::kOther;
};

/// Preconditions: F indices in [0, #V). Works on any such mesh; genus and class are
/// meaningful for manifold meshes (class is kOther otherwise).
Topology compute_topology(const TriMesh& mesh);

/// One face's use of an undirected edge (a < b).
struct EdgeUse {
  int a, b;
  int face;
  bool a_to_b;  // the face traverses a -> b
};
/// All 3F edge uses, ordered by (a, b, face): a counting sort on a, then each vertex's few
/// uses by insertion sort -- linear in practice. Indices must be >= 0.
std::vector<EdgeUse> sorted_edge_uses(const Faces& F);

/// Per face f and k, the face across its edge (F(f, k), F(f, k + 1)) (the edge opposite corner
/// k + 2): -1 on the boundary and where more than two faces share the edge.
std::vector<std::array<int, 3>> face_neighbors(const Faces& F);

/// Boundary loops as vertex cycles, each traversed in the direction of its faces' winding
/// (for a counter-clockwise disk: counter-clockwise), longest loop first. Precondition: an
/// edge-manifold mesh.
std::vector<std::vector<int>> boundary_loops(const TriMesh& mesh);

/// 1 for each vertex on one of boundary_loops(mesh), else 0. Same precondition.
std::vector<char> boundary_flags(const TriMesh& mesh);

/// Whether a mesh of this topology can be mapped onto the domain, and if not, why; empty
/// string when it fits (a closed genus-0 mesh asked onto the disk is told to use cut_hole).
std::string domain_mismatch(const Topology& t, Domain d);

/// Throws Error(kInvalidArgument) with domain_mismatch()'s reason.
void require_domain(const Topology& t, Domain d);

}  // namespace brenier::mesh

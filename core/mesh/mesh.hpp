// Triangle meshes as the core sees them: libigl-style dense arrays, double precision.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <string>
#include <vector>

namespace brenier::mesh {

/// #V by 3 vertex positions, row-major so a row is one vertex.
using Vertices = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
/// #F by 3 vertex indices (0-based), counter-clockwise seen from outside.
using Faces = Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>;
/// #V by 2 texture / parameter coordinates.
using UV = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;

struct TriMesh {
  Vertices V;
  Faces F;
  int num_vertices() const { return static_cast<int>(V.rows()); }
  int num_faces() const { return static_cast<int>(F.rows()); }
};

/// A point of a triangle mesh: its face and barycentric coordinates (>= 0, summing to 1).
struct SurfacePoint {
  int face = -1;
  Eigen::Vector3d bary = Eigen::Vector3d(1, 0, 0);
};

/// A mesh exactly as a file stored it: positions and polygons of any size, before
/// triangulation or any check. Indices are 0-based but not yet range-checked.
struct PolygonSoup {
  std::vector<Eigen::Vector3d> positions;
  std::vector<int64_t> face_offsets{0};  // face f is indices[offsets[f] .. offsets[f+1])
  std::vector<int64_t> indices;
  int64_t num_faces() const { return static_cast<int64_t>(face_offsets.size()) - 1; }
};

/// One problem found in a mesh. Errors make the mesh unusable for computation; warnings
/// describe something that was repaired or is tolerable.
struct Problem {
  enum class Severity { kWarning, kError };
  Severity severity;
  std::string code;     // stable machine-readable name, e.g. "non_manifold_edge"
  std::string message;  // one line naming the element, e.g. "edge (3, 17) has 3 faces: 5, 9, 12"
  int64_t count = 1;    // how many elements have this problem
};

struct Report {
  std::vector<Problem> problems;
  void warn(std::string code, std::string message, int64_t count = 1);
  void error(std::string code, std::string message, int64_t count = 1);
  bool has_errors() const;
  /// The first error, or nullptr.
  const Problem* first_error() const;
};

}  // namespace brenier::mesh

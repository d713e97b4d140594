// Turning what a file holds into a mesh the algorithms may use, and saying exactly what is
// wrong with it otherwise (problem, element index, count).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "mesh/io.hpp"
#include "mesh/mesh.hpp"

namespace brenier::mesh {

struct CleanOptions {
  /// Merge vertices with bit-identical coordinates (STL-style soups, split seams).
  bool merge_duplicates = false;
  /// Keep the component with the most faces instead of refusing several components.
  bool keep_largest_component = false;
  /// Flip faces so that each component is consistently oriented (fails on a non-orientable
  /// surface) instead of refusing inconsistent orientation: closed components face outward
  /// (positive enclosed volume), open ones keep the winding of most of their faces.
  bool fix_orientation = false;
  /// A face is of zero area when twice its area <= tol * (its longest edge)^2, i.e. its
  /// smallest height is below tol times its longest edge.
  double zero_area_tolerance = 1e-12;
};

/// A triangle mesh together with where each element came from and what was found.
struct CleanMesh {
  TriMesh mesh;
  std::vector<int> vertex_origin;    // #V: index of each vertex in the input file
  std::vector<int64_t> face_origin;  // #F: index of the input polygon each triangle came from
  int64_t input_vertices = 0;
  int64_t input_faces = 0;
  Report report;
  bool valid() const { return !report.has_errors(); }
};

/// Checks and (as asked) repairs a polygon soup:
///  errors    empty mesh; NaN/Inf coordinates; faces with fewer than 3 vertices, an index
///            out of range or a repeated vertex; duplicate faces; non-manifold edges (3+
///            faces) and vertices (several fans); inconsistent orientation; non-orientable
///            surfaces; several components; zero-area faces;
///  warnings  polygons triangulated; duplicate vertices (merged when asked); unreferenced
///            vertices (always dropped); components dropped; faces re-oriented.
/// Never throws on bad content: everything goes into the report. When the report has
/// errors, `mesh` may be empty or partial and must not be used for computation.
CleanMesh clean(const PolygonSoup& soup, const CleanOptions& options = {});

/// The same checks for a triangle mesh built in memory (its vertices and faces as a soup).
CleanMesh clean(const TriMesh& mesh, const CleanOptions& options = {});

/// Reads and cleans a file; read failures (corrupt, truncated, unknown format) throw.
CleanMesh load_mesh(const std::string& path, const CleanOptions& options = {},
                    std::optional<Format> format = std::nullopt, const ReadLimits& limits = {});

/// Throws Error(kInvalidArgument) with the first error of the report, prefixed with `what`
/// (e.g. the file name), when the mesh is not valid.
void require_valid(const CleanMesh& m, const std::string& what = "mesh");

/// Checks a TriMesh built in memory (indices in range, finite coordinates, manifold,
/// oriented, one component, no zero-area face). Same report as clean().
Report validate(const TriMesh& mesh, const CleanOptions& options = {});

}  // namespace brenier::mesh

// Synthetic meshes with known answers, for tests and benchmarks: planar grids and disks,
// icospheres, hemispheres, tori, open cylinders.
#pragma once

#include "mesh/mesh.hpp"

namespace brenier::mesh {

/// Regular n by n grid of vertices on [0,1]^2 (z = 0), 2 (n-1)^2 triangles, counter-clockwise
/// seen from +z. A topological disk. Precondition: n >= 2.
TriMesh make_grid(int n);

/// Unit-radius planar disk: `rings` concentric rings around a centre vertex, ring k having
/// 6k vertices (a near-uniform triangulation). A topological disk. Precondition: rings >= 1.
TriMesh make_disk(int rings);

/// Icosahedron subdivided `level` times (each triangle into 4) and projected onto the unit
/// sphere: 10 * 4^level + 2 vertices, outward-facing. Precondition: 0 <= level <= 8.
TriMesh make_icosphere(int level);

/// Upper unit hemisphere (z >= 0) with `rings` rings of latitude between the pole and the
/// equator, ring k having 6k vertices; the equator is the boundary. Outward-facing.
TriMesh make_hemisphere(int rings);

/// Torus with major radius R, minor radius r, n by m vertices. Genus 1.
TriMesh make_torus(int n, int m, double R = 1.0, double r = 0.35);

/// Cylinder of radius `radius` and height `height` around the z axis with `around` vertices
/// per ring and `rings` rings (z from 0 to height). With `cap_bottom`, the z = 0 end is
/// closed by a centre vertex (then the mesh is a disk); otherwise it is an annulus.
TriMesh make_cylinder(int around, int rings, double radius, double height, bool cap_bottom);

/// Splits every triangle into four at its edge midpoints (no smoothing): a mesh with the
/// same geometry and about four times the vertices, for scaling benchmarks.
TriMesh subdivide_midpoint(const TriMesh& mesh);

}  // namespace brenier::mesh

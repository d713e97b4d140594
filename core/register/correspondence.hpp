// Step 3 of Alg. 7 (dissertation sec. 4.3): f = phi2^-1 o g o phi1. Once g has carried the
// source's domain points onto the target's domain, each is located in the target's domain
// mesh (the image of the target's triangles under phi2, which is a bijection onto the disk or
// the sphere), and its barycentric coordinates there place it on the target surface.
#pragma once

#include <Eigen/Core>
#include <array>
#include <memory>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::registration {

using mesh::SurfacePoint;

/// Locates each row of `points` in the domain mesh (F over `domain`: planar with z = 0, or on
/// the unit sphere): on the plane the triangle holding it, on the sphere the chord triangle
/// the ray from the centre through it crosses; a point in no triangle (outside the inscribed
/// polygon of the disk, by round-off on the sphere) gets the nearest point of the mesh.
std::vector<SurfacePoint> locate(const mesh::Faces& F, const mesh::Vertices& domain, const mesh::Vertices& points,
                                 bool sphere);

/// locate() with its search tree built once, for callers that locate many point sets in one
/// domain mesh (the isometric refinement, once per trial step). Keeps references to F and
/// `domain`, which must outlive it.
class DomainLocator {
 public:
  DomainLocator(const mesh::Faces& F, const mesh::Vertices& domain, bool sphere);
  ~DomainLocator();
  DomainLocator(const DomainLocator&) = delete;
  DomainLocator& operator=(const DomainLocator&) = delete;
  std::vector<SurfacePoint> operator()(const mesh::Vertices& points) const;

  /// The triangle holding x and its barycentric coordinates (on the plane, of (x, y); on the
  /// sphere, of the point where the ray from the centre through x crosses the chord
  /// triangle), found by walking from face `from` across the edge beyond which the point lies
  /// (a few faces for a point that moved a little; no tree query). False where the walk
  /// leaves the mesh, meets a triangle the ray misses or takes more than 64 faces: then ask
  /// operator().
  bool walk(int from, const Eigen::Vector3d& x, SurfacePoint& out) const;

 private:
  struct Tree;
  const mesh::Faces& F_;
  const mesh::Vertices& domain_;
  bool sphere_;
  std::unique_ptr<Tree> tree_;
  std::vector<std::array<int, 3>> neighbors_;  // the faces across each edge (mesh::face_neighbors)
};

/// The positions of surface points on a mesh: sum_i bary_i V[F(face, i)].
mesh::Vertices positions(const mesh::TriMesh& mesh, const std::vector<SurfacePoint>& points);

/// Faces of a morph (the source's faces over the positions `morph` on the target surface)
/// that turn over on the target: whose normal points against the target's normal at the
/// point of the target nearest the face's centroid and, given `corner_face` (per morph
/// vertex, the target face it lies on), also against the sum of the unit normals of the faces
/// under its three corners. A fold reverses the triangle against every estimate of the
/// surface's normal under it; the nearest face alone lies on one flank of a ridge or a curl
/// and counted unfolded chords (lion-head's curls), the corner faces alone are ambiguous at a
/// vertex (any of its faces holds it).
int flipped_morph_faces(const mesh::Faces& F, const mesh::Vertices& morph, const mesh::TriMesh& target,
                        const std::vector<int>& corner_face = {});

/// Faces of a correspondence that turn over on the target surface itself, read in a chart of
/// it: `chart` gives the target's vertices (target_F over them) under a bijective map onto the
/// disk (z = 0) or the unit sphere, such as the target's conformal map. Each source face's
/// corners, `points` on the target, go into the chart by their barycentric coordinates, and the
/// face counts where its orientation there is opposite to the orientation of the target's own
/// faces in the chart. A map of the source surface onto the target that is piecewise linear
/// in this chart is a bijection exactly where no face counts (and its boundary goes round
/// once), so unlike flipped_morph_faces this test does not count chords of a face that
/// span a curl of the target. It does count folds of any correspondence read this way: the
/// evaluation's nearest-point ground truth folds at lion-head's curls and counts there
/// (bench/RESULTS.md, session 37), and on crowded sphere charts the sign is round-off.
int chart_flipped_faces(const mesh::Faces& F, const std::vector<SurfacePoint>& points, const mesh::Faces& target_F,
                        const mesh::Vertices& chart, bool sphere);

}  // namespace brenier::registration

// An intrinsic triangulation of a mesh's vertex set: connectivity that changes by edge flips,
// with one length per edge, used by the discrete Yamabe flow (dissertation Alg. 1).
//
// Lengths follow the discrete conformal equivalence of Def. 3.4 in the form of Gillespie,
// Springborn and Crane ("Discrete conformal equivalence of polyhedral surfaces", 2021):
// each edge stores a base length eta_ij and the current length is
//     l_ij = eta_ij * exp((u_i + u_j) / 2)                                  (vertex scaling)
// for the conformal factors u. A flip of a non-Delaunay edge replaces eta by the Ptolemy
// relation eta_kl = (eta_ik eta_jl + eta_il eta_jk) / eta_ij, which does not depend on u
// (the exp factors cancel) and coincides with the isometric flip of Def. 3.4 (c) whenever the
// quadrilateral is cocircular, i.e. exactly when the flow crosses the Delaunay condition of
// Def. 3.3. Before the flow starts, the input is made intrinsically Delaunay with isometric
// (Euclidean) flips, so both definitions agree on the starting metric.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "mesh/mesh.hpp"

namespace brenier::conformal {

class IntrinsicTriangulation {
 public:
  /// Preconditions: an edge-manifold, consistently oriented mesh whose faces have positive
  /// area (mesh::clean() checks all of it).
  explicit IntrinsicTriangulation(const mesh::TriMesh& mesh);

  int num_vertices() const { return nv_; }
  int num_faces() const { return static_cast<int>(he_next_.size()) / 3; }
  int num_edges() const { return static_cast<int>(eta_.size()); }
  int num_halfedges() const { return static_cast<int>(he_next_.size()); }

  // Half-edge h runs from origin(h) to origin(next(h)); twin(h) = -1 on the boundary.
  int next(int h) const { return he_next_[h]; }
  int twin(int h) const { return he_twin_[h]; }
  int origin(int h) const { return he_origin_[h]; }
  int edge(int h) const { return he_edge_[h]; }
  int face(int h) const { return he_face_[h]; }
  int face_halfedge(int f) const { return face_he_[f]; }
  int edge_halfedge(int e) const { return edge_he_[e]; }
  bool on_boundary(int h) const { return he_twin_[h] < 0; }
  const std::vector<char>& boundary_vertex() const { return boundary_vertex_; }

  /// Current length of half-edge h's edge for conformal factors u (#V).
  double length(int h, const Eigen::VectorXd& u) const;
  /// The same from s = half_exp(u): eta_ij s_i s_j, one multiplication instead of an exp
  /// (the loops over every face or edge compute s once).
  double scaled_length(int h, const Eigen::VectorXd& s) const {
    return eta_[he_edge_[h]] * s[he_origin_[h]] * s[he_origin_[he_next_[h]]];
  }

  /// Flips interior edges until every one is Delaunay for the metric given by u (opposite
  /// angles summing to at most pi), using Ptolemy flips. Returns the number of flips; -1
  /// when a triangle violates the triangle inequality at a boundary edge, where no flip can
  /// repair it; -2 when more than 100 flips per edge were needed. The caller rejects such u.
  int make_delaunay(const Eigen::VectorXd& u);

  /// Isometric intrinsic Delaunay flips of the input metric (u = 0), done once at the start.
  int make_delaunay_isometric();

  /// Splits the boundary edge of half-edge h (i -> j, twin -1) at its midpoint in the
  /// metric of u: a new boundary vertex m with factor u_m = (u_i + u_j) / 2, current lengths
  /// l/2, l/2 and, to the opposite corner k, the median sqrt(2a^2 + 2b^2 - c^2) / 2
  /// (Stewart's theorem), stored as base lengths. The metric is unchanged. u is extended by
  /// u_m; returns m. Used where a boundary edge faces a nearly flat angle: no flip can ever
  /// repair a boundary triangle, so it gets room to change shape instead.
  int split_boundary_edge(int h, Eigen::VectorXd& u);

  /// Total number of flips done so far.
  long total_flips() const { return total_flips_; }

 private:
  void flip(int h, double new_eta);
  // Makes h0 -> h1 -> h2 the half-edge cycle of face f.
  void link_face(int f, int h0, int h1, int h2);
  bool is_delaunay(int h, const Eigen::VectorXd& s) const;
  template <typename NewLength>
  int flip_to_delaunay(const Eigen::VectorXd& u, NewLength new_eta);
  bool all_faces_valid(const Eigen::VectorXd& s) const;

  int nv_ = 0;
  std::vector<int> he_next_, he_twin_, he_origin_, he_edge_, he_face_;
  std::vector<int> face_he_;
  std::vector<int> edge_he_;  // one half-edge of each edge
  std::vector<double> eta_;   // base length of each edge
  std::vector<char> boundary_vertex_;
  long total_flips_ = 0;
};

/// s_i = exp(u_i / 2) per vertex: the current length of edge ij is eta_ij s_i s_j.
inline Eigen::VectorXd half_exp(const Eigen::VectorXd& u) { return (0.5 * u.array()).exp().matrix(); }

/// Angle opposite side a in a triangle of sides a, b, c; pi when a >= b + c, 0 when b or c
/// is too long. Stable for needle triangles (the half-angle formula of Kahan).
double corner_angle(double a, double b, double c);
/// cot of corner_angle(a, b, c) computed from the same quantities; +-infinity for degenerate
/// triangles.
double corner_cot(double a, double b, double c);

}  // namespace brenier::conformal

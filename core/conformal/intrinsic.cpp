#include "conformal/intrinsic.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <tuple>

#include "common/check.hpp"
#include "common/error.hpp"

namespace brenier::conformal {

namespace {
constexpr double kInf = std::numeric_limits<double>::infinity();

// tan(alpha / 2) for the angle alpha opposite side a: sqrt((s-b)(s-c) / (s (s-a))), with the
// factors formed as sums and differences of the sides so needles keep their precision.
double half_tan(double a, double b, double c) {
  double sa = -a + b + c, sb = a - b + c, sc = a + b - c, s = a + b + c;
  if (sa <= 0) return kInf;  // alpha = pi
  if (sb <= 0 || sc <= 0) return 0;
  return std::sqrt(sb * sc / (s * sa));
}
}  // namespace

double corner_angle(double a, double b, double c) {
  double t = half_tan(a, b, c);
  return t == kInf ? std::numbers::pi : 2.0 * std::atan(t);
}

double corner_cot(double a, double b, double c) {
  double t = half_tan(a, b, c);
  if (t == kInf) return -kInf;
  if (t == 0) return kInf;
  return (1.0 - t * t) / (2.0 * t);
}

IntrinsicTriangulation::IntrinsicTriangulation(const mesh::TriMesh& m) {
  nv_ = m.num_vertices();
  const int nf = m.num_faces();
  const int nh = 3 * nf;
  he_next_.resize(nh);
  he_twin_.assign(nh, -1);
  he_origin_.resize(nh);
  he_edge_.assign(nh, -1);
  he_face_.resize(nh);
  face_he_.resize(nf);
  for (int f = 0; f < nf; ++f) {
    face_he_[f] = 3 * f;
    for (int k = 0; k < 3; ++k) {
      he_next_[3 * f + k] = 3 * f + (k + 1) % 3;
      he_origin_[3 * f + k] = m.F(f, k);
      he_face_[3 * f + k] = f;
    }
  }
  // Twins by sorting (min, max, half-edge).
  std::vector<std::tuple<int, int, int>> key(nh);
  for (int h = 0; h < nh; ++h) {
    int a = he_origin_[h], b = he_origin_[he_next_[h]];
    key[h] = {std::min(a, b), std::max(a, b), h};
  }
  std::sort(key.begin(), key.end());
  boundary_vertex_.assign(nv_, 0);
  for (int i = 0; i < nh;) {
    int j = i;
    while (j < nh && std::get<0>(key[j]) == std::get<0>(key[i]) && std::get<1>(key[j]) == std::get<1>(key[i])) ++j;
    BRENIER_CHECK(j - i <= 2, "edge (" << std::get<0>(key[i]) << ", " << std::get<1>(key[i])
                                       << ") is non-manifold; validate the mesh first");
    int e = static_cast<int>(eta_.size());
    int h0 = std::get<2>(key[i]);
    Eigen::Vector3d pa = m.V.row(he_origin_[h0]), pb = m.V.row(he_origin_[he_next_[h0]]);
    eta_.push_back((pa - pb).norm());
    edge_he_.push_back(h0);
    he_edge_[h0] = e;
    if (j - i == 2) {
      int h1 = std::get<2>(key[i + 1]);
      BRENIER_CHECK(he_origin_[h0] != he_origin_[h1],
                    "faces " << h0 / 3 << " and " << h1 / 3 << " are inconsistently oriented");
      he_twin_[h0] = h1;
      he_twin_[h1] = h0;
      he_edge_[h1] = e;
    } else {
      boundary_vertex_[he_origin_[h0]] = 1;
      boundary_vertex_[he_origin_[he_next_[h0]]] = 1;
    }
    i = j;
  }
}

double IntrinsicTriangulation::length(int h, const Eigen::VectorXd& u) const {
  return eta_[he_edge_[h]] * std::exp(0.5 * (u[he_origin_[h]] + u[he_origin_[he_next_[h]]]));
}

bool IntrinsicTriangulation::is_delaunay(int h, const Eigen::VectorXd& s) const {
  int t = he_twin_[h];
  if (t < 0) return true;
  // Face A = (h, h1, h2), opposite corner at origin(h2); face B = (t, t1, t2), at origin(t2).
  int h1 = he_next_[h], h2 = he_next_[h1], t1 = he_next_[t], t2 = he_next_[t1];
  double l = scaled_length(h, s);
  double cot_a = corner_cot(l, scaled_length(h1, s), scaled_length(h2, s));
  double cot_b = corner_cot(l, scaled_length(t1, s), scaled_length(t2, s));
  // Def. 3.3: theta_k + theta_l <= pi  <=>  cot theta_k + cot theta_l >= 0. The small
  // tolerance keeps nearly cocircular quadrilaterals from flipping back and forth.
  // Relative to the cotangents themselves: slivers have cotangents of 1e4 whose sum carries
  // a round-off far above any absolute threshold, and would flip back and forth.
  double sum = cot_a + cot_b;
  if (std::isnan(sum)) return true;          // undefined: leave it, the caller rejects u
  if (!std::isfinite(sum)) return sum > 0;  // an angle of pi (cot = -inf) must flip
  return sum >= -1e-10 * std::max({1.0, std::abs(cot_a), std::abs(cot_b)});
}

void IntrinsicTriangulation::link_face(int f, int h0, int h1, int h2) {
  he_next_[h0] = h1;
  he_next_[h1] = h2;
  he_next_[h2] = h0;
  he_face_[h0] = he_face_[h1] = he_face_[h2] = f;
  face_he_[f] = h0;
}

void IntrinsicTriangulation::flip(int h, double new_eta) {
  // Before: face A = a0 (i->j), a1 (j->k), a2 (k->i); face B = t0 (j->i), t1 (i->l), t2 (l->j).
  // After:  face A = a0 (l->k), a2 (k->i), t1 (i->l); face B = t0 (k->l), t2 (l->j), a1 (j->k).
  int a0 = h, a1 = he_next_[a0], a2 = he_next_[a1];
  int t0 = he_twin_[h], t1 = he_next_[t0], t2 = he_next_[t1];
  int k = he_origin_[a2], l = he_origin_[t2];
  int fa = he_face_[a0], fb = he_face_[t0];
  link_face(fa, a0, a2, t1);
  link_face(fb, t0, t2, a1);
  he_origin_[a0] = l;
  he_origin_[t0] = k;
  eta_[he_edge_[h]] = new_eta;
  ++total_flips_;
}

int IntrinsicTriangulation::split_boundary_edge(int h, Eigen::VectorXd& u) {
  BRENIER_CHECK(he_twin_[h] < 0, "half-edge " << h << " is not on the boundary");
  BRENIER_CHECK(u.size() == nv_, "u has " << u.size() << " entries for " << nv_ << " vertices");
  const int h0 = h, h1 = he_next_[h0], h2 = he_next_[h1];
  const int i = he_origin_[h0], j = he_origin_[h1], k = he_origin_[h2];
  const double c = length(h0, u), a = length(h1, u), b = length(h2, u);
  const int m = nv_++;
  u.conservativeResize(nv_);
  u[m] = 0.5 * (u[i] + u[j]);
  // Base length of an edge (p, q) whose current length is l: l * exp(-(u_p + u_q) / 2).
  auto base = [&](double l, int p, int q) { return l * std::exp(-0.5 * (u[p] + u[q])); };
  boundary_vertex_.push_back(1);
  const int f2 = num_faces();
  const int n0 = num_halfedges(), n1 = n0 + 1, n2 = n0 + 2;
  for (int t = 0; t < 3; ++t) {
    he_next_.push_back(-1);
    he_twin_.push_back(-1);
    he_origin_.push_back(-1);
    he_edge_.push_back(-1);
    he_face_.push_back(f2);
  }
  face_he_.push_back(n1);
  const int f1 = he_face_[h0];
  // Face f1 = (i, m, k): h0 (i->m), n0 (m->k), h2 (k->i).
  // Face f2 = (m, j, k): n1 (m->j), h1 (j->k), n2 (k->m).
  link_face(f1, h0, n0, h2);
  link_face(f2, n1, h1, n2);
  he_origin_[n0] = m;
  he_origin_[n1] = m;
  he_origin_[n2] = k;
  he_twin_[n0] = n2;
  he_twin_[n2] = n0;
  eta_[he_edge_[h0]] = base(0.5 * c, i, m);
  he_edge_[n1] = static_cast<int>(eta_.size());
  eta_.push_back(base(0.5 * c, m, j));
  edge_he_.push_back(n1);
  he_edge_[n0] = he_edge_[n2] = static_cast<int>(eta_.size());
  eta_.push_back(base(0.5 * std::sqrt(std::max(0.0, 2 * a * a + 2 * b * b - c * c)), m, k));
  edge_he_.push_back(n0);
  return m;
}

bool IntrinsicTriangulation::all_faces_valid(const Eigen::VectorXd& s) const {
  int invalid = 0;
#pragma omp parallel for schedule(static) reduction(+ : invalid)
  for (int f = 0; f < num_faces(); ++f) {
    int h0 = face_he_[f], h1 = he_next_[h0], h2 = he_next_[h1];
    double a = scaled_length(h0, s), b = scaled_length(h1, s), c = scaled_length(h2, s);
    invalid += !(a < b + c && b < a + c && c < a + b);
  }
  return invalid == 0;
}

template <typename NewLength>
int IntrinsicTriangulation::flip_to_delaunay(const Eigen::VectorXd& u, NewLength new_eta) {
  const Eigen::VectorXd s = half_exp(u);
  // The first pass over every edge runs in parallel; the flips and the edges they affect
  // are then handled one at a time.
  const int ne = num_edges();
  std::vector<char> queued(ne, 0);
#pragma omp parallel for schedule(static)
  for (int e = 0; e < ne; ++e) queued[e] = he_twin_[edge_he_[e]] >= 0 && !is_delaunay(edge_he_[e], s);
  std::vector<int> stack;
  for (int e = ne - 1; e >= 0; --e)
    if (queued[e]) stack.push_back(e);
  int flips = 0;
  const long cap = 100L * static_cast<long>(eta_.size()) + 1000;
  while (!stack.empty()) {
    int e = stack.back();
    stack.pop_back();
    queued[e] = 0;
    int h = edge_he_[e];
    if (he_twin_[h] < 0 || is_delaunay(h, s)) continue;
    int a1 = he_next_[h], a2 = he_next_[a1], t1 = he_next_[he_twin_[h]], t2 = he_next_[t1];
    flip(h, new_eta(h, a1, a2, t1, t2));
    // A metric far from the current one can need very many flips (or round-off can make
    // nearly cocircular quadrilaterals cycle); give up and let the caller reject it. The
    // triangulation stays a valid one of the same Penner coordinates.
    if (++flips > cap) return -2;
    for (int g : {a1, a2, t1, t2}) {
      int ge = he_edge_[g];
      if (!queued[ge]) {
        queued[ge] = 1;
        stack.push_back(ge);
      }
    }
  }
  return all_faces_valid(s) ? flips : -1;
}

int IntrinsicTriangulation::make_delaunay(const Eigen::VectorXd& u) {
  // Ptolemy flip in base lengths (independent of u):
  // eta_kl = (eta_ik eta_jl + eta_il eta_jk) / eta_ij.
  return flip_to_delaunay(u, [&](int h, int a1, int a2, int t1, int t2) {
    return (eta_[he_edge_[a2]] * eta_[he_edge_[t2]] + eta_[he_edge_[t1]] * eta_[he_edge_[a1]]) /
           eta_[he_edge_[h]];
  });
}

int IntrinsicTriangulation::make_delaunay_isometric() {
  Eigen::VectorXd zero = Eigen::VectorXd::Zero(nv_);
  // Euclidean flip: lay the two triangles out around vertex i = origin(h) and measure k-l:
  // l_kl^2 = l_ik^2 + l_il^2 - 2 l_ik l_il cos(angle_A(i) + angle_B(i)).
  return flip_to_delaunay(zero, [&](int h, int a1, int a2, int t1, int t2) {
    double lij = eta_[he_edge_[h]], ljk = eta_[he_edge_[a1]], lki = eta_[he_edge_[a2]];
    double lil = eta_[he_edge_[t1]], llj = eta_[he_edge_[t2]];
    double angle = corner_angle(ljk, lij, lki) + corner_angle(llj, lij, lil);
    double sq = lki * lki + lil * lil - 2 * lki * lil * std::cos(angle);
    return std::sqrt(std::max(sq, 0.0));
  });
}

}  // namespace brenier::conformal

// Geodesic distance fields (geodesics.hpp): the heat method and CGAL's exact geodesics.
#include "mesh/geodesics.hpp"

#include <Eigen/CholmodSupport>
#include <Eigen/Geometry>
#include <Eigen/SparseCore>
#include <algorithm>
#include <array>
#include <omp.h>
#include <tuple>
#include <cmath>

#include "common/error.hpp"
#include "common/parallel.hpp"
#include "conformal/intrinsic.hpp"
#include "mesh/cgal_surface.hpp"

namespace brenier::mesh {

using Sparse = Eigen::SparseMatrix<double>;

namespace {

// One solving lane's CHOLMOD state: its own cholmod_common and the result and workspace that
// cholmod_solve2 reuses (Eigen's solve() allocates both afresh for every call, and for tens of
// megabytes per block of sources those allocations, mmap then page faults, cost more than the
// solves did). Lanes solve with one shared, read-only factor at the same time.
class SolveLane {
 public:
  SolveLane() { cholmod_start(&common_); }
  SolveLane(const SolveLane&) = delete;
  SolveLane& operator=(const SolveLane&) = delete;
  ~SolveLane() {
    for (cholmod_dense** d : {&x_, &y_, &e_})
      if (*d) cholmod_free_dense(d, &common_);
    cholmod_finish(&common_);
  }
  /// out = A^-1 B for the factor L of A.
  void solve_into(cholmod_factor* L, Eigen::MatrixXd& B, Eigen::MatrixXd& out) {
    cholmod_dense b = Eigen::viewAsCholmod(B);
    if (!cholmod_solve2(CHOLMOD_A, L, &b, nullptr, &x_, nullptr, &y_, &e_, &common_))
      fail(ErrorCode::kInternal, "heat geodesics: CHOLMOD's solve failed");
    out = Eigen::Map<const Eigen::MatrixXd, 0, Eigen::OuterStride<>>(static_cast<const double*>(x_->x),
                                                                      static_cast<Eigen::Index>(x_->nrow),
                                                                      static_cast<Eigen::Index>(x_->ncol),
                                                                      Eigen::OuterStride<>(static_cast<Eigen::Index>(x_->d)));
  }

 private:
  cholmod_common common_;
  cholmod_dense *x_ = nullptr, *y_ = nullptr, *e_ = nullptr;
};

// A CHOLMOD factorization whose factor the lanes share.
class Cholesky : public Eigen::CholmodDecomposition<Sparse> {
 public:
  cholmod_factor* factor() const { return m_cholmodFactor; }
};

// One lane's buffers for a block of sources, kept between blocks, and its two solvers.
struct Lane {
  Eigen::MatrixXd U0, U, div, rhs, phi;
  SolveLane heat, poisson;
};

}  // namespace

struct HeatGeodesics::Impl {
  const TriMesh* mesh = nullptr;
  // The intrinsic Delaunay triangulation of the mesh (same vertices, same metric), each
  // triangle laid out in its own plane: corner c of face f at layout[f][c].
  std::vector<std::array<int, 3>> tri;
  std::vector<std::array<Eigen::Vector2d, 3>> layout;
  std::vector<Eigen::Vector3d> cot;  // per face, at each corner
  Cholesky heat, poisson;  // M + t L, and L without vertex 0 (held at phi = 0)
  std::vector<std::unique_ptr<Lane>> lanes;  // per thread solving blocks, made on first use
};

namespace {

void factor(Cholesky& c, const Sparse& A, const char* what) {
  c.setMode(Eigen::CholmodSupernodalLLt);
  c.cholmod().print = 0;
  with_library_loops_serial([&] { c.compute(A); });
  if (c.info() != Eigen::Success)
    fail(ErrorCode::kInternal, std::string("heat geodesics: the ") + what + " system is not positive definite");
}

// The gradient of corner c's barycentric coordinate on a laid-out triangle of twice-area a2:
// the opposite edge turned a quarter counter-clockwise, over a2.
Eigen::Vector2d grad_lambda(const std::array<Eigen::Vector2d, 3>& P, int c, double a2) {
  const Eigen::Vector2d e = P[static_cast<size_t>((c + 2) % 3)] - P[static_cast<size_t>((c + 1) % 3)];
  return Eigen::Vector2d(-e.y(), e.x()) / a2;
}

}  // namespace

namespace {

struct Layout {  // the intrinsic triangulation's faces, laid out (HeatGeodesics::Impl)
  const std::vector<std::array<int, 3>>& tri;
  const std::vector<std::array<Eigen::Vector2d, 3>>& layout;
  const std::vector<Eigen::Vector3d>& cot;
};

// Steps 2 and 3 of the heat method for the columns of U: the normalized field per face,
// X = -grad u / |grad u|, and its integrated divergence per vertex
//   (div X)_i = 1/2 sum over faces at i of cot(angle at l) (e_ij . X) + cot(angle at j) (e_il . X)
// (the cotangent formula of the paper). Faces add into their corners, so the columns run in
// parallel when `parallel`, each over all faces in order.
void divergence(const Layout& s, const Eigen::MatrixXd& U, Eigen::MatrixXd& div, bool parallel) {
  const int nf = static_cast<int>(s.tri.size());
  div.setZero(U.rows(), U.cols());
#pragma omp parallel for schedule(static) if (parallel)
  for (Eigen::Index c = 0; c < U.cols(); ++c) {
    for (int f = 0; f < nf; ++f) {
      const auto& t = s.tri[static_cast<size_t>(f)];
      const auto& P = s.layout[static_cast<size_t>(f)];
      const double a2 = P[1].x() * P[2].y();
      Eigen::Vector2d g = Eigen::Vector2d::Zero();
      for (int k = 0; k < 3; ++k) g += U(t[static_cast<size_t>(k)], c) * grad_lambda(P, k, a2);
      const double gn = g.norm();
      if (!(gn > 0)) continue;
      const Eigen::Vector2d X = -g / gn;
      const Eigen::Vector3d& ct = s.cot[static_cast<size_t>(f)];
      for (int k = 0; k < 3; ++k) {
        const size_t i = static_cast<size_t>(k), j = static_cast<size_t>((k + 1) % 3), l = static_cast<size_t>((k + 2) % 3);
        div(t[i], c) += 0.5 * (ct[static_cast<Eigen::Index>(l)] * (P[j] - P[i]).dot(X) +
                               ct[static_cast<Eigen::Index>(j)] * (P[l] - P[i]).dot(X));
      }
    }
  }
}

}  // namespace

// The Laplacian is built on the intrinsic Delaunay triangulation (Sharp, Soliman and Crane,
// "Navigating intrinsic triangulations", 2019): on real meshes with obtuse corners the
// extrinsic cotangent weights go negative, the heat solve then loses the far field to
// cancellation (u decays like exp(-r / sqrt t)), and whole distance fields came out wrong
// (lion-head from vertex 34: 0.04 where the exact distance is 1.21). Intrinsic Delaunay
// weights are non-negative at interior edges, so M + t L is an M-matrix.
HeatGeodesics::HeatGeodesics(const TriMesh& m, double time_factor) : impl_(std::make_unique<Impl>()) {
  Impl& s = *impl_;
  s.mesh = &m;
  const int nv = m.num_vertices();
  if (nv < 2 || m.num_faces() < 1) invalid("heat geodesics: the mesh has no faces");
  conformal::IntrinsicTriangulation it(m);
  if (it.make_delaunay_isometric() < 0) fail(ErrorCode::kInternal, "heat geodesics: no intrinsic Delaunay triangulation");
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(nv);
  const int nf = it.num_faces();
  s.tri.resize(static_cast<size_t>(nf));
  s.layout.resize(static_cast<size_t>(nf));
  s.cot.resize(static_cast<size_t>(nf));
  std::vector<Eigen::Triplet<double>> L, Lheld;
  Eigen::VectorXd mass = Eigen::VectorXd::Zero(nv);
  double edge_sum = 0;
  for (int f = 0; f < nf; ++f) {
    const int h0 = it.face_halfedge(f), h1 = it.next(h0), h2 = it.next(h1);
    const double l0 = it.length(h0, zero), l1 = it.length(h1, zero), l2 = it.length(h2, zero);  // ij, jk, ki
    s.tri[static_cast<size_t>(f)] = {it.origin(h0), it.origin(h1), it.origin(h2)};
    const double x = (l0 * l0 + l2 * l2 - l1 * l1) / (2 * l0), y = std::sqrt(std::max(0.0, l2 * l2 - x * x));
    s.layout[static_cast<size_t>(f)] = {Eigen::Vector2d(0, 0), Eigen::Vector2d(l0, 0), Eigen::Vector2d(x, y)};
    if (!(y > 0)) invalid("heat geodesics: face " + std::to_string(f) + " has zero area");
    // Corner c faces the edge of lengths {l1, l2, l0}[c].
    const double opposite[3] = {l1, l2, l0}, side_a[3] = {l0, l0, l1}, side_b[3] = {l2, l1, l2};
    for (int c = 0; c < 3; ++c) s.cot[static_cast<size_t>(f)][c] = conformal::corner_cot(opposite[c], side_a[c], side_b[c]);
    edge_sum += l0 + l1 + l2;
    const auto& t = s.tri[static_cast<size_t>(f)];
    for (int c = 0; c < 3; ++c) {
      mass[t[static_cast<size_t>(c)]] += l0 * y / 6;
      const int j = t[static_cast<size_t>((c + 1) % 3)], l = t[static_cast<size_t>((c + 2) % 3)];
      const double w = s.cot[static_cast<size_t>(f)][c] / 2;  // the triangle's stiffness matrix
      for (const auto& [a, b, v] : {std::tuple{j, j, w}, std::tuple{l, l, w}, std::tuple{j, l, -w}, std::tuple{l, j, -w}}) {
        L.emplace_back(a, b, v);
        if (a != 0 && b != 0) Lheld.emplace_back(a - 1, b - 1, v);
      }
    }
  }
  const double h = edge_sum / (3.0 * nf), t = time_factor * h * h;
  Sparse A(nv, nv), P(nv - 1, nv - 1);
  for (auto& e : L) e = Eigen::Triplet<double>(e.row(), e.col(), t * e.value());
  for (int i = 0; i < nv; ++i) L.emplace_back(i, i, mass[i]);
  A.setFromTriplets(L.begin(), L.end());
  P.setFromTriplets(Lheld.begin(), Lheld.end());
  single_threaded_blas();
  factor(s.heat, A, "heat");
  factor(s.poisson, P, "Poisson");
}

HeatGeodesics::~HeatGeodesics() = default;

Eigen::MatrixXd HeatGeodesics::distances(const std::vector<SurfacePoint>& sources) {
  Eigen::MatrixXd D;
  distances(sources, D);
  return D;
}

void HeatGeodesics::distances(const std::vector<SurfacePoint>& sources, Eigen::MatrixXd& D) {
  Impl& s = *impl_;
  const TriMesh& m = *s.mesh;
  const int nv = m.num_vertices(), ns = static_cast<int>(sources.size());
  for (const SurfacePoint& p : sources)
    if (p.face < 0 || p.face >= m.num_faces()) fail(ErrorCode::kInternal, "heat geodesics: a source's face is out of range");
  D.resize(nv, ns);
  // Sources go through the solves in blocks of up to 8 (a multi-column solve runs in BLAS 3;
  // measured on lion-head subdivided, 33K and 133K vertices, 8 was as fast as any larger
  // block) and at most 12 MB per matrix. The solves run single-threaded (BLAS too), so the
  // blocks are dealt round to lanes, one per thread OpenMP may use here (one inside a worker
  // pool's task), each with its own solver state: on 2 cores, 1,000 sources on 133K vertices
  // took 15 s with one lane. Each column's arithmetic is the same on any number of lanes;
  // parallel_for rethrows a lane's failure after all have stopped.
  const int block = std::clamp(static_cast<int>((12 << 20) / (8L * nv)), 1, 8);
  const int blocks = (ns + block - 1) / block;
  const int lanes = std::max(1, std::min(blocks, omp_get_max_threads()));
  while (static_cast<int>(s.lanes.size()) < lanes) s.lanes.push_back(std::make_unique<Lane>());
  auto solve_block = [&](int first, int b, Lane& lane) {
    lane.U0.setZero(nv, b);
    for (int c = 0; c < b; ++c) {
      const SurfacePoint& p = sources[static_cast<size_t>(first + c)];
      for (int j = 0; j < 3; ++j) lane.U0(m.F(p.face, j), c) += p.bary[j];
    }
    lane.heat.solve_into(s.heat.factor(), lane.U0, lane.U);             // step 1
    divergence({s.tri, s.layout, s.cot}, lane.U, lane.div, lanes == 1);  // steps 2 and 3
    lane.rhs = -lane.div.bottomRows(nv - 1);
    lane.poisson.solve_into(s.poisson.factor(), lane.rhs, lane.phi);
    for (int c = 0; c < b; ++c) {
      // Step 4, shifted by the least value (the source's, up to the smoothing near it).
      D(0, first + c) = 0;
      D.col(first + c).tail(nv - 1) = lane.phi.col(c);
      D.col(first + c).array() -= D.col(first + c).minCoeff();
    }
  };
  parallel_for(lanes, lanes, [&](int l) {
    for (int k = l; k < blocks; k += lanes) solve_block(k * block, std::min(block, ns - k * block), *s.lanes[static_cast<size_t>(l)]);
  });
}

Eigen::VectorXd exact_distances(const TriMesh& m, const SurfacePoint& from) {
  const cgal::Surface sm = cgal::to_surface_mesh(m);
  cgal::Paths paths(sm);
  const cgal::Location at = cgal::location(sm, m, from);
  paths.add_source_point(at.first, at.second);
  paths.build_sequence_tree();
  Eigen::VectorXd d(m.num_vertices());
  for (auto v : sm.vertices()) d[static_cast<Eigen::Index>(v.idx())] = paths.shortest_distance_to_source_points(v).first;
  return d;
}

}  // namespace brenier::mesh

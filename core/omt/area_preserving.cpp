#include "omt/area_preserving.hpp"

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <functional>
#include <future>
#include <limits>
#include <malloc.h>
#include <mutex>
#include <optional>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "common/error.hpp"
#include "conformal/mobius.hpp"
#include "mesh/geometry.hpp"
#include "mesh/topology.hpp"
#include "omt/fold_repair.hpp"
#include "quality/quality.hpp"

namespace brenier::omt {

Eigen::VectorXd vertex_masses(const mesh::TriMesh& m) {
  const Eigen::VectorXd area = mesh::face_areas(m);
  Eigen::VectorXd mass = Eigen::VectorXd::Zero(m.num_vertices());
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) mass[m.F(f, k)] += area[f] / 3.0;
  return mass;
}

namespace {

// Checks the options; the vertex masses of eq. 3.30 times the region weights (sec. 6.3).
Eigen::VectorXd weighted_masses(const mesh::TriMesh& m, const AreaPreservingOptions& opt) {
  const int nv = m.num_vertices();
  if (opt.weights.size() != 0) {
    if (opt.weights.size() != nv)
      invalid("weights: " + std::to_string(opt.weights.size()) + " values for " + std::to_string(nv) + " vertices");
    for (int v = 0; v < nv; ++v)
      if (!(opt.weights[v] > 0) || !std::isfinite(opt.weights[v]))
        invalid("the weight of vertex " + std::to_string(v) + " is " + std::to_string(opt.weights[v]) +
                "; weights must be positive");
  }
  if (!(opt.t >= 0 && opt.t <= 1)) invalid("t must lie in [0, 1], got " + std::to_string(opt.t));
  Eigen::VectorXd nu = vertex_masses(m);
  if (opt.weights.size() != 0) nu = nu.cwiseProduct(opt.weights);
  return nu;
}

// A map that starts from the conformal map c, which must have converged.
AreaPreservingMap starting_from(conformal::ConformalMap c) {
  if (!c.converged)
    fail(ErrorCode::kNotConverged,
         "the conformal map did not converge: max |K - Kbar| = " + std::to_string(c.max_curvature_error));
  AreaPreservingMap out;
  out.conformal = std::move(c);
  return out;
}

// The refinement's target areas: each face's area times its corners' mean region weight (the
// vertex masses of eq. 3.30 weighted the same way).
Eigen::VectorXd face_targets(const mesh::TriMesh& m, const AreaPreservingOptions& opt) {
  Eigen::VectorXd target = mesh::face_areas(m);
  if (opt.weights.size() != 0)
    for (int f = 0; f < m.num_faces(); ++f)
      target[f] *= (opt.weights[m.F(f, 0)] + opt.weights[m.F(f, 1)] + opt.weights[m.F(f, 2)]) / 3;
  return target;
}

bool refines(const AreaPreservingOptions& opt, const AreaPreservingMap& map) {
  return opt.refine.enabled && opt.t == 0 && map.folded_faces == 0;
}

// The refinement's plan (area_refinement.hpp), made by `make` on a second thread while this
// one computes the conformal map and the transport: its analysis depends on the mesh alone,
// and those stages are serial for the most part (the 100K-vertex disk map ran 12.5 s of CPU
// in 12.6 s). None when the map is not to be refined, or when no thread can be started (the
// refinement then makes its own). The thread's own malloc arena would keep the analysis's
// freed scratch between the plan's live blocks, out of the main thread's reach: malloc_trim
// hands it back (the 100K disk map's peak: 397-433 MB before, 472-500 MB with the thread,
// 420-422 MB with the trim; bench/RESULTS.md, session 49).
// A plan whose map ended without it (an error or a cancel thrown past it, or a map not to be
// refined) is left to finish on its own: a std::async future's destructor would wait for the
// analysis (2.8 s on the 97K-vertex hemisphere beside a matrix run, where its conformal map
// took 1.1 s), and a cancelled job's end waited for it: the service's cancel test took
// 1.03-1.11 s against its one-second bar under load, 0.2 s since (bench/RESULTS.md, session
// 83). Left plans are dropped once done, at the next plan made ahead or left, and waited for at
// exit. The make functions own copies of what they read, so that they outlive the map's caller.
using PlanFuture = std::future<std::shared_ptr<RefinementPlan>>;
void drop_finished(std::vector<PlanFuture>& left) {
  std::erase_if(left, [](const PlanFuture& f) {
    return f.wait_for(std::chrono::seconds(0)) == std::future_status::ready;
  });
}
void leave(PlanFuture f) {
  static std::mutex mutex;
  static std::vector<PlanFuture> left;
  std::lock_guard<std::mutex> lock(mutex);
  drop_finished(left);
  if (f.valid()) left.push_back(std::move(f));
}

class PlanAhead {
 public:
  PlanAhead() = default;
  explicit PlanAhead(PlanFuture f) : f_(std::move(f)) {}
  PlanAhead(const PlanAhead&) = delete;
  PlanAhead& operator=(const PlanAhead&) = delete;
  ~PlanAhead() {
    try {
      leave(std::move(f_));
    } catch (...) {  // (no memory to keep it in: the future's destructor waits, as it did)
    }
  }
  std::shared_ptr<RefinementPlan> take() { return f_.valid() ? f_.get() : nullptr; }

 private:
  PlanFuture f_;
};

template <class Make>
PlanAhead plan_ahead(const AreaPreservingOptions& opt, Make make) {
  leave({});  // (drops the plans left that are done)
  if (!opt.refine.enabled || opt.t != 0) return {};
  try {
    return PlanAhead(std::async(std::launch::async, [make = std::move(make)] {
      std::shared_ptr<RefinementPlan> plan = make();
      malloc_trim(0);
      return plan;
    }));
  } catch (const std::system_error&) {
    return {};
  }
}

// The sphere map returned, with the face-by-face refinement when it is a bijection.
AreaPreservingMap refined_on_sphere(const mesh::TriMesh& m, const AreaPreservingOptions& opt, PlanAhead& plan,
                                    AreaPreservingMap map) {
  if (refines(opt, map) && quality::covers_once(map.degree))
    map.refinement = refine_sphere_areas(m, face_targets(m, opt), map.positions, opt.refine, plan.take());
  return map;
}

}  // namespace

OmtResult transport_to_mesh_sites(const mesh::TriMesh& m, const Domain& domain, const Points& sites, const Eigen::VectorXd& nu,
                    const OmtOptions& opt) {
  OmtResult r;
  try {
    r = solve_omt(domain, sites, nu, opt);
  } catch (const Error& e) {
    if (e.code() != ErrorCode::kInvalidArgument) throw;
    fail(ErrorCode::kNotConverged, std::string("the conformal map crowds vertices below double precision: ") + e.what());
  }
  if (!r.converged) {
    // Say when the conformal map packs sites too tightly for double precision: a bisector
    // is placed to ~1e-16 / |y_i - y_j| by heights of size one, so cells much below 1e-6
    // across cannot be brought to their masses (and the damped steps hide them).
    double closest = std::numeric_limits<double>::infinity();
    for (int f = 0; f < m.num_faces(); ++f)
      for (int k = 0; k < 3; ++k)
        closest = std::min(closest, (sites.row(m.F(f, k)) - sites.row(m.F(f, (k + 1) % 3))).norm());
    char buf[300];
    std::snprintf(buf, sizeof buf,
                  "the optimal transport did not converge: max relative cell-mass error %.2e after %d Newton iterations",
                  r.max_relative_error, r.iterations);
    std::string what = buf;
    if (closest < 1e-5) {
      std::snprintf(buf, sizeof buf,
                    "; the conformal map puts neighbouring vertices as close as %.1e, below what double precision "
                    "resolves",
                    closest);
      what += buf;
    }
    fail(ErrorCode::kNotConverged, what);
  }
  return r;
}


AreaPreservingMap area_preserving_disk(const mesh::TriMesh& m, const AreaPreservingOptions& opt) {
  const int nv = m.num_vertices();
  const Eigen::VectorXd nu = weighted_masses(m, opt);
  // (The plan's thread finds the boundary itself: an error there waits for the conformal
  // map's checks of the mesh, which name the problem first.)
  PlanAhead plan = plan_ahead(opt, [m, slide = opt.refine.slide_boundary] {
    AreaRefineOptions o;
    o.slide_boundary = slide;
    return plan_disk_refinement(m, mesh::boundary_flags(m), o);
  });
  // (1) conformal map phi: S -> D (Alg. 1).
  AreaPreservingMap out = starting_from(conformal::map_to_disk(m, opt.conformal));
  // (2) sites p_i = phi(v_i), masses nu_i scaled to the disk's area pi inside solve_omt;
  // (3) the OMT map tau from the uniform disk to (p, nu).
  Points sites = out.conformal.positions.leftCols(2);
  OmtOptions transport = opt.omt;
  // Above multilevel_from the coarse-to-fine start is taken without the probe of the plain
  // start's first Newton step (OmtOptions::multilevel_probe), which is there for the
  // distances' near-uniform measures: a conformal image's masses vary by orders of magnitude,
  // so that step is damped and wasted. The 99,731-vertex disk map (lion-head subdivided):
  // 27 -> 26 Newton iterations, conformal map and transport 6.97 -> 5.47 s; the real disk
  // meshes forced onto the coarse start took as many iterations or one fewer without the
  // probe (bench/RESULTS.md, session 47).
  if (opt.multilevel_from > 0 && nv >= opt.multilevel_from) {
    transport.multilevel = true;
    transport.multilevel_probe = false;
  }
  out.omt = transport_to_mesh_sites(m, Domain::unit_disk(), sites, nu, transport);
  // (4) tau^{-1} o phi: each vertex goes to the centroid of its cell W_i = tau^{-1}(p_i).
  out.positions = mesh::Vertices::Zero(nv, 3);
  out.positions.leftCols(2) = out.omt.cells.centroid;
  if (opt.t > 0)  // phi_t = grad u_t o phi_0: (1 - t) c_i + t p_i
    out.positions.leftCols(2) = (1 - opt.t) * out.positions.leftCols(2) + opt.t * sites;
  // Centroids of neighbouring cells can come out in the wrong order where the conformal map
  // crowds the sites (a fold of the piecewise-linear map through the vertices, though tau
  // itself is a bijection); those faces are repaired locally by the mean-value Tutte
  // embedding the conformal map uses, the rest of the map kept as it is.
  // The boundary goes to the boundary: a boundary vertex's cell meets the circle, and the
  // vertex is put where the radius through its centroid meets it (this also makes the
  // fixed outline of the repair below convex, as Floater's theorem asks).
  const std::vector<char> fixed = mesh::boundary_flags(m);
  for (int v = 0; v < nv; ++v)
    if (fixed[v]) {
      const double r = out.positions.row(v).norm();
      if (r > 0) out.positions.row(v) /= r;
      // x / |x| can come out an ulp outside the circle; the map lies in the closed disk.
      while (out.positions.row(v).norm() > 1) out.positions.row(v) *= 1 - std::numeric_limits<double>::epsilon();
    }
  out.relaxed_vertices = conformal::repair_planar_folds(m, out.positions, fixed, out.folded_faces);
  if (refines(opt, out))
    out.refinement = refine_disk_areas(m, face_targets(m, opt), out.positions, fixed, opt.refine, plan.take());
  return out;
}

namespace {

// The face whose image under X holds the direction p (its three edge planes leave p on the
// inner side), else the face with the middle nearest p.
int face_holding(const mesh::TriMesh& m, const mesh::Vertices& X, const Eigen::Vector3d& p) {
  int nearest = 0;
  double nearest_d = std::numeric_limits<double>::infinity();
  for (int f = 0; f < m.num_faces(); ++f) {
    const Eigen::Vector3d a = X.row(m.F(f, 0)), b = X.row(m.F(f, 1)), c = X.row(m.F(f, 2));
    if (p.dot(a.cross(b)) >= 0 && p.dot(b.cross(c)) >= 0 && p.dot(c.cross(a)) >= 0 && p.dot(a + b + c) > 0) return f;
    const double d = ((a + b + c).normalized() - p).squaredNorm();
    if (d < nearest_d) nearest_d = d, nearest = f;
  }
  return nearest;
}

// The face with the largest image under X: the default pole's (as far from every vertex as
// the map allows).
int widest_face(const mesh::TriMesh& m, const mesh::Vertices& X) {
  int widest = 0;
  double widest_area = -1;
  for (int f = 0; f < m.num_faces(); ++f) {
    const Eigen::Vector3d a = X.row(m.F(f, 0)), b = X.row(m.F(f, 1)), c = X.row(m.F(f, 2));
    const double area = (b - a).cross(c - a).norm();
    if (area > widest_area) widest_area = area, widest = f;
  }
  return widest;
}

// The direction of the middle of face f's image under X.
Eigen::Vector3d face_direction(const mesh::TriMesh& m, const mesh::Vertices& X, int f) {
  return (X.row(m.F(f, 0)) + X.row(m.F(f, 1)) + X.row(m.F(f, 2))).transpose().normalized();
}

}  // namespace

Points stereographic_sites(const mesh::TriMesh& m, const mesh::Vertices& X, Eigen::Matrix3d& R,
                           const Eigen::Vector3d* toward) {
  // The north pole (infinity of the stereographic plane) goes to the middle of the face
  // holding `toward`, by default of the face with the largest image.
  const Eigen::Vector3d pole = face_direction(m, X, toward ? face_holding(m, X, toward->normalized()) : widest_face(m, X));
  R = Eigen::Quaterniond::FromTwoVectors(pole, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const mesh::Vertices Y = X * R.transpose();  // rows R x
  Points sites(X.rows(), 2);
  for (Eigen::Index v = 0; v < X.rows(); ++v) sites.row(v) << Y(v, 0) / (1 - Y(v, 2)), Y(v, 1) / (1 - Y(v, 2));
  return sites;
}

namespace {

// The shortest chord from each vertex to a neighbour under the map X.
Eigen::VectorXd shortest_edges(const mesh::TriMesh& m, const mesh::Vertices& X) {
  Eigen::VectorXd s = Eigen::VectorXd::Constant(m.num_vertices(), std::numeric_limits<double>::infinity());
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) {
      const int a = m.F(f, k), b = m.F(f, (k + 1) % 3);
      const double d = (X.row(a) - X.row(b)).norm();
      s[a] = std::min(s[a], d);
      s[b] = std::min(s[b], d);
    }
  return s;
}

// One stage of the spreading start of area_preserving_sphere: the vertices marked
// `deferred` (crowded below what the transport resolves) leave the transport for this
// stage; the transport from the sphere to the other vertices' sites with their own masses
// (scaled to the sphere's area) is solved to a loose tolerance, and each kept vertex goes
// to its cell's centroid. The deferred vertices are then placed by a Tutte embedding (the
// surface's own mean value weights) inside the kept ring around them, in the stereographic
// plane. (Giving a crowded region's mass to its ring instead makes a cell ~1e-12 across
// grow by 1e10 and the Newton direction there hides its neighbours at every step length.)
// The ring now spans about the area its side of the surface fills, so the region inside it
// comes out spread by that factor. Returns the new map on the sphere.
mesh::Vertices spread_once(const mesh::TriMesh& m, const mesh::Vertices& X, const Eigen::VectorXd& nu,
                           const std::vector<char>& deferred, const OmtOptions& omt, int stage,
                           const Eigen::Vector3d* pole, OmtResult& result) {
  const int nv = m.num_vertices();
  Eigen::Matrix3d R;
  const Points all = stereographic_sites(m, X, R, pole);
  std::vector<int> slot(nv, -1);
  int kept = 0;
  for (int v = 0; v < nv; ++v)
    if (!deferred[v]) slot[v] = kept++;
  if (kept < 4)
    fail(ErrorCode::kNotConverged, "the conformal sphere map crowds all but " + std::to_string(kept) +
                                       " vertices below what double precision resolves");
  Points sites(kept, 2);
  Eigen::VectorXd mass = Eigen::VectorXd::Zero(kept);
  for (int v = 0; v < nv; ++v)
    if (slot[v] >= 0) sites.row(slot[v]) = all.row(v), mass[slot[v]] = nu[v];
  OmtOptions loose = omt;
  loose.tolerance = std::max(omt.tolerance, 1e-4);  // a start only: spread, not exact
  loose.initial_h.resize(0);
  result = solve_omt(Domain::stereographic_sphere(), sites, mass, loose);
  if (!result.converged) {
    char buf[200];
    std::snprintf(buf, sizeof buf,
                  "spreading the crowded conformal sphere map (stage %d, %d of %d vertices kept): the optimal "
                  "transport did not converge, max relative cell-mass error %.2e",
                  stage, kept, nv, result.max_relative_error);
    fail(ErrorCode::kNotConverged, buf);
  }
  mesh::Vertices P = mesh::Vertices::Zero(nv, 3);
  for (int v = 0; v < nv; ++v)
    if (slot[v] >= 0) P.row(v).head<2>() = result.cells.centroid.row(slot[v]);
  // Where the kept centroids around a crowded region do not form a simple polygon (their
  // cells are far larger than their spacing there, so their order is loose), the Tutte
  // region wraps around the sphere. The region then grows by 1, 2, 4, ... rings, its outline
  // moving out to where the centroids are in order, until the map covers the sphere once.
  std::vector<std::vector<int>> ring(nv);
  for (int f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) ring[m.F(f, k)].push_back(m.F(f, (k + 1) % 3));
  std::vector<char> region = deferred;
  mesh::Vertices Y(nv, 3);
  for (int grown = 0, rings = 0;; ++grown) {
    mesh::Vertices Q = P;
    if (!conformal::tutte_fill(m, Q, region))
      fail(ErrorCode::kNotConverged, "spreading the crowded conformal sphere map: the Tutte solve failed");
    for (int v = 0; v < nv; ++v)  // back onto the sphere, still turned by R
      Y.row(v) = conformal::inverse_stereographic({Q(v, 0), Q(v, 1)}).transpose();
    if (quality::covers_once(quality::sphere_degree(m.F, Y))) break;
    if (grown == 6)
      fail(ErrorCode::kNotConverged, "spreading the crowded conformal sphere map (stage " + std::to_string(stage) +
                                         "): the placed region wraps around the sphere");
    const int add = std::max(1, rings);
    for (int r = 0; r < add; ++r) {
      std::vector<char> next = region;
      for (int v = 0; v < nv; ++v)
        if (region[v])
          for (int w : ring[v]) next[w] = 1;
      region = std::move(next);
    }
    rings += add;
  }
  return Y * R;  // rows R^T y
}

// The caller's choice of pole (AreaPreservingOptions::pole) given the conformal map X and
// its default pole; none without a chooser.
std::optional<Eigen::Vector3d> chosen_pole(const mesh::TriMesh& m, const mesh::Vertices& X, const AreaPreservingOptions& opt) {
  if (!opt.pole) return std::nullopt;
  return opt.pole(X, face_direction(m, X, widest_face(m, X))).normalized();
}

// The last step of each try of area_preserving_sphere: the centroids (out.positions), blended
// toward the conformal map X for t > 0, then repaired: local moves (conformal::untangle), then
// fold_repair.hpp's barrier where it keeps the area distortion no larger and the degree 1. A
// map that wraps around the sphere more than once is reported as it is. Returns whether the
// map is bijective. With `keep_longest_edges` no local move may lengthen a vertex's longest
// edge. Without it, where the centroids fold in crowded legs, mirror moves across slivers walk
// vertices across the sphere: camel's 10,911-vertex copy came out of them with 205 faces whose
// edges span over 0.9 (none in its centroid map), folded and unfolded ones whose signed areas
// cancel, so the degree stayed 1 while no barrier region around them could be untangled
// (their enclosed area in the chart was negative); the try ended 7 folds short and the next
// started from scratch. With it, that try comes out bijective (bench/RESULTS.md, session 70).
bool finish_sphere_map(const mesh::TriMesh& m, const mesh::Vertices& X, const AreaPreservingOptions& opt,
                       bool keep_longest_edges, AreaPreservingMap& out) {
  const int nv = m.num_vertices();
  if (opt.t > 0)
    for (int v = 0; v < nv; ++v)
      out.positions.row(v) = ((1 - opt.t) * out.positions.row(v) + opt.t * X.row(v)).normalized();
  // Each barrier step only while the map covers the sphere once: one that wraps around it
  // more than once is reported as it is. Up to four chart passes (u kept 9 folds and dino 4
  // with the chart repair alone, without the sphere's first).
  SphereUnfold how;
  how.keep_longest_edges = keep_longest_edges;
  how.only_covering_once = true;
  how.chart_passes = 4;
  how.keep_going = opt.repair_progress;
  const SphereUnfolded left = unfold_sphere_map(m, out.positions, how);
  out.relaxed_vertices = left.moved;
  out.folded_faces = left.folds;
  out.degree = left.degree;
  return out.folded_faces == 0 && quality::covers_once(out.degree);
}

}  // namespace

AreaPreservingMap area_preserving_sphere(const mesh::TriMesh& m, const AreaPreservingOptions& opt) {
  const int nv = m.num_vertices();
  const Eigen::VectorXd nu = weighted_masses(m, opt);
  PlanAhead plan = plan_ahead(opt, [m] { return plan_sphere_refinement(m); });
  AreaPreservingMap out = starting_from(conformal::map_to_sphere(m, opt.conformal));
  const mesh::Vertices& X = out.conformal.positions;
  // The start. Long protrusions (legs, tails, fingers) shrink exponentially under the
  // conformal map: bull, camel, cow, dino, diplodocus and man put neighbouring vertices
  // 1e-10 to 1e-15 apart on the sphere, where positions of size one keep few correct
  // digits of their differences and the Newton direction's round-off alone hides such
  // cells. Such maps (and any whose transport from the conformal start fails) start
  // instead from a spread map: spread_once, repeated until no two neighbours are closer
  // than kDefer, each stage deferring the vertices closer than that to a neighbour. The
  // result is still exactly area-preserving cell by cell, but it is the polar factor of
  // the spread start, not of the conformal map (out.spreading_stages > 0 says so).
  constexpr double kCrowded = 1e-8, kDefer = 1e-6, kDeferMore = 1e-5;  // armadillo's 3e-8: not crowded
  constexpr int kMaxStages = 10;
  const std::optional<Eigen::Vector3d> chosen = chosen_pole(m, X, opt);  // none: the default pole
  const Eigen::Vector3d* toward = chosen ? &*chosen : nullptr;
  mesh::Vertices centroids;  // the last transport's centroid map, before finish repairs it
  auto transport_from = [&](const mesh::Vertices& start) {
    Eigen::Matrix3d R;
    out.omt = transport_to_mesh_sites(m, Domain::stereographic_sphere(), stereographic_sites(m, start, R, toward), nu, opt.omt);
    out.pole = R.row(2).transpose();
    out.positions = out.omt.cells.sphere_centroid * R;  // each vertex to its cell's centroid, turned back
    centroids = out.positions;
  };
  // The tries below, in order; the first bijective map is returned, else the one closest
  // to it (covering the sphere once, then the fewest folds), reported as it is. A try whose
  // transport fails to converge passes the turn; if all do, the last failure is thrown.
  std::optional<AreaPreservingMap> best;
  std::exception_ptr failure;
  auto attempt = [&](const std::function<void()>& start, bool keep_longest_edges) {
    try {
      start();
    } catch (const Error& e) {
      if (e.code() != ErrorCode::kNotConverged) throw;
      failure = std::current_exception();
      return false;
    }
    const bool bijective = finish_sphere_map(m, X, opt, keep_longest_edges, out);
    auto rank = [](const AreaPreservingMap& a) { return std::pair(!quality::covers_once(a.degree), a.folded_faces); };
    if (!best || rank(out) < rank(*best)) best = out;
    return bijective;
  };
  // The spread start: stages until no two neighbours are closer than `defer`. After each
  // stage the folds it left get local Tutte steps (a start with fewer folds gives a final
  // centroid map with fewer: camel 0.88 -> 0.33 mean |log area ratio|), and with
  // `repair_stages` also the barrier repairs.
  auto spread_start = [&](bool repair_stages, double defer) {
    out.spreading_stages = out.spreading_newton_iterations = 0;
    mesh::Vertices start = X;
    for (Eigen::VectorXd shortest = shortest_edges(m, start);
         out.spreading_stages == 0 || shortest.minCoeff() < defer; shortest = shortest_edges(m, start)) {
      if (out.spreading_stages == kMaxStages)
        fail(ErrorCode::kNotConverged, "the conformal sphere map is still crowded to " +
                                           std::to_string(shortest.minCoeff()) + " after " +
                                           std::to_string(kMaxStages) + " spreading stages");
      std::vector<char> deferred(nv);
      for (int v = 0; v < nv; ++v) deferred[v] = shortest[v] < defer;
      OmtResult stage;
      start = spread_once(m, start, nu, deferred, opt.omt, ++out.spreading_stages, toward, stage);
      out.spreading_newton_iterations += stage.iterations;
      // The Tutte steps may not lengthen a vertex's longest edge here: where the stage tore
      // faces open, a vertex mirrored across one lands across the sphere and tears its
      // other faces, which the next transport keeps (man kept 4 folds; with this, none).
      SphereUnfold how;
      how.keep_longest_edges = true;
      how.barrier = repair_stages;
      how.keep_going = opt.repair_progress;
      unfold_sphere_map(m, start, how);
    }
    transport_from(start);
  };
  // 1. The conformal map itself, unless it is crowded (or its transport fails: armadillo on
  //    some processors, where the Voronoi start cannot take a step).
  if (shortest_edges(m, X).minCoeff() >= kCrowded) {
    if (attempt([&] { transport_from(X); }, false)) return refined_on_sphere(m, opt, plan, std::move(out));
    // 1b. Where the free local moves left a fold: the same centroids again, the moves kept
    //     from lengthening edges as in the spread tries below (cactus: mended by try 2 before,
    //     refined to 0.0740; from here 0.0577). Not first: on part and oblong the free moves
    //     give the refinement a better start (part 0.0165 against 0.0297 refined).
    if (centroids.rows() == nv && attempt([&] { out.positions = centroids; }, true))
      return refined_on_sphere(m, opt, plan, std::move(out));
  }
  // 2. The spread start with Tutte steps only between stages (cheap; camel and cow come out
  //    bijective this way). A stage runs even where nothing is crowded: one loose transport
  //    and its centroids order a start whose own centroid map folds (cactus: 6 folds from
  //    the conformal map, none from one stage).
  if (attempt([&] { spread_start(false, kDefer); }, true)) return refined_on_sphere(m, opt, plan, std::move(out));
  // 3. Also the barrier repairs between stages, on the sphere and then in charts (bull and
  //    armadillo need the first: the next stage's kept centroids are then in order, where
  //    the second try leaves their regions wrapped; dino the second: 2 folds left without).
  if (attempt([&] { spread_start(true, kDefer); }, true)) return refined_on_sphere(m, opt, plan, std::move(out));
  // 4. Deferring more (vertices within 1e-5 of a neighbour), with the repairs: only where the
  //    round-off of the tries above left a fold torn across the sphere. Man with CHOLMOD's
  //    simplicial factor kept one after try 3 and none after this one (1e-7 kept it).
  if (attempt([&] { spread_start(true, kDeferMore); }, true)) return refined_on_sphere(m, opt, plan, std::move(out));
  if (!best) std::rethrow_exception(failure);
  return refined_on_sphere(m, opt, plan, std::move(*best));
}

}  // namespace brenier::omt

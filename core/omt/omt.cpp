#include "omt/omt.hpp"

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCore>
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "common/check.hpp"
#include "common/error.hpp"
#include "common/parallel.hpp"
#include "numeric/cholmod_settings.hpp"
#include "numeric/krylov.hpp"
#include "omt/coarse_to_fine.hpp"

namespace brenier::omt {

namespace {

// The Hessian of eq. 3.28 on the heights other than h_p (held: the energy is invariant
// under adding a constant to h, so the Hessian is singular along the constants): the
// weighted graph Laplacian of the clipped dual edges. (Eq. 3.28 prints the off-diagonal
// entries with a plus sign; d w_i / d h_j = -|e_ij| / |y_i - y_j| for j != i, since
// raising h_j grows W_j at W_i's expense, and the diagonal is minus the sum of its row.)
// Unknown k stands for height k < p ? k : k + 1.
Eigen::SparseMatrix<double> hessian(const PowerCells& cells, const Points& sites, int n, int p) {
  const int m = n - 1;
  auto slot = [p](int i) { return i < p ? i : i - 1; };
  const std::vector<DualEdge>& edges = cells.edges;
  std::vector<double> weight(edges.size());
  Eigen::VectorXd diag = Eigen::VectorXd::Zero(n);
  std::vector<int> start(m + 1, 0);
  for (size_t k = 0; k < edges.size(); ++k) {
    const DualEdge& e = edges[k];
    const double w = weight[k] = e.length / (sites.row(e.i) - sites.row(e.j)).norm();
    diag[e.i] += w;
    diag[e.j] += w;
    if (e.i != p && e.j != p) ++start[slot(e.i) + 1], ++start[slot(e.j) + 1];
  }
  for (int c = 0; c < m; ++c) ++start[c + 1];  // the diagonal
  for (int c = 0; c < m; ++c) start[c + 1] += start[c];
  // Straight into compressed columns, rows ascending: the edges come ordered by (i, j)
  // with i < j, so column i gets rows i' < i (from earlier edges), then i, then j > i.
  // (Assembling millions of edges through triplets cost more than the rest of an iteration.)
  Eigen::SparseMatrix<double> H(m, m);
  H.resizeNonZeros(start[m]);
  std::vector<int> fill(start.begin(), start.end() - 1);
  auto put = [&](int row, int col, double v) {
    H.innerIndexPtr()[fill[col]] = row;
    H.valuePtr()[fill[col]++] = v;
  };
  size_t k = 0;
  for (int i = 0; i < n; ++i) {
    if (i != p) put(slot(i), slot(i), diag[i]);
    for (; k < edges.size() && edges[k].i == i; ++k) {
      const int j = edges[k].j;
      if (i == p || j == p) continue;
      put(slot(j), slot(i), -weight[k]);
      put(slot(i), slot(j), -weight[k]);
    }
  }
  BRENIER_CHECK(k == edges.size(), "dual edges must come ordered by their first cell");
  std::copy(start.begin(), start.end(), H.outerIndexPtr());
  return H;
}

// The vector without entry p, and back (entry p zero).
Eigen::VectorXd drop(const Eigen::VectorXd& v, int p) {
  Eigen::VectorXd out(v.size() - 1);
  out << v.head(p), v.tail(v.size() - p - 1);
  return out;
}
Eigen::VectorXd undrop(const Eigen::VectorXd& v, int p) {
  Eigen::VectorXd out(v.size() + 1);
  out << v.head(p), 0.0, v.tail(v.size() - p);
  return out;
}

double relative_norm(const Eigen::VectorXd& g, const Eigen::VectorXd& nu) {
  return (g.array() / nu.array()).matrix().norm();
}

double max_relative(const Eigen::VectorXd& w, const Eigen::VectorXd& nu) {
  return ((w - nu).array().abs() / nu.array()).maxCoeff();
}

// The Kantorovich dual D at offsets psi (+ psi_lo) with the cells there and g = masses -
// targets: w_i = |y_i|^2 + 2 h_i = 2 psi_i (OmtOptions::dual_gap_tolerance).
double dual(const Eigen::VectorXd& psi, const Eigen::VectorXd& psi_lo, const PowerCells& cells,
            const Eigen::VectorXd& g) {
  return cells.second_moment.sum() - 2 * (psi + psi_lo).dot(g);
}

}  // namespace

void check_transport_input(int n, const Eigen::VectorXd& nu_in, const OmtOptions& opt) {
  if (n == 0) invalid("no sites");
  if (nu_in.size() != n)
    invalid("target masses: " + std::to_string(nu_in.size()) + " for " + std::to_string(n) + " sites");
  for (int i = 0; i < n; ++i)
    if (!(nu_in[i] > 0) || !std::isfinite(nu_in[i]))
      invalid("target mass of site " + std::to_string(i) + " is " + std::to_string(nu_in[i]) + "; it must be positive");
  if (!(opt.tolerance > 0)) invalid("the OMT tolerance must be positive");
  if (opt.alternative_h.size() != 0 && (opt.alternative_h.size() != n || !opt.alternative_h.allFinite()))
    invalid("alternative heights: " + std::to_string(opt.alternative_h.size()) + " finite values needed for " +
            std::to_string(n) + " sites");
}

namespace {

// Heights as offsets psi = h + |y|^2 / 2 (PowerDiagrams::at_offsets), which keep their
// precision where h would carry the round-off of |y_i|^2: the Voronoi start is psi = 0
// exactly, and a Newton step changes psi as it changes h. The steps are accumulated in
// double-double (hi + lo): a cluster of sites d apart that the conformal map packs together
// has offsets of size ~0.5 that differ by ~1e-8, and in plain doubles their bisectors would
// stay eps |psi| / d off (bunny00 and armadillo stalled at 3e-8).
struct Offsets {
  Eigen::VectorXd hi, lo;
  explicit Offsets(int n = 0) : hi(Eigen::VectorXd::Zero(n)), lo(Eigen::VectorXd::Zero(n)) {}
  /// (hi, lo) + step in double-double: Knuth's two-sum, then renormalized (Dekker).
  Offsets plus(const Eigen::VectorXd& step) const {
    Offsets out(static_cast<int>(hi.size()));
    for (Eigen::Index i = 0; i < hi.size(); ++i) {
      const double s = hi[i] + step[i], bb = s - hi[i];
      const double e = (hi[i] - (s - bb)) + (step[i] - bb);
      const double l = lo[i] + e, sum = s + l;
      out.hi[i] = sum;
      out.lo[i] = l - (sum - s);
    }
    return out;
  }
};

// A start that leaves a few cells empty, as sites just outside the domain whose cells miss
// it: their offsets are raised, each by 1e-7 and then by four times more while its cell is
// still empty (12 rounds reach 1.7; raising psi_i by d moves the cell's edges by d / |y_i -
// y_j|). Leaves `c` with the cells at the raised offsets, or empty if a site became hidden.
void reopen_empty_cells(const PowerDiagrams& diagram, Eigen::VectorXd& psi, std::optional<PowerCells>& c) {
  const Eigen::Index n = psi.size();
  Eigen::VectorXd raise = Eigen::VectorXd::Constant(n, 1e-7);
  for (int round = 0; round < 12 && c && c->empty_cells > 0; ++round) {
    for (Eigen::Index i = 0; i < n; ++i)
      if (!(c->mass[i] > 0)) psi[i] += raise[i], raise[i] *= 4;
    c = diagram.at_offsets_if_none_hidden(psi);
  }
}

// The given start if it leaves no cell empty and, when it is far off (some cell 10x its
// target), is nearer the targets than Voronoi in the line search's per-cell relative norm.
// Neither always wins: a shape's density sent to its own vertices starts well from Voronoi
// (each cell about its share of the adjacent triangles; mannequin-devil, whose density spans
// e^44, did not converge in 200 iterations from the uniform disk's heights), another shape's
// density better from those heights (24 iterations where Voronoi took 52). The threshold
// spares the extra diagram where the start is good.
void try_warm_start(const PowerDiagrams& diagram, const Eigen::VectorXd& initial_h, Offsets& psi, OmtResult& r) {
  const int n = static_cast<int>(psi.hi.size());
  if (initial_h.size() != n || !initial_h.allFinite())
    invalid("initial heights: " + std::to_string(initial_h.size()) + " finite values needed for " + std::to_string(n) +
            " sites");
  const Eigen::VectorXd& nu = r.target;
  const Eigen::VectorXd initial = diagram.offsets(initial_h);
  std::optional<PowerCells> c = diagram.at_offsets_if_none_hidden(initial);
  if (!c || c->empty_cells > 0) return;
  bool take = max_relative(c->mass, nu) <= 10;
  if (!take) {
    r.cells = diagram.at_offsets(psi.hi);
    take = r.cells.empty_cells > 0 || relative_norm(c->mass - nu, nu) < relative_norm(r.cells.mass - nu, nu);
  }
  if (take) {
    psi = Offsets(n);
    psi.hi = initial;
    r.cells = std::move(*c);
    r.warm_started = true;
  }
}

// A candidate start: its offsets, its cells (none where a site is hidden) and the dual D there
// (minus infinity where a cell is empty: not a start).
struct Start {
  Eigen::VectorXd psi;
  std::optional<PowerCells> cells;
  double dual = -std::numeric_limits<double>::infinity();
};
void rate_start(const Eigen::VectorXd& nu, Start& s) {
  if (s.cells && s.cells->empty_cells == 0)
    s.dual = dual(s.psi, Eigen::VectorXd::Zero(s.psi.size()), *s.cells, s.cells->mass - nu);
}

// A coarse-to-fine start (coarse_to_fine_heights with `ratio` and `recurse`), its cells reopened
// where at most 1 % are empty; not rated (only a rival needs that).
Start coarse_to_fine_start(const Domain& domain, const PowerDiagrams& diagram, const Points& sites,
                           const OmtOptions& opt, OmtResult& r, int ratio, bool recurse) {
  const int n = static_cast<int>(sites.rows());
  const std::optional<Eigen::VectorXd> h =
      detail::coarse_to_fine_heights(domain, sites, r.target, opt, r, ratio, recurse);
  Start s;
  if (h) {
    s.psi = diagram.offsets(*h);
    s.cells = diagram.at_offsets_if_none_hidden(s.psi);
    if (s.cells && s.cells->empty_cells > 0 && s.cells->empty_cells <= std::max(1, n / 100))
      reopen_empty_cells(diagram, s.psi, s.cells);
  }
  return s;
}

// The rival start (OmtOptions::alternative_h), rated; nothing without one.
std::optional<Start> rival_start(const PowerDiagrams& diagram, const OmtOptions& opt, const Eigen::VectorXd& nu) {
  if (opt.alternative_h.size() == 0) return std::nullopt;
  Start rival;
  rival.psi = diagram.offsets(opt.alternative_h);
  rival.cells = diagram.at_offsets_if_none_hidden(rival.psi);
  rate_start(nu, rival);
  return rival;
}

// The probe's subset: 1/64 of the sites, solved in one level (OmtOptions::alternative_h).
// Its start's D, against the rival's, at the first transport of each direction (session 44):
// near copies (mannequin-devil x remeshed, lion-head x deformed, lion-head-deformed x
// remeshed) -0.005..-0.026 against the rival's 4e-4..1.4e-3; unrelated shapes (lion-head x
// mannequin-devil, mushroom x three_peaks, nefertiti x lion-head, mannequin-devil x
// three_peaks, cylinder_locally_refined x lion-head) 0.022..0.57 against at most 2.5e-3.
// A 1/512 subset's start fell below the rival on lion-head x mannequin-devil and mushroom x
// three_peaks too.
constexpr int kProbeRatio = 64;
// Whether the rival beats the probe's start. The probe costs a fine diagram and its coarse
// solve (0.03 s of nefertiti x lion-head's 0.22 s), so it runs only where
// detail::worth_probing says (bench/RESULTS.md, sessions 44-45); false where it does not run,
// or where its coarse solve fails: the coarse levels then decide.
bool probe_prefers_rival(const Domain& domain, const PowerDiagrams& diagram, const Points& sites,
                         const OmtOptions& opt, const Offsets& psi, OmtResult& r, const Start& rival) {
  if (r.cells.empty_cells > 0) return false;
  const double plain = dual(psi.hi, psi.lo, r.cells, r.cells.mass - r.target);
  if (!detail::worth_probing(plain, rival.dual)) return false;
  Start probe = coarse_to_fine_start(domain, diagram, sites, opt, r, kProbeRatio, false);
  rate_start(r.target, probe);
  return std::isfinite(probe.dual) && rival.dual > probe.dual;
}

// OmtOptions::multilevel: the coarse-to-fine heights, taken if they leave no cell empty --
// whatever the norm says: a start far off in a few cells can lose to Voronoi in the norm
// while far nearer the solution elsewhere (lion-head's sites from mannequin-devil's density,
// 2,089-site level: 71 against 67, and Voronoi then took 28 Newton iterations, the transfer 25).
// OmtOptions::alternative_h replaces them where its dual is higher than the probe's start
// (then the coarse levels are not solved) or than theirs (r.levels is then 1).
// Returns whether the start was replaced.
bool coarse_start(const Domain& domain, const PowerDiagrams& diagram, const Points& sites, const OmtOptions& opt,
                  Offsets& psi, OmtResult& r) {
  const int n = static_cast<int>(sites.rows());
  std::optional<Start> rival = rival_start(diagram, opt, r.target);
  bool rival_taken = rival && probe_prefers_rival(domain, diagram, sites, opt, psi, r, *rival);
  Start s;
  if (!rival_taken) {
    s = coarse_to_fine_start(domain, diagram, sites, opt, r, detail::kCoarseRatio, true);
    if (rival) {
      rate_start(r.target, s);
      rival_taken = rival->dual > s.dual;
    }
  }
  if (rival_taken) s = std::move(*rival);
  if (rival_taken || !s.cells || s.cells->empty_cells > 0) r.levels = 1;  // the start is the rival or the plain one
  if (!s.cells || s.cells->empty_cells > 0) return false;
  psi = Offsets(n);
  psi.hi = std::move(s.psi);
  r.cells = std::move(*s.cells);
  r.warm_started = true;
  r.max_relative_error = max_relative(r.cells.mass, r.target);
  return true;
}

// Sites outside the domain (a conformal image's vertices on the unit circle, beyond the
// chords of another image's hull) can have empty Voronoi cells. Pull the sites toward the
// domain's centre c, z_i = c + s (y_i - c), halving s until every z_i is inside: the Voronoi
// diagram of the z_i, which is the power diagram of the y_i at h_i = -|z_i|^2 / (2 s), gives
// every site a cell containing z_i.
void shrink_start(const Domain& domain, const PowerDiagrams& diagram, const Points& sites, Offsets& psi, OmtResult& r) {
  const int n = static_cast<int>(sites.rows());
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  if (!domain.is_disk && !domain.is_sphere) c = domain.polygon.colwise().mean().transpose();
  auto all_inside = [&](double s) {
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector2d z = c + s * (sites.row(i).transpose() - c);
      if (!domain.contains(z.x(), z.y(), -1e-12)) return false;
    }
    return true;
  };
  double s = 1;
  for (int k = 0; k < 60 && !all_inside(s); ++k) s *= 0.5;
  if (s == 1) return;
  // psi_i = h_i + |y_i|^2 / 2 = (s - 1) (|c|^2 - s |y_i - c|^2) / (2 s)
  Eigen::VectorXd shrunk(n);
  for (int i = 0; i < n; ++i)
    shrunk[i] = (s - 1) * (c.squaredNorm() - s * (sites.row(i).transpose() - c).squaredNorm()) / (2 * s);
  PowerCells cells = diagram.at_offsets(shrunk);
  if (cells.empty_cells < r.cells.empty_cells) {
    psi = Offsets(n);
    psi.hi = std::move(shrunk);
    r.cells = std::move(cells);
  }
}

// The Kitagawa-Merigot-Thibert bound: every cell keeps at least eps0, a fraction of the
// smallest target or starting cell. Their convergence proof holds for any eps0 below the
// smallest target; the fraction only sets how far a trial may shrink a cell. Planar domains
// take a tenth: with a half, omt-bench's Gaussian had its last damped steps refused although
// they hid no site and cut the norm to 0.13, because 1-14 tail cells fell below half their
// targets on the way (bench/RESULTS.md, session 54). The stereographic sphere keeps its half:
// CI's every-sphere-mesh test has passed on that path. None left means sites outside the
// domain (the caller's error) or crowded beyond what doubles resolve (the method's limit).
double kmt_floor(const Domain& domain, const Points& sites, const OmtResult& r) {
  const double fraction = domain.is_sphere ? 0.5 : 0.1;
  const double eps0 = fraction * std::min(r.target.minCoeff(), r.cells.mass.minCoeff());
  if (eps0 > 0) return eps0;
  const int n = static_cast<int>(sites.rows());
  int outside = 0;
  for (int i = 0; i < n; ++i) outside += !domain.contains(sites(i, 0), sites(i, 1), 1e-12);
  const std::string what = std::to_string(r.cells.empty_cells) + " of " + std::to_string(n) +
                           " sites have empty Voronoi cells in the domain";
  if (outside > 0) invalid(what + " (" + std::to_string(outside) + " sites lie outside it; move them in)");
  fail(ErrorCode::kNotConverged, what + " (sites crowded closer than double precision resolves, as where a "
                                        "conformal map compresses a long protrusion)");
}

// Newton directions: the systems solved by GMRES preconditioned with the sparse Cholesky
// factor of an earlier Hessian (CHOLMOD), refactored only when the kept one has cost about a
// factorization in iterations: consecutive Hessians differ little.
class Directions {
 public:
  Directions(bool sphere, int n, OmtResult& r) : r_(r) {
    // Planar domains from 20K sites: supernodal factorizations, converted at their end to a
    // packed simplicial LL^T below 500K sites. The supernodal kernels factor a 100K-site
    // Hessian in 0.085 s against the simplicial code's 0.22 s; but GMRES applies a kept
    // factor 20-30 times, and one right-hand side through a supernodal factor (a dtrsv per
    // supernode) costs more than through a simplicial one, which is why simplicial alone was
    // faster below 200K. CHOLMOD converts the factor once it is made
    // (numeric::convert_factors_for_solves). omt-bench Gaussian, alternated: 20K even, 30K
    // -3 %, 100K 2.37-2.45 -> 2.24-2.29 s, 200K 8.5 -> 7.6 s; the 100K-vertex disk map
    // 5.7-5.8 -> 5.6 s. At 1M the time is even and the conversion adds 119 MB, so it stays
    // supernodal there; below 20K simplicial alone is as fast (bench/RESULTS.md, session 53).
    // The sphere keeps supernodal, unconverted: with simplicial, one sphere mesh's map (man)
    // kept a fold torn across the sphere until area_preserving_sphere's fourth try.
    constexpr int kSupernodalFrom = 20000, kConvertedBelow = 500000;
    single_threaded_blas();  // before CHOLMOD reaches OpenBLAS
    const bool supernodal = sphere || n >= kSupernodalFrom;
    llt_.setMode(supernodal ? Eigen::CholmodSupernodalLLt : Eigen::CholmodSimplicialLLt);
    if (supernodal && !sphere && n < kConvertedBelow) numeric::convert_factors_for_solves(llt_.cholmod());
    llt_.cholmod().print = 0;
    // AMD alone: by default CHOLMOD also tries METIS when AMD's fill is high, which at 1M
    // sites cost far more ordering time than the fill it saved (bench/RESULTS.md).
    llt_.cholmod().nmethods = 1;
    llt_.cholmod().method[0].ordering = CHOLMOD_AMD;
  }

  /// The next direction from a fresh factor (the start moved far).
  void forget() { have_factor_ = false; }
  /// Whether the last direction came from a factor of its own Hessian (then GMRES solves
  /// it to round-off in one or two iterations, whatever eta asked).
  bool fresh() const { return fresh_; }

  /// The step for the heights but the held one, to the relative accuracy eta; pass 0 from
  /// the kept factor, pass 1 from a fresh one. `solved` says whether GMRES converged.
  Eigen::VectorXd solve(const Eigen::SparseMatrix<double>& H, const Eigen::VectorXd& rhs, double eta, int pass,
                        bool& solved) {
    // The kept factor ages: its GMRES iterations grow with every Newton step, while a
    // factorization costs about 20-30 of them. Refactoring once the iterations spent on the
    // current factor reach that cost (the ski-rental rule, counted in iterations rather
    // than clock time so that the result does not depend on the machine's load) keeps the
    // cycle near its optimum of ~3 Newton steps. Not in the quadratic phase (error below
    // 1e-2): two or three steps remain, and at 1M sites a factorization costs seconds.
    constexpr int kBudget = 30, kRefactorAfter = 20;
    // H is symmetric: H^T x is H x, and Eigen splits a row-major product's rows over the
    // OpenMP threads (the column-major one runs on one). Each row sums its entries in column
    // order, as the column-major product does: the same bits, for any thread count.
    auto apply = [&](const Eigen::VectorXd& x) { return Eigen::VectorXd(H.transpose() * x); };
    auto precondition = [&](const Eigen::VectorXd& x) { return Eigen::VectorXd(llt_.solve(x)); };
    Eigen::VectorXd d;
    numeric::KrylovResult kr;
    for (int attempt = 0; attempt < 2 && !kr.converged; ++attempt) {
      const bool fresh = !have_factor_ || (since_factor_ >= kRefactorAfter && r_.max_relative_error > 1e-2) ||
                         attempt > 0 || pass > 0;
      if (fresh) factor(H);
      fresh_ = fresh;
      d = Eigen::VectorXd::Zero(rhs.size());
      kr = numeric::gmres(apply, precondition, rhs, d, eta, fresh ? 100 : kBudget);
      r_.linear_iterations += kr.iterations;
      since_factor_ += kr.iterations;
      if (fresh) break;
    }
    solved = kr.converged;
    return d;
  }

 private:
  void factor(const Eigen::SparseMatrix<double>& H) {
    with_library_loops_serial([&] { llt_.compute(H); });
    if (llt_.info() != Eigen::Success)
      fail(ErrorCode::kNotConverged, "the OMT Hessian is singular at iteration " + std::to_string(r_.iterations) +
                                         " (a cell without neighbours inside the domain)");
    have_factor_ = true;
    since_factor_ = 0;
    ++r_.factorizations;
  }

  OmtResult& r_;
  Eigen::CholmodDecomposition<Eigen::SparseMatrix<double>> llt_;
  bool have_factor_ = false, fresh_ = false;
  int since_factor_ = 0;
};

// Kitagawa-Merigot-Thibert halving along dh. Their decrease test holds in any fixed norm
// (the Newton step scales the gradient by 1 - t to first order); we measure it per cell
// relative to the targets, as the stopping test does: in the plain 2-norm the large cells'
// round-off hides the small cells' progress. 30 halvings (t = 1e-9) without progress mean
// the round-off floor; in the quadratic phase (error below 1e-4, where full steps are
// taken) 4 do; none below `min_step`. Returns the step taken (psi, g and r.cells moved to
// it), 0 if none.
// `second` (0: none) is one more trial between t = 1 and t = 1/2, not counted as a halving.
double line_search(const PowerDiagrams& diagram, const Eigen::VectorXd& dh, double eps0, double tolerance, Offsets& psi,
                 Eigen::VectorXd& g, OmtResult& r, double min_step = 0, double second = 0) {
  const Eigen::VectorXd& nu = r.target;
  const double gnorm = relative_norm(g, nu);
  const int max_halvings = r.max_relative_error < 1e-4 ? 4 : 30;
  std::vector<double> steps{1};
  if (second > 0) steps.push_back(second);
  for (int k = 1; k < max_halvings; ++k) steps.push_back(std::ldexp(1.0, -k));
  for (double t : steps) {
    if (t < min_step) break;
    Offsets trial = psi.plus(t * dh);
    std::optional<PowerCells> c = diagram.at_offsets_if_none_hidden(trial.hi, trial.lo);
    if (!c || c->empty_cells > 0 || c->mass.minCoeff() < eps0) continue;
    Eigen::VectorXd gt = c->mass - nu;
    if (relative_norm(gt, nu) <= (1 - 0.5 * t) * gnorm || max_relative(c->mass, nu) <= tolerance) {
      psi = std::move(trial);
      r.cells = std::move(*c);
      g = std::move(gt);
      return t;
    }
  }
  return 0;
}

}  // namespace

namespace {

// A direction from the kept factor (planar domains) stops its steps at kInexactStepFloor:
// below it the direction, not the damping, is what holds the step back, and the exact one
// is tried before so short a step is taken. Without the floor (and with a quarter of the
// sites per coarse level, as then), mannequin-devil's density onto cylinder_locally_refined's
// 517-site coarsest level took ten steps of t = 1.5e-5 .. 3.7e-9 in a row, each after 16-28
// refused trials, with the error stuck at 16.52, until no step passed and the exact direction
// then took t = 1/32 (the pair: 90 -> 81 Newton iterations, bench/RESULTS.md, session 38).
// Not on the stereographic sphere (the sphere's area-preserving maps): there the changed path
// left man.off's map with 6 folds after the repair, in CI's every-sphere-mesh test; its steps
// stay as they were.
constexpr double kInexactStepFloor = 1e-3;

// line_search's trial between 1 and 1/2 on planar domains, where the previous step was at
// least 1/2 but not full. A scan of omt-bench's damped steps (10K Gaussian, bench/RESULTS.md,
// session 54): the full step hides hundreds of sites, t = 0.8 a few, and t = 0.7 none while it
// cuts the norm to 0.29-0.33 of the start's, where 1/2 cuts it to 0.5. A trial of 0.75 hid a
// few sites and so cost nearly a whole diagram each time (session 39). Not after shorter
// steps: the real pairs' long damped runs (t = 1/128..1/8) would pay a refused trial at every
// iteration (mannequin-devil x patch-01 +9 % with the trial after any damped step). With eps0
// at a tenth (kmt_floor): omt-bench Gaussian 10K 15 -> 12 iterations, 100K 14 -> 13, 1M
// 17 -> 15; the 45 real disk pairs 1,495 -> 1,442. The stereographic sphere keeps plain
// halving.
double second_trial(const Domain& domain, double previous_step) {
  return !domain.is_sphere && previous_step >= 0.5 && previous_step < 1 ? 0.7 : 0;
}

// Alg. 2: damped Newton on the heights h of the power diagram until every cell's mass meets
// its target (eq. 3.27 the gradient, eq. 3.28 the Hessian).
OmtResult solve(const Domain& domain, const Points& sites, const Eigen::VectorXd& nu_in, const OmtOptions& opt) {
  const int n = static_cast<int>(sites.rows());
  check_transport_input(n, nu_in, opt);
  if (opt.dual_gap_tolerance > 0 && domain.is_sphere)
    invalid("the dual gap test is for planar domains (the sphere's cells minimize another cost)");
  OmtResult r;
  r.target = nu_in * (domain.area() / nu_in.sum());
  const Eigen::VectorXd& nu = r.target;
  // Alg. 2 starts from the Voronoi diagram ("h = 0" in the power-distance convention); with
  // u_h = max <x, y_i> + h_i that is h_i = -|y_i|^2 / 2 (equal power weights): psi = 0.
  const PowerDiagrams diagram(domain, sites);
  Offsets psi(n);
  if (opt.initial_h.size() != 0) try_warm_start(diagram, opt.initial_h, psi, r);
  if (!r.warm_started && r.cells.mass.size() == 0) r.cells = diagram.at_offsets(psi.hi);
  if (!r.warm_started && r.cells.empty_cells > 0) shrink_start(domain, diagram, sites, psi, r);
  r.max_relative_error = max_relative(r.cells.mass, nu);
  // OmtOptions::multilevel: the first Newton step from the plain start decides. Where it is
  // damped below 1/4 (real shapes' densities: 1/128..1/8, and dozens of damped steps
  // follow), the coarse-to-fine start is taken instead; where it is not (the synthetic
  // height fields: 1/2, and a handful of full steps after it), the plain solve goes on. No statistic
  // of the start's cells told the two apart (bench/RESULTS.md, sessions 19-20).
  bool probing = opt.multilevel && r.max_relative_error > 10 && n >= 1000 && !domain.is_sphere;
  constexpr double kDampedStep = 0.25;
  if (probing && !opt.multilevel_probe) {
    probing = false;
    coarse_start(domain, diagram, sites, opt, psi, r);
  }
  if (n == 1) {
    r.h = Eigen::VectorXd::Zero(1);
    r.converged = true;
    return r;
  }
  double eps0 = kmt_floor(domain, sites, r);
  Eigen::VectorXd g = r.cells.mass - nu;
  // The Newton step solves for every height but one; the held cell absorbs the round-off
  // of the total mass (sum_i w_i - sum_i nu_i, ~1e-15 at 100K cells). Holding the largest
  // target keeps that below 1e-11 of any cell's mass; holding the first cell left a small
  // cell of a 100K Gaussian case 1.1e-8 off for good.
  int held = 0;
  nu.maxCoeff(&held);
  Directions directions(domain.is_sphere, n, r);
  bool gap_closed = false;
  // OmtOptions::abandon: the dual at the current cells, a lower bound of the cost.
  auto abandon = [&] {
    if (!opt.abandon || domain.is_sphere) return false;
    r.dual_value = dual(psi.hi, psi.lo, r.cells, g);
    return r.abandoned = opt.abandon(r.dual_value);
  };
  detail::StallWatch stall(opt.stall_window);
  for (r.iterations = 0; r.iterations < opt.max_iterations; ++r.iterations) {
    if (r.max_relative_error <= opt.tolerance || abandon()) break;
    // OmtOptions::stall_window (not while probing: one iteration decides there). The norm is
    // an O(n) pass, taken only with a window.
    if (!probing && stall.on() && stall.stalled(relative_norm(g, nu))) {
      r.stalled = true;
      break;
    }
    // The cores of a pool whose other tasks are done (a distance's faster direction): the
    // cells are integrated in parallel. mannequin-devil x three_peaks, whose directions take
    // 0.2 s and 5.6 s, 5.7-8.3 s -> 4.8-6.1 s by bench_pair; balanced pairs show nothing
    // beyond this machine's spread (bench/RESULTS.md, sessions 37-38). Each cell is
    // integrated by one thread, so the results do not depend on the count. (Planar domains:
    // the stereographic sphere's maps keep the path CI's every-sphere-mesh test has passed.)
    if (!domain.is_sphere) take_idle_workers();
    const Eigen::SparseMatrix<double> H = hessian(r.cells, sites, n, held);
    const Eigen::VectorXd rhs = -drop(g, held);
    double step = 0;
    // Two passes: the direction from the kept factor at the forcing-term accuracy; if no
    // step along it is accepted, once more from a fresh factor solved to 1e-10 (an
    // inexact direction measured in the per-cell metric need not descend in the 2-norm of
    // the line search). On planar domains the kept factor's steps stop at kInexactStepFloor.
    for (int pass = 0; pass < (probing ? 1 : 2) && step == 0 && !gap_closed; ++pass) {
      // Forcing term eta = error (superlinear convergence), but no smaller than what
      // brings this step to the tolerance (0.3 tol / error): the last step is not solved
      // beyond what it needs.
      const double e = r.max_relative_error;
      const double eta = pass ? 1e-10 : std::clamp(std::max(e, 0.3 * opt.tolerance / e), 1e-12, 1e-2);
      bool solved = false;
      const Eigen::VectorXd dh = undrop(directions.solve(H, rhs, eta, pass, solved), held);
      if (pass == 0 && opt.dual_gap_tolerance > 0 && solved && r.max_relative_error <= 0.25) {
        const double rise = -g.dot(dh), value = dual(psi.hi, psi.lo, r.cells, g);
        if (rise >= 0 && rise <= opt.dual_gap_tolerance * std::abs(value)) {
          r.dual_value = value;
          r.dual_rise = rise;
          gap_closed = true;
          break;
        }
      }
      const bool floored = pass == 0 && !directions.fresh() && !domain.is_sphere;
      const double min_step = probing ? kDampedStep : floored ? kInexactStepFloor : 0;
      const double second = second_trial(domain, stall.last_step());
      step = line_search(diagram, dh, eps0, opt.tolerance, psi, g, r, min_step, second);
    }
    const bool accepted = step > 0;
    stall.took(step);
    if (gap_closed) break;
    if (std::exchange(probing, false) && !accepted) {  // counted as an iteration: it cost one
      if (coarse_start(domain, diagram, sites, opt, psi, r)) {  // taken (if not, the plain solve goes on)
        stall.restart();
        eps0 = kmt_floor(domain, sites, r);
        g = r.cells.mass - nu;
        directions.forget();
      }
      continue;
    }
    r.max_relative_error = max_relative(r.cells.mass, nu);
    if (opt.progress && !opt.progress(r.iterations + 1, r.max_relative_error))
      fail(ErrorCode::kCancelled, "optimal transport cancelled");
    if (!accepted) {
      ++r.iterations;
      break;  // round-off floor: no step improves any more
    }
  }
  if (!domain.is_sphere && !gap_closed && !r.abandoned) r.dual_value = dual(psi.hi, psi.lo, r.cells, r.cells.mass - nu);
  r.h = (psi.hi - 0.5 * sites.rowwise().squaredNorm()) + psi.lo;
  r.h.array() -= r.h.mean();
  r.converged = (r.max_relative_error <= opt.tolerance || gap_closed) && !r.abandoned && !r.stalled;
  r.iterations += r.coarse_iterations;
  return r;
}

}  // namespace

// The gate on the probe. Near copies: rival / plain 0.97..1.07 in the six directions measured
// in session 44; the unrelated shapes 0.55, 0.74, 1.37 and more, or a rival with empty cells.
// A plain start whose dual is negative is far off (every start near the solution sits just
// below W2^2 > 0): mannequin-devil x remeshed's 12,977-site direction (plain D = -0.30, the
// rival's 4.7e-4) took 248 Newton iterations unprobed and 105 probed. Two of the 45 real
// pairs' directions are probed for it and keep the coarse levels: lion-head x nefertiti
// (+3 iterations, about +0.03 s) and mushroom x three_peaks (+5 on 30 sites).
bool detail::worth_probing(double plain_dual, double rival_dual) {
  constexpr double kNearPlain = 0.15;
  if (!(rival_dual > 0)) return false;  // -inf: the rival leaves a cell empty
  if (plain_dual < 0) return true;
  return plain_dual > 0 && std::abs(rival_dual / plain_dual - 1) <= kNearPlain;
}

OmtResult solve_omt(const Domain& domain, const Points& sites, const Eigen::VectorXd& nu, const OmtOptions& opt) {
  return detail::with_plain_fallback(
      opt, [&](const OmtOptions& o) { return solve(domain, sites, nu, o); }, detail::AfterStall::kPlainStart);
}

}  // namespace brenier::omt

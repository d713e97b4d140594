#include "distance/shape.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <unsupported/Eigen/FFT>

#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <unordered_map>
#include <vector>

#include "common/check.hpp"
#include "common/error.hpp"
#include "common/hash.hpp"
#include "common/version.hpp"
#include "distance/distance.hpp"
#include "mesh/geometry.hpp"
#include "mesh/topology.hpp"
#include "omt/area_preserving.hpp"

namespace brenier::distance {

omt::Points Quadrature::points() const {
  omt::Points p(static_cast<Eigen::Index>(rings) * angles, 2);
  for (int k = 0; k < rings; ++k) {
    const double r = std::sqrt((k + 0.5) / rings);
    for (int j = 0; j < angles; ++j) {
      const double a = 2 * M_PI * (j + 0.5) / angles;
      p.row(static_cast<Eigen::Index>(k) * angles + j) << r * std::cos(a), r * std::sin(a);
    }
  }
  return p;
}

Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> Quadrature::sphere_points() const {
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> p(static_cast<Eigen::Index>(rings) * angles, 3);
  for (int k = 0; k < rings; ++k) {
    const double z = 1 - (2.0 * k + 1) / rings, r = std::sqrt(std::max(0.0, 1 - z * z));
    for (int j = 0; j < angles; ++j) {
      const double a = 2 * M_PI * (j + 0.5) / angles;
      p.row(static_cast<Eigen::Index>(k) * angles + j) << r * std::cos(a), r * std::sin(a), z;
    }
  }
  return p;
}

std::string ShapeOptions::fingerprint() const {
  char buf[320];
  std::snprintf(buf, sizeof buf, "%s;center=%d;boundary=%d;ktol=%.17g;otol=%.17g;wtol=%.17g;ctol=%.17g;quad=%dx%d",
                sphere ? "sphere" : "disk", center_vertex.value_or(-1), boundary_vertex.value_or(-1),
                conformal_tolerance, omt_tolerance, transport_tolerance, cost_tolerance,
                quadrature.rings, quadrature.angles);
  std::string out = buf;
  if (sphere) {  // (the disk's keys stay as they were)
    std::snprintf(buf, sizeof buf, ";merge=%.17g;cap=%.17g", merge_radius, density_cap);
    out += buf;
  }
  return out;
}

std::string shape_key(const mesh::TriMesh& m, const ShapeOptions& opt) {
  Sha256 h;
  h.update(std::string("brenier-shape-v") + kNumericsVersion + "\n" + opt.fingerprint() + "\n");
  const long long counts[2] = {m.V.rows(), m.F.rows()};
  h.update(counts, sizeof counts);
  h.update(m.V.data(), sizeof(double) * m.V.size());
  h.update(m.F.data(), sizeof(int) * m.F.size());
  return h.hex();
}

namespace {

void check_transport_tolerances(const ShapeOptions& opt) {
  if (!(opt.transport_tolerance > 0) || !(opt.omt_tolerance > 0)) invalid("transport tolerances must be positive");
  if (!(opt.cost_tolerance >= 0) || !std::isfinite(opt.cost_tolerance)) invalid("the cost tolerance must be 0 or positive");
}

// The quantization cost from the transport of a shape's density onto its own vertices.
double quantization_cost(const Shape& s, const TransportCost& q) {
  if (!q.converged) {
    char buf[160];
    std::snprintf(buf, sizeof buf, " (max relative cell-mass error %.2e after %d Newton iterations)",
                  q.max_relative_error, q.iterations);
    fail(ErrorCode::kNotConverged, s.name + ": the transport from its density to its own vertices did not converge" +
                                       (q.failure.empty() ? std::string(buf) : " (" + q.failure + ")"));
  }
  return q.w2_squared;
}

void attach_surface(Shape& s) {
  auto surface = std::make_shared<omt::SurfaceDensity>();
  surface->vertices = s.sphere_vertices;
  surface->faces = s.tri;
  surface->density = s.density;
  surface->check();
  s.surface = std::move(surface);
}

// The vertex measure of the sphere image X (rows in the shape's frame), with images closer
// than the merge radius as one site, and the transport of the uniform sphere onto it.
struct SphereTransport {
  omt::Points3 merged;        // the sites on the sphere
  std::vector<int> site_of;   // each vertex's site
  omt::Points sites;          // the sites in the stereographic plane from the pole
  Eigen::Matrix3d R;          // rows R x: the pole at +z
  Eigen::VectorXd mass;       // each site's: the masses of its vertices
  omt::OmtResult omt;
  double radius = 0;          // the merge radius used
};

// Where the transport does not converge at ShapeOptions::merge_radius, the radius grows
// tenfold, up to 1e-3: camel and diplodocus keep clusters of sites 1e-5..1e-4 apart (of
// camel's 9,770 vertices, 6,131 lie within 1e-4 of another), whose first Newton step hid a
// site at every step length. Their OMT-map distances to blobby moved by 2e-5 and 4e-5
// between 1e-4 and 1e-3. The radius used is the shape's merge_radius.
SphereTransport transport_onto_vertices(const mesh::Vertices& X, const Eigen::VectorXd& vertex_mass,
                                        const ShapeOptions& opt, const omt::Progress& progress, const std::string& name) {
  constexpr double kLargestRadius = 1e-3;
  SphereTransport t;
  // The transport runs in the stereographic plane with its quadratic cost, which depends on
  // where the pole is: every shape puts it at the same place of its frame, so that all maps
  // answer the same transport problem (a pole per shape, as the area-preserving map picks,
  // made bear and its remesh bear_bis look unrelated). The direction (1, 2, 3) / sqrt(14)
  // avoids the frame's axes and planes, where symmetric meshes put vertices.
  const Eigen::Vector3d pole = Eigen::Vector3d(1, 2, 3).normalized();
  t.R = Eigen::Quaterniond::FromTwoVectors(pole, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  for (t.radius = opt.merge_radius;; t.radius *= 10) {
    t.merged = merge_sphere_sites(X, t.radius, t.site_of);
    t.mass = Eigen::VectorXd::Zero(t.merged.rows());
    for (Eigen::Index v = 0; v < X.rows(); ++v) t.mass[t.site_of[v]] += vertex_mass[v];
    const omt::Points3 Y = t.merged * t.R.transpose();
    t.sites.resize(Y.rows(), 2);
    double nearest = 2;
    for (Eigen::Index v = 0; v < Y.rows(); ++v) {
      nearest = std::min(nearest, (t.merged.row(v).transpose() - pole).norm());
      t.sites.row(v) << Y(v, 0) / (1 - Y(v, 2)), Y(v, 1) / (1 - Y(v, 2));
    }
    if (nearest < 1e-7)
      fail(ErrorCode::kNotConverged, name + ": a vertex's image lies on the pole of the stereographic projection");
    omt::OmtOptions oopt;
    oopt.tolerance = opt.omt_tolerance;
    oopt.progress = progress;
    t.omt = omt::solve_omt(omt::Domain::stereographic_sphere(), t.sites, t.mass, oopt);
    if (t.omt.converged) return t;
    if (t.radius == 0 || t.radius * 10 > kLargestRadius * (1 + 1e-9)) break;
  }
  char buf[240];
  std::snprintf(buf, sizeof buf,
                ": the transport of the sphere onto the vertex measure did not converge (max relative cell-mass "
                "error %.2e after %d Newton iterations, vertex images merged within %.1e)",
                t.omt.max_relative_error, t.omt.iterations, t.radius);
  fail(ErrorCode::kNotConverged, name + buf);
}

// Def. 2.24's OMT map on the sphere: the conformal sphere map (sec. 3.2.5) in its principal
// frame, the transport from the sphere's uniform measure onto the vertex measure through
// the stereographic plane from the frame's third axis (Domain::stereographic_sphere, the
// construction of the area-preserving sphere map), and each quadrature point takes the
// position of its cell's site.
Shape prepare_sphere(const mesh::TriMesh& m, const ShapeOptions& opt, Shape s, const omt::Progress& progress) {
  if (opt.center_vertex || opt.boundary_vertex)
    invalid(s.name + ": markers are for the disk; on the sphere the frame comes from the shape");
  if (opt.quadrature.angles % 2 != 0) invalid("the sphere's quadrature needs an even number of angles");
  conformal::ConformalOptions copt;
  copt.tolerance = opt.conformal_tolerance;
  copt.progress = progress;
  const conformal::ConformalMap c = conformal::map_to_sphere(m, copt);
  if (!c.converged)
    fail(ErrorCode::kNotConverged, s.name + ": the conformal sphere map did not converge (max |K - Kbar| = " +
                                       std::to_string(c.max_curvature_error) + ")");
  if (c.folded_faces > 0)
    fail(ErrorCode::kNotConverged, s.name + ": the conformal sphere map folds " + std::to_string(c.folded_faces) + " faces");
  s.sphere = true;
  s.conformal_iterations = c.newton_iterations;
  s.curvature_error = c.max_curvature_error;
  s.tri = m.F;
  s.mass = mesh::vertex_areas(m) * (4 * M_PI / mesh::total_area(m));
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  for (int v = 0; v < m.num_vertices(); ++v) M += s.mass[v] * c.positions.row(v).transpose() * c.positions.row(v);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(M);
  Eigen::Matrix3d E;
  E.col(0) = eig.eigenvectors().col(2);
  E.col(1) = eig.eigenvectors().col(1);
  // Each axis points where the area's third moment along it is positive (the skewed side):
  // a rotated copy then gets the same frame, not one turned by a half-turn.
  for (int k = 0; k < 2; ++k) {
    double third = 0;
    for (int v = 0; v < m.num_vertices(); ++v) third += s.mass[v] * std::pow(c.positions.row(v).dot(E.col(k)), 3);
    if (third < 0) E.col(k) = -E.col(k);
  }
  E.col(2) = E.col(0).cross(E.col(1));
  const mesh::Vertices X = c.positions * E;  // rows E^T x: coordinates in the frame
  const SphereTransport t = transport_onto_vertices(X, s.mass, opt, progress, s.name);
  const omt::Points3& merged = t.merged;
  const omt::Points& sites = t.sites;
  const omt::OmtResult& r = t.omt;
  const Eigen::Matrix3d& R = t.R;
  s.merge_radius = t.radius;
  s.mass = t.mass;
  for (int v = 0; v < m.num_vertices(); ++v)
    s.merge_shift = std::max(s.merge_shift, (X.row(v) - merged.row(t.site_of[v])).norm());
  s.merged_vertices = m.num_vertices() - static_cast<int>(merged.rows());
  s.normalization = c.normalization + ", principal frame of the pushed-forward area (eigenvalues " +
                    std::to_string(eig.eigenvalues()[2]) + ", " + std::to_string(eig.eigenvalues()[1]) + ", " +
                    std::to_string(eig.eigenvalues()[0]) + ")";
  s.sites = sites;
  s.h = r.h;
  s.omt_iterations = r.iterations;
  s.omt_error = r.max_relative_error;
  const Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> q = opt.quadrature.sphere_points() * R.transpose();
  omt::Points plane(q.rows(), 2);
  for (Eigen::Index k = 0; k < q.rows(); ++k) {
    // A point at the pole itself (measure zero) is nudged off it.
    const double d = std::max(1 - q(k, 2), 1e-300);
    plane.row(k) << q(k, 0) / d, q(k, 1) / d;
  }
  const std::vector<int> cell = omt::PowerDiagrams(omt::Domain::stereographic_sphere(), sites, false).locate(r.h, plane);
  s.sphere_samples.resize(q.rows(), 3);
  for (Eigen::Index k = 0; k < q.rows(); ++k) s.sphere_samples.row(k) = merged.row(cell[k]);
  // The exact distance's source measure: the surface's area (4 pi in all) on the flat
  // triangles of its sphere image, constant on each, and its quantization cost (the
  // shape's density onto its own vertices, solved as a pair's direction is).
  s.sphere_sites = merged;
  s.sphere_vertices = X;
  const Eigen::VectorXd area = mesh::face_areas(m) * (4 * M_PI / mesh::total_area(m));
  const Eigen::VectorXd image = mesh::face_areas(m.F, X);
  for (int f = 0; f < m.num_faces(); ++f)
    if (!(image[f] > 0))
      fail(ErrorCode::kNotConverged, s.name + ": face " + std::to_string(f) + " has no area in the sphere image");
  Eigen::VectorXd mass = area;
  const DensityCap capped = cap_density(m.F, X, image, opt.density_cap, mass);
  s.density_shift = capped.shift;
  s.capped_mass = capped.moved;
  s.density = mass.cwiseQuotient(image);
  attach_surface(s);
  Eigen::VectorXd start;
  s.quantization = quantization_cost(s, transport_cost_sphere(s, s, Eigen::Vector3d::Ones(), progress, start));
  return s;
}

}  // namespace

// cap_density (shape.hpp): the sets over the cap are found by a walk across edges, and the
// rings around each by breadth-first search from it.
DensityCap cap_density(const mesh::Faces& F, const mesh::Vertices& X, const Eigen::VectorXd& image, double cap,
                       Eigen::VectorXd& mass) {
  DensityCap out;
  const int nf = static_cast<int>(F.rows());
  auto room = [&](int f) { return cap * image[f] - mass[f]; };
  std::vector<int> heavy;
  for (int f = 0; f < nf; ++f)
    if (room(f) < 0) heavy.push_back(f);
  if (heavy.empty() || !(cap > 0)) return out;
  // across[f][k]: the face across edge (F(f, k), F(f, k + 1)).
  const std::vector<std::array<int, 3>> across = mesh::face_neighbors(F);
  std::vector<int> seen(nf, -1);  // the set (its first face) that visited the face
  double total = mass.sum();
  for (int h0 : heavy) {
    if (seen[h0] >= 0) continue;
    // The connected set of faces over the cap around h0, its excess taken off.
    std::vector<int> set{h0}, ring;
    seen[h0] = h0;
    double excess = 0;
    for (size_t i = 0; i < set.size(); ++i) {
      const int f = set[i];
      excess += -room(f);
      mass[f] = cap * image[f];
      for (int g : across[f])
        if (g >= 0 && seen[g] != h0 && room(g) < 0) seen[g] = h0, set.push_back(g);
    }
    out.moved += excess;
    const Eigen::RowVector3d c = X.row(F(h0, 0));
    double r_set = 0, r_rings = 0;
    for (int f : set)
      for (int k = 0; k < 3; ++k) r_set = std::max(r_set, (X.row(F(f, k)) - c).norm());
    // Rings outward, each filled to the cap until the excess is placed.
    std::vector<int> front = set;
    while (excess > 0 && !front.empty()) {
      ring.clear();
      for (int f : front)
        for (int g : across[f])
          if (g >= 0 && seen[g] != h0) seen[g] = h0, ring.push_back(g);
      double space = 0;
      for (int g : ring) space += std::max(0.0, room(g));
      const double share = space > excess ? excess / space : 1;
      for (int g : ring) {
        if (room(g) <= 0) continue;
        mass[g] += share * room(g);
        for (int k = 0; k < 3; ++k) r_rings = std::max(r_rings, (X.row(F(g, k)) - c).norm());
      }
      excess -= share * space;
      if (share < 1) excess = 0;
      front.swap(ring);
    }
    BRENIER_CHECK(excess <= 1e-12 * total, "the density cap found no room for a peak's mass");
    out.shift = std::max(out.shift, r_set + r_rings);
  }
  out.moved /= total;
  return out;
}

omt::Points3 merge_sphere_sites(const omt::Points3& X, double radius, std::vector<int>& site_of) {
  // Below 1e-15 the grid's cell indices (coordinates / radius) would leave a long long; no
  // transport resolves sites that close anyway.
  if (!(radius == 0 || (radius >= 1e-15 && std::isfinite(radius))))
    invalid("the merge radius must be 0 or between 1e-15 and infinity");
  const Eigen::Index n = X.rows();
  site_of.assign(n, -1);
  std::vector<Eigen::Index> sites;
  if (radius == 0) {
    for (Eigen::Index v = 0; v < n; ++v) site_of[v] = static_cast<int>(v);
    return X;
  }
  // Grid cells of side `radius`: a site within `radius` of x lies in one of the 27 cells
  // around x's own.
  auto cell_of = [radius](double t) { return static_cast<long long>(std::floor(t / radius)); };
  auto key = [](long long i, long long j, long long k) {
    return (static_cast<unsigned long long>(i) * 73856093ULL) ^ (static_cast<unsigned long long>(j) * 19349663ULL) ^
           (static_cast<unsigned long long>(k) * 83492791ULL);
  };
  std::unordered_map<unsigned long long, std::vector<int>> grid;
  for (Eigen::Index v = 0; v < n; ++v) {
    const long long ci = cell_of(X(v, 0)), cj = cell_of(X(v, 1)), ck = cell_of(X(v, 2));
    int found = -1;
    for (long long di = -1; di <= 1 && found < 0; ++di)
      for (long long dj = -1; dj <= 1 && found < 0; ++dj)
        for (long long dk = -1; dk <= 1 && found < 0; ++dk) {
          const auto it = grid.find(key(ci + di, cj + dj, ck + dk));
          if (it == grid.end()) continue;
          for (const int site : it->second)
            if ((X.row(v) - X.row(sites[site])).norm() < radius) {
              found = site;
              break;
            }
        }
    if (found < 0) {
      found = static_cast<int>(sites.size());
      sites.push_back(v);
      grid[key(ci, cj, ck)].push_back(found);
    }
    site_of[v] = found;
  }
  omt::Points3 out(static_cast<Eigen::Index>(sites.size()), 3);
  for (size_t k = 0; k < sites.size(); ++k) out.row(static_cast<Eigen::Index>(k)) = X.row(sites[k]);
  return out;
}

Shape prepare_shape(const mesh::TriMesh& m, const std::string& name, const ShapeOptions& opt,
                    const omt::Progress& progress) {
  if (opt.quadrature.rings < 1 || opt.quadrature.angles < 4)
    invalid("the quadrature needs at least 1 ring and 4 angles");
  if (opt.center_vertex.has_value() != opt.boundary_vertex.has_value())
    invalid(name + ": give both markers (an interior and a boundary vertex) or neither");
  Shape s;
  s.name = name;
  s.key = shape_key(m, opt);
  s.vertices = m.num_vertices();
  s.faces = m.num_faces();
  s.rings = opt.quadrature.rings;
  s.angles = opt.quadrature.angles;
  check_transport_tolerances(opt);
  s.transport_tolerance = opt.transport_tolerance;
  s.cost_tolerance = opt.cost_tolerance;
  if (opt.sphere) return prepare_sphere(m, opt, std::move(s), progress);
  // Alg. 5 step 2: the conformal map onto the unit disk, Moebius-normalized (Thm 2.13).
  conformal::ConformalOptions copt;
  copt.tolerance = opt.conformal_tolerance;
  copt.progress = progress;
  copt.center_vertex = opt.center_vertex;
  copt.boundary_vertex = opt.boundary_vertex;
  const conformal::ConformalMap c = conformal::map_to_disk(m, copt);
  if (!c.converged)
    fail(ErrorCode::kNotConverged, name + ": the conformal map did not converge (max |K - Kbar| = " +
                                       std::to_string(c.max_curvature_error) + ")");
  if (c.folded_faces > 0)
    fail(ErrorCode::kNotConverged, name + ": the conformal map folds " + std::to_string(c.folded_faces) + " faces");
  s.markers = opt.center_vertex.has_value();
  s.normalization = c.normalization;
  s.conformal_iterations = c.newton_iterations;
  s.curvature_error = c.max_curvature_error;
  s.sites = c.positions.leftCols<2>();
  // Alg. 5 step 1: area pi. Vertex masses of eq. 3.30 and the density of eq. 2.57 per face.
  const Eigen::VectorXd area = mesh::face_areas(m) * (M_PI / mesh::total_area(m));
  s.tri = m.F;
  s.mass = Eigen::VectorXd::Zero(m.num_vertices());
  s.density.resize(m.num_faces());
  for (int f = 0; f < m.num_faces(); ++f) {
    for (int k = 0; k < 3; ++k) s.mass[m.F(f, k)] += area[f] / 3;
    const Eigen::Vector2d a = s.sites.row(m.F(f, 0)), b = s.sites.row(m.F(f, 1)), d = s.sites.row(m.F(f, 2));
    const double image = 0.5 * ((b - a).x() * (d - a).y() - (b - a).y() * (d - a).x());
    if (!(image > 0))
      fail(ErrorCode::kNotConverged, name + ": face " + std::to_string(f) + " has no area in the conformal image");
    s.density[f] = area[f] / image;
  }
  s.density_domain = std::make_shared<const omt::Domain>(omt::Domain::piecewise_constant(s.sites, s.tri, s.density));
  // Def. 2.24's OMT map: the transport from the uniform disk onto the vertex measure
  // (Alg. 2), sampled on the quadrature: each point takes the site of its power cell.
  omt::OmtOptions oopt;
  oopt.tolerance = opt.omt_tolerance;
  oopt.progress = progress;
  const omt::OmtResult r = omt::transport_to_mesh_sites(m, omt::Domain::unit_disk(), s.sites, s.mass, oopt);
  s.h = r.h;
  s.omt_iterations = r.iterations;
  s.omt_error = r.max_relative_error;
  const std::vector<int> cell =
      omt::PowerDiagrams(omt::Domain::unit_disk(), s.sites, false).locate(r.h, opt.quadrature.points());
  // The quantization cost (WassersteinOptions::debias), solved exactly as a pair's
  // direction with this shape on both sides is (same start, same tolerance).
  Eigen::VectorXd start;
  s.quantization = quantization_cost(s, transport_cost(s, s, 0.0, progress, start));
  s.quantization_h = start;
  const int R = opt.quadrature.rings, A = opt.quadrature.angles;
  s.samples.resize(R, A);
  s.spectrum.resize(R, A);
  Eigen::FFT<double> fft;
  std::vector<std::complex<double>> ring(A), freq(A);
  for (int k = 0; k < R; ++k) {
    for (int j = 0; j < A; ++j) {
      const int i = cell[static_cast<size_t>(k) * A + j];
      ring[j] = {s.sites(i, 0), s.sites(i, 1)};
      s.samples(k, j) = ring[j];
    }
    fft.fwd(freq, ring);
    for (int j = 0; j < A; ++j) s.spectrum(k, j) = freq[j];
  }
  return s;
}

// ---- cache files -------------------------------------------------------------------------

namespace {

constexpr char kMagic[8] = {'B', 'R', 'S', 'H', 'A', 'P', 'E', '9'};

struct Writer {
  std::ostream& os;
  template <class T>
  void pod(const T& v) { os.write(reinterpret_cast<const char*>(&v), sizeof v); }
  void str(const std::string& s) {
    pod<long long>(static_cast<long long>(s.size()));
    os.write(s.data(), static_cast<std::streamsize>(s.size()));
  }
  template <class M>
  void mat(const M& m) {
    pod<long long>(m.rows());
    pod<long long>(m.cols());
    os.write(reinterpret_cast<const char*>(m.data()), static_cast<std::streamsize>(sizeof(typename M::Scalar) * m.size()));
  }
};

struct Reader {
  std::istream& is;
  bool ok = true;
  template <class T>
  void pod(T& v) {
    if (ok) ok = static_cast<bool>(is.read(reinterpret_cast<char*>(&v), sizeof v));
  }
  void str(std::string& s) {
    long long n = -1;
    pod(n);
    if (!ok || n < 0 || n > (1 << 20)) return void(ok = false);
    s.resize(static_cast<size_t>(n));
    ok = static_cast<bool>(is.read(s.data(), n));
  }
  template <class M>
  void mat(M& m) {
    long long r = -1, c = -1;
    pod(r);
    pod(c);
    if (!ok || r < 0 || c < 0 || r * c > (1LL << 31)) return void(ok = false);
    if ((M::RowsAtCompileTime != Eigen::Dynamic && r != M::RowsAtCompileTime) ||
        (M::ColsAtCompileTime != Eigen::Dynamic && c != M::ColsAtCompileTime))
      return void(ok = false);
    m.resize(r, c);
    ok = static_cast<bool>(is.read(reinterpret_cast<char*>(m.data()), static_cast<std::streamsize>(sizeof(typename M::Scalar) * m.size())));
  }
};

}  // namespace

void save_shape(const Shape& s, const std::string& path) {
  // A name of its own per process and call: tiles on several machines may share the cache.
  static std::atomic<long> serial{0};
  const std::string tmp = path + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(serial++);
  {
    std::ofstream os(tmp, std::ios::binary | std::ios::trunc);
    if (!os) fail(ErrorCode::kNotFound, "cannot write the cache file " + tmp);
    Writer w{os};
    os.write(kMagic, sizeof kMagic);
    w.str(s.key);
    w.str(s.name);
    w.str(s.normalization);
    w.pod(s.vertices);
    w.pod(s.faces);
    w.pod(s.markers);
    w.pod(s.sphere);
    w.pod(s.rings);
    w.pod(s.angles);
    w.pod(s.conformal_iterations);
    w.pod(s.curvature_error);
    w.pod(s.omt_iterations);
    w.pod(s.omt_error);
    w.pod(s.quantization);
    w.pod(s.transport_tolerance);
    w.pod(s.cost_tolerance);
    w.pod(s.merged_vertices);
    w.pod(s.merge_shift);
    w.pod(s.density_shift);
    w.pod(s.merge_radius);
    w.pod(s.capped_mass);
    w.mat(s.sites);
    w.mat(s.mass);
    w.mat(s.tri);
    w.mat(s.density);
    w.mat(s.h);
    w.mat(s.quantization_h);
    w.mat(s.samples);
    w.mat(s.spectrum);
    w.mat(s.sphere_samples);
    w.mat(s.sphere_sites);
    w.mat(s.sphere_vertices);
    os.write(kMagic, sizeof kMagic);  // a whole file ends as it begins
    if (!os.flush()) fail(ErrorCode::kResourceExhausted, "cannot write the cache file " + tmp);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    fail(ErrorCode::kNotFound, "cannot move the cache file into place: " + path);
  }
}

bool load_shape(const std::string& path, Shape& out) {
  std::ifstream is(path, std::ios::binary);
  if (!is) return false;
  char magic[8];
  if (!is.read(magic, 8) || !std::equal(magic, magic + 8, kMagic)) return false;
  Shape s;
  Reader r{is};
  r.str(s.key);
  r.str(s.name);
  r.str(s.normalization);
  r.pod(s.vertices);
  r.pod(s.faces);
  r.pod(s.markers);
  r.pod(s.sphere);
  r.pod(s.rings);
  r.pod(s.angles);
  r.pod(s.conformal_iterations);
  r.pod(s.curvature_error);
  r.pod(s.omt_iterations);
  r.pod(s.omt_error);
  r.pod(s.quantization);
  r.pod(s.transport_tolerance);
  r.pod(s.cost_tolerance);
  r.pod(s.merged_vertices);
  r.pod(s.merge_shift);
  r.pod(s.density_shift);
  r.pod(s.merge_radius);
  r.pod(s.capped_mass);
  r.mat(s.sites);
  r.mat(s.mass);
  r.mat(s.tri);
  r.mat(s.density);
  r.mat(s.h);
  r.mat(s.quantization_h);
  r.mat(s.samples);
  r.mat(s.spectrum);
  r.mat(s.sphere_samples);
  r.mat(s.sphere_sites);
  r.mat(s.sphere_vertices);
  if (!r.ok || !is.read(magic, 8) || !std::equal(magic, magic + 8, kMagic)) return false;
  // Sites: one per vertex on the disk; on the sphere, as many as the merge left.
  const Eigen::Index nsites = s.sphere ? s.vertices - s.merged_vertices : s.vertices;
  if (s.merged_vertices < 0 || (!s.sphere && s.merged_vertices != 0) || nsites < 1) return false;
  if (s.sites.rows() != nsites || s.mass.size() != nsites || s.tri.rows() != s.faces ||
      s.density.size() != s.faces || s.h.size() != nsites ||
      (s.quantization_h.size() != 0 && s.quantization_h.size() != nsites) ||
      (s.sphere && (s.sphere_sites.rows() != nsites || s.sphere_vertices.rows() != s.vertices)) ||
      s.samples.rows() != s.spectrum.rows() || s.samples.cols() != s.spectrum.cols())
    return false;
  const long long samples = static_cast<long long>(s.rings) * s.angles;
  if (s.rings < 1 || s.angles < 4 ||
      (s.sphere ? s.sphere_samples.rows() != samples : s.samples.rows() != s.rings || s.samples.cols() != s.angles))
    return false;
  if (s.faces > 0 && (s.tri.minCoeff() < 0 || s.tri.maxCoeff() >= s.vertices)) return false;
  try {
    if (s.sphere)
      attach_surface(s);
    else
      s.density_domain =
          std::make_shared<const omt::Domain>(omt::Domain::piecewise_constant(s.sites, s.tri, s.density));
  } catch (const Error&) {
    return false;  // a damaged file: prepared anew
  }
  out = std::move(s);
  return true;
}

}  // namespace brenier::distance

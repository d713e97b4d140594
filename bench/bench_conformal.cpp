// Conformal maps on real meshes: time and quality (flipped faces, angle distortion), ours
// beside CGAL's Discrete_conformal_map_parameterizer_3 (circular arc-length border, Eigen
// solver) on the disk meshes. A timed harness: prints one table (Markdown).
// Run: build/bench/bench_conformal [DATA_DIR]   (after scripts/fetch-data.sh)
// Brenier timings are the median of three runs; CGAL runs once.
#include <CGAL/Polygon_mesh_processing/measure.h>
#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_parameterization/Circular_border_parameterizer_3.h>
#include <CGAL/Surface_mesh_parameterization/Discrete_conformal_map_parameterizer_3.h>
#include <CGAL/Surface_mesh_parameterization/parameterize.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <map>
#include <stdexcept>
#include <string>

#include "conformal/conformal_map.hpp"
#include "omt/area_preserving.hpp"
#include "mesh/geometry.hpp"
#include "mesh/shapes.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"
#include "quality/quality.hpp"

using namespace brenier;
namespace SMP = CGAL::Surface_mesh_parameterization;
using K = CGAL::Simple_cartesian<double>;
using SurfaceMesh = CGAL::Surface_mesh<K::Point_3>;

namespace {

double now() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// Median of three runs: this VM's timings vary by about +-30 % from run to run.
template <typename Fn>
double median_seconds(Fn&& fn) {
  double t[3];
  for (double& x : t) {
    double t0 = now();
    fn();
    x = now() - t0;
  }
  std::sort(t, t + 3);
  return t[1];
}

std::string sci(double x) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1e", x);
  return buf;
}

void row(const std::string& name, int nv, const char* who, double secs, const quality::MapQuality& q,
         const std::string& note = "") {
  std::printf("| %s | %d | %s | %.3f | %d | %.2f | %.2f | %.1f | %s |\n", name.c_str(), nv, who, secs,
              q.flipped_faces, q.angle_distortion_deg.mean, q.angle_distortion_deg.p95,
              q.angle_distortion_deg.max, note.c_str());
  std::fflush(stdout);
}

// CGAL's discrete conformal map with the boundary on a circle by arc length.
bool cgal_dcm(const mesh::TriMesh& m, mesh::Vertices& out, double& secs) {
  SurfaceMesh sm;
  std::vector<SurfaceMesh::Vertex_index> vi;
  for (int i = 0; i < m.num_vertices(); ++i) vi.push_back(sm.add_vertex(K::Point_3(m.V(i, 0), m.V(i, 1), m.V(i, 2))));
  for (int f = 0; f < m.num_faces(); ++f) sm.add_face(vi[m.F(f, 0)], vi[m.F(f, 1)], vi[m.F(f, 2)]);
  double t0 = now();
  auto bhd = CGAL::Polygon_mesh_processing::longest_border(sm).first;
  auto uv = sm.add_property_map<SurfaceMesh::Vertex_index, K::Point_2>("v:uv").first;
  using Border = SMP::Circular_border_arc_length_parameterizer_3<SurfaceMesh>;
  using Param = SMP::Discrete_conformal_map_parameterizer_3<SurfaceMesh, Border>;
  SMP::Error_code err = SMP::parameterize(sm, Param(), bhd, uv);
  secs = now() - t0;
  if (err != SMP::OK) return false;
  out = mesh::Vertices::Zero(m.num_vertices(), 3);
  for (int i = 0; i < m.num_vertices(); ++i) {
    out(i, 0) = uv[vi[i]].x();
    out(i, 1) = uv[vi[i]].y();
  }
  return true;
}

// The faces `faces` of `m` with the vertices they use, renumbered in order of first use.
mesh::TriMesh keep_faces(const mesh::TriMesh& m, const std::vector<int>& faces) {
  std::vector<int> id(m.num_vertices(), -1);
  mesh::TriMesh out;
  out.F.resize(static_cast<int>(faces.size()), 3);
  int n = 0;
  for (size_t i = 0; i < faces.size(); ++i)
    for (int k = 0; k < 3; ++k) {
      int& v = id[m.F(faces[i], k)];
      if (v < 0) v = n++;
      out.F(static_cast<int>(i), k) = v;
    }
  out.V.resize(n, 3);
  for (int v = 0; v < m.num_vertices(); ++v)
    if (id[v] >= 0) out.V.row(id[v]) = m.V.row(v);
  return out;
}

// Throws unless `m` is a valid topological disk (the benchmark must not time something else).
const mesh::TriMesh& require_disk(const mesh::TriMesh& m, const char* what) {
  mesh::Report report = mesh::validate(m);
  if (report.has_errors()) throw std::runtime_error(std::string(what) + ": " + report.first_error()->message);
  mesh::Topology t = mesh::compute_topology(m);
  if (t.mesh_class != mesh::MeshClass::kDisk)
    throw std::runtime_error(std::string(what) + " is not a disk (" + std::to_string(t.boundary_loops) + " boundary loops)");
  return m;
}

// A real-mesh disk of at least `count` vertices cut from the disk `m`: the faces reached first
// by a breadth-first search over shared edges from the face at the default centre vertex;
// the pockets the search leaves at its rim (unreached faces not connected to the rest of
// the unreached ones) are filled, so the patch has a single boundary loop.
mesh::TriMesh patch(const mesh::TriMesh& m, int count) {
  const int nf = m.num_faces();
  std::map<std::pair<int, int>, std::vector<int>> edge_faces;
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) {
      int a = m.F(f, k), b = m.F(f, (k + 1) % 3);
      edge_faces[{std::min(a, b), std::max(a, b)}].push_back(f);
    }
  std::vector<std::vector<int>> nbr(nf);
  for (const auto& [e, fs] : edge_faces)
    if (fs.size() == 2) {
      nbr[fs[0]].push_back(fs[1]);
      nbr[fs[1]].push_back(fs[0]);
    }
  const int centre = mesh::default_hole_vertex(m);
  int seed = 0;
  for (int f = 0; f < nf; ++f)
    if (m.F(f, 0) == centre || m.F(f, 1) == centre || m.F(f, 2) == centre) seed = f;
  std::vector<char> in(nf, 0), seen_vertex(m.num_vertices(), 0);
  std::vector<int> queue{seed};
  in[seed] = 1;
  int vertices = 0;
  for (size_t q = 0; q < queue.size() && vertices < count; ++q) {
    for (int k = 0; k < 3; ++k) vertices += !seen_vertex[m.F(queue[q], k)]++;
    for (int g : nbr[queue[q]])
      if (!in[g]) {
        in[g] = 1;
        queue.push_back(g);
      }
  }
  // Components of the faces left out; all but the largest are pockets.
  std::vector<int> comp(nf, -1), size;
  for (int f = 0; f < nf; ++f) {
    if (in[f] || comp[f] >= 0) continue;
    const int c = static_cast<int>(size.size());
    size.push_back(0);
    std::vector<int> stack{f};
    comp[f] = c;
    while (!stack.empty()) {
      int g = stack.back();
      stack.pop_back();
      ++size[c];
      for (int h : nbr[g])
        if (!in[h] && comp[h] < 0) {
          comp[h] = c;
          stack.push_back(h);
        }
    }
  }
  const int outer = static_cast<int>(std::max_element(size.begin(), size.end()) - size.begin());
  std::vector<int> faces;
  for (int f = 0; f < nf; ++f)
    if (in[f] || comp[f] != outer) faces.push_back(f);
  mesh::TriMesh out = keep_faces(m, faces);
  require_disk(out, "the patch");
  return out;
}

// The disk `m` with its outermost ring of faces removed, again and again, until at most
// `count` vertices remain (a smaller disk of the same mesh, with the same triangle shapes).
mesh::TriMesh peel(mesh::TriMesh m, int count) {
  while (m.num_vertices() > count) {
    std::vector<char> rim(m.num_vertices(), 0);
    for (const auto& loop : mesh::boundary_loops(m))
      for (int v : loop) rim[v] = 1;
    std::vector<int> faces;
    for (int f = 0; f < m.num_faces(); ++f)
      if (!rim[m.F(f, 0)] && !rim[m.F(f, 1)] && !rim[m.F(f, 2)]) faces.push_back(f);
    m = keep_faces(m, faces);
  }
  require_disk(m, "the peeled mesh");
  return m;
}

}  // namespace

int main(int argc, char** argv) {
  std::string data = argc > 1 ? argv[1] : BRENIER_DATA_DIR;
  // `bench_conformal DATA --write-peeled FILE`: only write the ~100K-vertex disk, for timing
  // it through `brenier-compute map FILE --json` (seconds.map).
  if (argc > 3 && std::string(argv[2]) == "--write-peeled") {
    mesh::TriMesh big = mesh::subdivide_midpoint(mesh::subdivide_midpoint(mesh::load_mesh(data + "/lion-head.off").mesh));
    mesh::write_mesh_file(argv[3], peel(big, 100000));
    return 0;
  }
  std::printf("| mesh | vertices | method | seconds | flipped faces | angle mean (deg) | p95 | max | note |\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  struct DiskCase {
    std::string name;
    mesh::TriMesh mesh;
  };
  std::vector<DiskCase> disks;
  for (const char* f : {"lion-head.off", "mannequin-devil.off", "three_peaks.off", "nefertiti.off", "mushroom.off"})
    disks.push_back({f, mesh::load_mesh(data + "/" + f).mesh});
  {
    mesh::TriMesh big = mesh::subdivide_midpoint(mesh::subdivide_midpoint(mesh::load_mesh(data + "/lion-head.off").mesh));
    disks.push_back({"lion-head x16 (midpoint subdivided twice)", big});
    disks.push_back({"lion-head x16 peeled to 100K vertices", peel(big, 100000)});
  }
  {
    mesh::TriMesh big = mesh::subdivide_midpoint(mesh::subdivide_midpoint(mesh::load_mesh(data + "/mannequin-devil.off").mesh));
    disks.push_back({"mannequin-devil x16, a patch around its centre", patch(big, 87000)});
  }
  for (const auto& c : disks) {
    conformal::ConformalMap map;
    double secs = median_seconds([&] { map = conformal::map_to_disk(c.mesh); });
    row(c.name, c.mesh.num_vertices(), "brenier disk", secs,
        quality::measure(c.mesh, map.positions, quality::Target::kPlane),
        std::to_string(map.newton_iterations) + " Newton its, max|K-Kbar| " + sci(map.max_curvature_error));
    mesh::Vertices uv;
    double cs = 0;
    if (cgal_dcm(c.mesh, uv, cs))
      row(c.name, c.mesh.num_vertices(), "CGAL DCM", cs, quality::measure(c.mesh, uv, quality::Target::kPlane));
    else
      std::printf("| %s | %d | CGAL DCM | - | - | - | - | - | failed |\n", c.name.c_str(), c.mesh.num_vertices());
  }
  // The whole area-preserving pipeline (conformal map, transport, centroids, fold repair,
  // face-by-face refinement)
  // on the ~100K-vertex disk, once; angle columns are the area-preserving map's, the note
  // gives its area distortion (mean |log area ratio|) beside the conformal map's.
  for (const auto& c : disks) {
    if (c.name.find("peeled") == std::string::npos) continue;
    double t0 = now();
    omt::AreaPreservingMap ap = omt::area_preserving_disk(c.mesh);
    const double secs = now() - t0;
    auto q = quality::measure(c.mesh, ap.positions, quality::Target::kPlane);
    auto qc = quality::measure(c.mesh, ap.conformal.positions, quality::Target::kPlane);
    char note[300];
    const omt::AreaRefinement& r = ap.refinement;
    std::snprintf(note, sizeof note,
                  "%d OT Newton its, max rel. cell error %.1e; area distortion %.4f / p95 %.3f (centroid map %.3f, "
                  "conformal %.3f); refinement %d Newton steps, %.1f s, %s",
                  ap.omt.iterations, ap.omt.max_relative_error, q.area_distortion_log_abs.mean,
                  q.area_distortion_log_abs.p95, r.before.mean, qc.area_distortion_log_abs.mean, r.iterations, r.seconds,
                  r.converged ? "converged" : "not converged");
    row(c.name, c.mesh.num_vertices(), "brenier area-preserving", secs, q, note);
  }
  for (const char* f : {"bear.off", "armadillo.off", "camel.off", "man.off", "dino.off", "bunny00.off"}) {
    mesh::TriMesh m = mesh::load_mesh(data + "/" + f).mesh;
    conformal::ConformalMap map;
    double secs = median_seconds([&] { map = conformal::map_to_sphere(m); });
    row(f, m.num_vertices(), "brenier sphere", secs, quality::measure(m, map.positions, quality::Target::kSphere),
        std::to_string(map.newton_iterations) + " Newton its, max|K-Kbar| " + sci(map.max_curvature_error));
  }
  return 0;
}

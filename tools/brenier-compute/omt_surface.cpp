// brenier-compute omt-surface MESH --sites FILE [--masses FILE] [--source-density FILE]
// [--subdivide N] [--geodesics heat|exact] [--tolerance T] [-o cells.csv] [--json]:
// Riemannian optimal transport on the surface (dissertation Alg. 4, omt/geodesic_omt.hpp).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <sstream>

#include "commands.hpp"
#include "common/error.hpp"
#include "jobs/requests.hpp"
#include "mesh/geometry.hpp"
#include "omt/geodesic_omt.hpp"
#include "register/correspondence.hpp"

namespace brenier::tools {
namespace {

struct OmtSurfaceOptions {
  MeshInputOptions input;
  std::string sites, masses, density, output, geodesics = "heat";
  omt::GeodesicOmtOptions solver;
  bool json = false;
};

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The sites of the file on the cleaned mesh: vertex numbers through the cleaning's
// renumbering, points by the nearest point of the surface, which must be within 1e-6 of the
// bounding box's diagonal.
std::vector<mesh::SurfacePoint> place_sites(const mesh::CleanMesh& cm, const std::string& path) {
  const std::vector<jobs::SiteEntry> entries = jobs::read_sites_file(path);
  const mesh::TriMesh& m = cm.mesh;
  std::vector<int> to(static_cast<size_t>(cm.input_vertices), -1);
  for (size_t i = 0; i < cm.vertex_origin.size(); ++i) to[static_cast<size_t>(cm.vertex_origin[i])] = static_cast<int>(i);
  std::vector<int> corner_face(static_cast<size_t>(m.num_vertices()), -1), corner(static_cast<size_t>(m.num_vertices()), 0);
  for (int f = m.num_faces() - 1; f >= 0; --f)
    for (int k = 0; k < 3; ++k) {
      corner_face[static_cast<size_t>(m.F(f, k))] = f;
      corner[static_cast<size_t>(m.F(f, k))] = k;
    }
  // Only the point sites are located (one AABB tree for all of them); near[i] is entry i's.
  std::vector<size_t> point_entries;
  for (size_t i = 0; i < entries.size(); ++i)
    if (entries[i].vertex < 0) point_entries.push_back(i);
  mesh::Vertices points(static_cast<Eigen::Index>(entries.size()), 3);
  mesh::Vertices query(static_cast<Eigen::Index>(point_entries.size()), 3);
  for (size_t i = 0; i < entries.size(); ++i)
    points.row(static_cast<Eigen::Index>(i)) << entries[i].point[0], entries[i].point[1], entries[i].point[2];
  for (size_t q = 0; q < point_entries.size(); ++q) query.row(static_cast<Eigen::Index>(q)) = points.row(static_cast<Eigen::Index>(point_entries[q]));
  std::vector<mesh::SurfacePoint> near(entries.size());
  if (!point_entries.empty()) {
    const std::vector<mesh::SurfacePoint> found = registration::locate(m.F, m.V, query, false);
    for (size_t q = 0; q < point_entries.size(); ++q) near[point_entries[q]] = found[q];
  }
  const double diagonal = (m.V.colwise().maxCoeff() - m.V.colwise().minCoeff()).norm();
  std::vector<mesh::SurfacePoint> out;
  for (size_t i = 0; i < entries.size(); ++i) {
    const jobs::SiteEntry& e = entries[i];
    const std::string where = path + ":" + std::to_string(e.line) + ": site " + std::to_string(i);
    if (e.vertex >= 0) {
      if (e.vertex >= cm.input_vertices || to[static_cast<size_t>(e.vertex)] < 0)
        invalid(where + " is vertex " + std::to_string(e.vertex) + ", which is not a vertex of the surface (" +
                std::to_string(cm.input_vertices) + " in the file, unreferenced and merged ones dropped)");
      const int v = to[static_cast<size_t>(e.vertex)];
      mesh::SurfacePoint p{corner_face[static_cast<size_t>(v)], Eigen::Vector3d::Zero()};
      p.bary[corner[static_cast<size_t>(v)]] = 1;
      out.push_back(p);
      continue;
    }
    const mesh::SurfacePoint& p = near[i];
    Eigen::Vector3d at = Eigen::Vector3d::Zero();
    for (int k = 0; k < 3; ++k) at += p.bary[k] * m.V.row(m.F(p.face, k)).transpose();
    const double off = (at - points.row(static_cast<Eigen::Index>(i)).transpose()).norm();
    if (off > 1e-6 * diagonal) {
      std::ostringstream s;
      s << where << " is " << off << " from the surface (" << off / diagonal
        << " of its bounding box's diagonal): sites must lie on the mesh";
      invalid(s.str());
    }
    out.push_back(p);
  }
  return out;
}

// Per-vertex values of a file in the input's numbering, carried onto the cleaned mesh.
Eigen::VectorXd per_vertex(const mesh::CleanMesh& cm, const std::string& path) {
  const std::vector<double> w = jobs::read_weights_file(path);
  if (static_cast<int64_t>(w.size()) != cm.input_vertices)
    invalid(path + ": " + std::to_string(w.size()) + " values for the mesh's " + std::to_string(cm.input_vertices) +
            " vertices");
  Eigen::VectorXd out(cm.mesh.num_vertices());
  for (int v = 0; v < cm.mesh.num_vertices(); ++v) out[v] = w[static_cast<size_t>(cm.vertex_origin[static_cast<size_t>(v)])];
  return out;
}

int run_omt_surface(OmtSurfaceOptions o) {
  const auto t0 = std::chrono::steady_clock::now();
  if (o.geodesics != "heat" && o.geodesics != "exact")
    invalid("--geodesics is '" + o.geodesics + "'; it must be heat or exact");
  o.solver.geodesics = o.geodesics == "exact" ? omt::GeodesicMethod::kExact : omt::GeodesicMethod::kHeat;
  const mesh::CleanMesh cm = o.input.load();
  mesh::require_valid(cm, o.input.path);
  const std::vector<mesh::SurfacePoint> sites = place_sites(cm, o.sites);
  Eigen::VectorXd masses, density;
  if (!o.masses.empty()) {
    const std::vector<double> w = jobs::read_weights_file(o.masses);
    masses = Eigen::Map<const Eigen::VectorXd>(w.data(), static_cast<Eigen::Index>(w.size()));
  }
  if (!o.density.empty()) density = per_vertex(cm, o.density);
  const double t_read = seconds_since(t0);
  const omt::GeodesicOmtResult r = omt::solve_geodesic_omt(cm.mesh, sites, masses, density, o.solver);

  const double mu = r.target.sum();
  if (!o.output.empty()) {
    std::string csv = "face,input_face,cell,share\n";
    const int per_input = 1 << (2 * r.subdivisions);
    for (int f = 0; f < r.mesh.num_faces(); ++f) {
      char row[96];
      std::snprintf(row, sizeof row, "%d,%lld,%d,%.9g\n", f,
                    static_cast<long long>(cm.face_origin[static_cast<size_t>(f / per_input)]),
                    r.face_cell[static_cast<size_t>(f)], r.face_share[f]);
      csv += row;
    }
    write_output(o.output, csv);
  }
  nlohmann::json j;
  j["mesh"] = o.input.path;
  j["vertices"] = cm.mesh.num_vertices();
  j["faces"] = cm.mesh.num_faces();
  j["subdivisions"] = r.subdivisions;
  j["resolved_on"] = {{"vertices", r.mesh.num_vertices()}, {"faces", r.mesh.num_faces()}};
  j["sites"] = sites.size();
  j["geodesics"] = o.geodesics;
  j["distance_rounds"] = r.distance_rounds;
  j["chordal_start"] = r.chordal_start;
  j["converged"] = r.converged;
  j["iterations"] = r.iterations;
  j["max_relative_error"] = r.max_relative_error;
  j["tolerance"] = o.solver.tolerance;
  j["source_mass"] = mu;
  j["transport_cost"] = r.transport_cost;     // sum_i int_{W_i} d_g(x, p_i)^2 dmu
  j["w2"] = std::sqrt(r.transport_cost / mu);  // both measures scaled to mass 1
  nlohmann::json cells = nlohmann::json::array();
  for (Eigen::Index i = 0; i < r.mass.size(); ++i)
    cells.push_back({{"site", i}, {"mass", r.mass[i]}, {"target", r.target[i]}, {"height", r.h[i]}, {"cost", r.cost[i]}});
  j["cells"] = cells;
  j["seconds"] = {{"read", t_read}, {"geodesics", r.seconds_geodesics}, {"transport", r.seconds_transport},
                  {"total", seconds_since(t0)}};
  if (!o.output.empty()) j["output"] = o.output;
  if (o.json) {
    std::cout << j.dump(2) << std::endl;
  } else {
    std::printf("%s: %zu sites on %d faces (%d subdivisions), %s geodesics: %s in %d iterations, max relative cell-mass "
                "error %.3g, W2 %.6g, %.3f s\n",
                o.input.path.c_str(), sites.size(), r.mesh.num_faces(), r.subdivisions, o.geodesics.c_str(),
                r.converged ? "converged" : "NOT converged", r.iterations, r.max_relative_error, j["w2"].get<double>(),
                j["seconds"]["total"].get<double>());
    if (!o.output.empty()) std::printf("wrote %s\n", o.output.c_str());
  }
  return r.converged ? kExitOk : kExitNotConverged;
}

}  // namespace

void add_omt_surface(CLI::App& app, Action& action) {
  auto o = std::make_shared<OmtSurfaceOptions>();
  CLI::App* cmd = app.add_subcommand(
      "omt-surface", "optimal transport on the surface with the squared geodesic cost (Riemannian OMT, Alg. 4)");
  o->input.add_to(cmd);
  cmd->add_option("--sites", o->sites, "the sites: one per line, a vertex number or x y z on the surface")->required();
  cmd->add_option("--masses", o->masses, "the sites' masses (positive, any scale; default equal)");
  cmd->add_option("--source-density", o->density, "a positive density per vertex of the mesh (default 1: the area)");
  cmd->add_option("--subdivide", o->solver.subdivisions,
                  "midpoint subdivisions of the mesh (default: enough for 64 faces per cell, at most 4)");
  cmd->add_option("--geodesics", o->geodesics, "heat (one factorization, default) or exact (CGAL, small meshes)");
  cmd->add_option("--tolerance", o->solver.tolerance, "max relative cell-mass error (default 1e-6)");
  cmd->add_option("--max-iterations", o->solver.max_iterations, "Newton iterations (default 100)");
  cmd->add_option("-o,--output", o->output, "write per face of the subdivided mesh: its input face, its cell and share");
  cmd->add_flag("--json", o->json, "print one JSON object");
  cmd->callback([o, &action] { action = [o] { return run_omt_surface(*o); }; });
}

}  // namespace brenier::tools

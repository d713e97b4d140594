// brenier-compute inspect MESH [--json]: what a mesh is and what is wrong with it.
#include <cstdio>
#include <iostream>
#include <memory>

#include "commands.hpp"
#include "request_flags.hpp"
#include "common/error.hpp"
#include "mesh/geometry.hpp"

namespace brenier::tools {
namespace {

struct InspectOptions {
  MeshInputOptions input;
  bool json = false;
  std::optional<mesh::Domain> domain;  // --domain given: check that the mesh fits it
  mesh::Domain domain_value = mesh::Domain::kDisk;
  bool cut = false;
  int hole_vertex = -1;
};

int run_inspect(const InspectOptions& o) {
  mesh::CleanMesh cm = o.input.load();
  nlohmann::json j;
  j["file"] = o.input.path;
  j["input"] = {{"vertices", cm.input_vertices}, {"faces", cm.input_faces}};
  const mesh::Problem* err = cm.report.first_error();

  std::optional<mesh::Topology> topo;
  std::string domain_error;
  int cut_vertex = -1;
  if (cm.mesh.F.rows() > 0 && cm.mesh.V.rows() > 0 && !cm.report.has_errors()) {
    if (o.cut) {
      auto cut = mesh::cut_hole(cm.mesh, o.hole_vertex >= 0 ? std::optional<int>(o.hole_vertex)
                                                            : std::nullopt);
      cut_vertex = cm.vertex_origin[cut.vertex];
      cm.mesh = std::move(cut.mesh);
    }
    topo = mesh::compute_topology(cm.mesh);
    if (o.domain) {
      domain_error = mesh::domain_mismatch(*topo, *o.domain);
    }
  } else if (cm.mesh.F.rows() > 0 && cm.mesh.V.rows() > 0 &&
             !cm.report.problems.empty() && cm.mesh.V.allFinite()) {
    // Invalid but indexable (e.g. non-manifold): the topology still says what it is.
    topo = mesh::compute_topology(cm.mesh);
  }

  double area = topo ? mesh::total_area(cm.mesh) : 0.0;
  bool valid = err == nullptr && domain_error.empty();
  if (o.json) {
    if (topo) j.update(topology_json(*topo));
    if (topo) j["area"] = area;
    if (cut_vertex >= 0) j["cut_hole_vertex"] = cut_vertex;
    if (o.domain) j["fits_domain"] = domain_error.empty();
    j["valid"] = valid;
    j["problems"] = problems_json(cm.report);
    std::cout << j.dump(2) << std::endl;
  } else {
    std::cout << "file:           " << o.input.path << "\n";
    if (topo) {
      const auto& t = *topo;
      std::cout << "vertices:       " << t.vertices << "\n"
                << "faces:          " << t.faces << "\n"
                << "edges:          " << t.edges << "\n"
                << "components:     " << t.components << "\n"
                << "boundary_loops: " << t.boundary_loops << "\n"
                << "euler:          " << t.euler << "\n"
                << "genus:          " << t.genus << "\n"
                << "manifold:       " << (t.manifold ? "yes" : "no") << "\n"
                << "class:          " << mesh::class_name(t.mesh_class) << "\n";
      char buf[64];
      std::snprintf(buf, sizeof buf, "%.10g", area);
      std::cout << "area:           " << buf << "\n";
      if (cut_vertex >= 0) std::cout << "cut hole at:    vertex " << cut_vertex << "\n";
    }
    for (const auto& p : cm.report.problems)
      std::cout << (p.severity == mesh::Problem::Severity::kError ? "error:   " : "warning: ")
                << p.code << ": " << name_options(p.message, OptionStyle::kFlag) << "\n";
    if (!domain_error.empty()) std::cout << "error:   domain: " << name_options(domain_error, OptionStyle::kFlag) << "\n";
    std::cout << "valid:          " << (valid ? "yes" : "no") << std::endl;
  }
  if (err) invalid(o.input.path + ": " + err->message);
  if (!domain_error.empty()) invalid(o.input.path + ": " + domain_error);
  return kExitOk;
}

}  // namespace

void add_inspect(CLI::App& app, Action& action) {
  auto o = std::make_shared<InspectOptions>();
  CLI::App* cmd = app.add_subcommand(
      "inspect", "report vertices, faces, components, boundary loops, Euler characteristic, "
                 "genus, class (disk/sphere/other), area and every problem found");
  o->input.add_to(cmd);
  cmd->add_flag("--json", o->json, "print one JSON object");
  CLI::Option* domain = options::add_domain(cmd, o->domain_value, "also check that the mesh fits this domain");
  options::add_cut_hole(cmd, o->cut, o->hole_vertex, "open a closed genus-0 mesh into a disk by removing one vertex's star");
  cmd->callback([o, domain, &action] {
    if (domain->count() > 0) o->domain = o->domain_value;
    action = [o] { return run_inspect(*o); };
  });
}

}  // namespace brenier::tools

#include "commands.hpp"

namespace brenier::tools {

nlohmann::json problems_json(const mesh::Report& report) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& p : report.problems)
    out.push_back({{"severity", p.severity == mesh::Problem::Severity::kError ? "error" : "warning"},
                   {"code", p.code},
                   {"message", p.message},
                   {"count", p.count}});
  return out;
}

nlohmann::json topology_json(const mesh::Topology& t) {
  return {{"vertices", t.vertices},
          {"edges", t.edges},
          {"faces", t.faces},
          {"components", t.components},
          {"boundary_loops", t.boundary_loops},
          {"euler", t.euler},
          {"genus", t.genus},
          {"manifold", t.manifold},
          {"class", mesh::class_name(t.mesh_class)}};
}

void MeshInputOptions::add_to(CLI::App* app) {
  app->add_option("mesh", path, "mesh file (OBJ, OFF, PLY, STL or a FreeSurfer surface)")
      ->required();
  app->add_option("--format", format, "input format when the extension does not tell it")
      ->check(CLI::IsMember({"obj", "off", "ply", "stl", "freesurfer"}));
  app->add_flag("--merge-duplicates", clean.merge_duplicates,
                "merge vertices with identical coordinates");
  app->add_flag("--keep-largest", clean.keep_largest_component,
                "keep the largest connected component instead of refusing several");
  app->add_flag("--fix-orientation", clean.fix_orientation,
                "flip faces to orient each component consistently");
}

mesh::CleanMesh MeshInputOptions::load() const {
  std::optional<mesh::Format> f;
  if (!format.empty()) f = mesh::parse_format(format);
  return mesh::load_mesh(path, clean, f);
}

}  // namespace brenier::tools

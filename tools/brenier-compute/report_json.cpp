#include "commands.hpp"

namespace brenier::tools {

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

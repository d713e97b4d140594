// brenier-compute render RESULT... -o fig.png|fig.svg: pictures of results (core/render).
// A RESULT is a map written by `map -o` (a disk map's OBJ with its vt, or a sphere map's mesh
// on the unit sphere; one row each, so a conformal map beside an area-preserving one is two
// files) or a distance matrix (.csv or .json, with --labels).
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>

#include "commands.hpp"
#include "common/error.hpp"
#include "distance/matrix.hpp"
#include "render/render.hpp"

namespace brenier::tools {
namespace {

struct RenderOptions {
  std::vector<std::string> results;
  std::string output, surface, labels, view = "auto";
  int width = 0, height = 0;
  bool json = false;
};

bool is_matrix_file(const std::string& path) {
  const std::string ext = std::filesystem::path(path).extension().string();
  return ext == ".csv" || ext == ".json";
}

mesh::TriMesh triangles(const mesh::PolygonSoup& s, const std::string& path) {
  mesh::TriMesh m;
  m.V.resize(static_cast<Eigen::Index>(s.positions.size()), 3);
  for (size_t i = 0; i < s.positions.size(); ++i) m.V.row(static_cast<Eigen::Index>(i)) = s.positions[i].transpose();
  m.F.resize(s.num_faces(), 3);
  for (int64_t f = 0; f < s.num_faces(); ++f) {
    if (s.face_offsets[f + 1] - s.face_offsets[f] != 3) invalid(path + ": face " + std::to_string(f) + " is not a triangle");
    for (int k = 0; k < 3; ++k) {
      const int64_t v = s.indices[static_cast<size_t>(s.face_offsets[f] + k)];
      if (v < 0 || v >= m.V.rows()) invalid(path + ": face " + std::to_string(f) + " has a vertex out of range");
      m.F(f, k) = static_cast<int>(v);
    }
  }
  return m;
}

// A map result as written by `map -o`: read as it is (no cleaning, which could merge or
// renumber vertices and so detach the image from its surface).
render::MapFigure read_map(const std::string& path, const std::string& surface_path) {
  render::MapFigure m;
  m.title = std::filesystem::path(path).filename().string();
  const std::string bytes = mesh::read_file_bytes(path);
  const mesh::Format format = mesh::detect_format(path, std::string_view(bytes).substr(0, 64));
  const mesh::TriMesh read = triangles(mesh::read_soup(bytes, format), path);
  if (read.num_faces() == 0) invalid(path + " has no faces");
  const std::optional<mesh::UV> uv =
      format == mesh::Format::kObj ? mesh::read_obj_uv(bytes, read.V.rows()) : std::nullopt;
  if (uv) {
    m.surface = read;
    m.image = mesh::Vertices::Zero(read.V.rows(), 3);
    m.image.leftCols(2) = *uv;
    return m;
  }
  const Eigen::VectorXd r = read.V.rowwise().norm();
  if ((r.array() - 1).abs().maxCoeff() > 1e-6)
    invalid(path + " is no map: it has no disk coordinates (OBJ vt) and its vertices are not on the unit sphere");
  m.disk = false;
  m.image = read.V;
  m.surface.F = read.F;
  if (!surface_path.empty()) {
    const mesh::TriMesh s = triangles(mesh::read_soup_file(surface_path), surface_path);
    // The sizes first: Eigen compares matrices of equal sizes only.
    if (s.V.rows() != read.V.rows() || s.F.rows() != read.F.rows() || s.F != read.F)
      invalid(surface_path + " is not the surface of " + path + " (other vertices or faces)");
    m.surface.V = s.V;
  } else {
    m.surface.V = read.V;  // no surface given: the 3-D panel shows the sphere itself
  }
  return m;
}

int run_render(const RenderOptions& o) {
  const render::Format format = render::format_of(o.output);
  const render::View view = render::parse_view(o.view);
  size_t matrices = 0;
  for (const std::string& r : o.results) matrices += is_matrix_file(r);
  if (matrices > 0 && o.results.size() > 1) invalid("render one matrix at a time, or map results only");
  render::Picture p;
  if (matrices == 1) {
    render::MatrixFigure m;
    distance::read_matrix(o.results[0], m.names, m.d);
    if (!o.labels.empty()) m.labels = read_labels(o.labels, m.names);
    p = render::matrix_picture(m, format, o.width ? o.width : render::kMatrixPictureWidth,
                               o.height ? o.height : render::kMatrixPictureHeight);
  } else {
    if (!o.labels.empty()) invalid("--labels is for a matrix");
    std::vector<render::MapFigure> maps;
    for (const std::string& r : o.results) maps.push_back(read_map(r, o.surface));
    const int rows = static_cast<int>(maps.size());
    p = render::map_picture(maps, format, o.width ? o.width : render::kMapPictureWidth,
                            o.height ? o.height : render::kMapRowHeight * rows, view);
  }
  write_output(o.output, p.bytes);
  if (o.json) {
    nlohmann::json j = p.layout.json();
    j["output"] = o.output;
    j["bytes"] = p.bytes.size();
    std::cout << j.dump(2) << std::endl;
  } else {
    std::printf("wrote %s (%dx%d)\n", o.output.c_str(), p.layout.width, p.layout.height);
  }
  return kExitOk;
}

}  // namespace

void write_output(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out.flush()) invalid("cannot write '" + path + "'");
}

void add_render(CLI::App& app, Action& action) {
  auto o = std::make_shared<RenderOptions>();
  CLI::App* cmd = app.add_subcommand("render", "pictures of map results (one row each) or of a distance matrix");
  cmd->add_option("results", o->results, "maps written by map -o (disk OBJ with vt, or sphere mesh), or one matrix")
      ->required();
  cmd->add_option("-o,--output", o->output, "picture file (.png or .svg)")->required();
  cmd->add_option("--surface", o->surface, "a sphere map's input mesh, for its 3-D view");
  cmd->add_option("--labels", o->labels, "matrix: CSV of name,label (groups the heat map, colours the MDS plot)");
  cmd->add_option("--view", o->view, "the 3-D view: auto, or AZIMUTH,ELEVATION in degrees");
  cmd->add_option("--width", o->width, "pixels (default 1600 for maps, 1400 for a matrix)");
  cmd->add_option("--height", o->height, "pixels (default 330 per map, 760 for a matrix)");
  cmd->add_flag("--json", o->json, "print the picture's layout (panels, colour bars and their ranges) as JSON");
  cmd->callback([o, &action] { action = [o] { return run_render(*o); }; });
}

}  // namespace brenier::tools

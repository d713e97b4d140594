// brenier-compute map MESH --domain disk|sphere --method conformal [...]: a map of a surface
// onto the unit disk or sphere, written as a mesh and reported as JSON (DESIGN.md contract).
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <cstdio>
#include <iostream>
#include <memory>

#include "commands.hpp"
#include "common/error.hpp"
#include "jobs/jobs.hpp"
#include "render/render.hpp"
#include "render/report.hpp"
#include "request_flags.hpp"

namespace brenier::tools {
namespace {

struct MapOptions {
  MeshInputOptions input;
  options::MapFlags flags;
  std::string output, picture, report_html;
  bool json = false;
};

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The map's picture (render::map_picture; an area-preserving map beside its conformal start).
void write_picture(const jobs::MapOutcome& m, const std::string& input, const std::string& path) {
  const std::vector<render::MapFigure> rows = render::map_figures(m, std::filesystem::path(input).filename().string());
  write_output(path, render::default_map_picture(rows, render::format_of(path)).bytes);
}

int run_map(const MapOptions& o) {
  auto t0 = std::chrono::steady_clock::now();
  const jobs::MapRequest r = o.flags.resolve();
  mesh::CleanMesh cm = o.input.load();
  mesh::require_valid(cm, o.input.path);
  const double t_read = seconds_since(t0);

  if (!o.picture.empty()) render::format_of(o.picture);  // a bad name fails before the work
  jobs::MapOutcome m = jobs::run_map(cm, o.input.path, r);
  if (!o.output.empty()) jobs::write_map_file(m, o.output);
  if (!o.picture.empty()) write_picture(m, o.input.path, o.picture);
  if (!o.report_html.empty())
    write_output(o.report_html, render::map_report_html(m, std::filesystem::path(o.input.path).filename().string()));

  nlohmann::json& j = m.report;
  j["seconds"]["read"] = t_read;
  j["seconds"]["total"] = seconds_since(t0);
  if (!o.output.empty()) j["output"] = o.output;
  if (!o.picture.empty()) j["picture"] = o.picture;
  if (!o.report_html.empty()) j["report_html"] = o.report_html;
  if (o.json) {
    std::cout << j.dump(2) << std::endl;
    return kExitOk;
  }
  const nlohmann::json& q = j["quality"];
  std::printf("%s -> %s (%s): %d vertices, %d Newton iterations, max |K-Kbar| %.2e, %.3f s\n", o.input.path.c_str(),
              jobs::domain_name(r.domain), jobs::map_method_name(r.method), j["mesh"]["vertices"].get<int>(),
              j["conformal"]["newton_iterations"].get<int>(), j["conformal"]["max_curvature_error"].get<double>(),
              j["seconds"]["total"].get<double>());
  if (j.contains("omt"))
    std::printf("optimal transport: %d Newton iterations, max relative cell-mass error %.2e\n",
                j["omt"]["newton_iterations"].get<int>(), j["omt"]["max_relative_area_error"].get<double>());
  std::printf("flipped faces %d; angle distortion mean %.3f deg, p95 %.3f, max %.3f; "
              "|log area ratio| mean %.3f, max %.3f\n",
              q["flipped_faces"].get<int>(), q["angle_distortion_deg"]["mean"].get<double>(),
              q["angle_distortion_deg"]["p95"].get<double>(), q["angle_distortion_deg"]["max"].get<double>(),
              q["area_distortion_log"]["mean_abs"].get<double>(), q["area_distortion_log"]["max_abs"].get<double>());
  if (!o.output.empty()) std::printf("wrote %s\n", o.output.c_str());
  if (!o.picture.empty()) std::printf("wrote %s\n", o.picture.c_str());
  if (!o.report_html.empty()) std::printf("wrote %s\n", o.report_html.c_str());
  return kExitOk;
}

}  // namespace

void add_map(CLI::App& app, Action& action) {
  auto o = std::make_shared<MapOptions>();
  CLI::App* cmd = app.add_subcommand("map", "map a surface onto the unit disk or sphere");
  o->input.add_to(cmd);
  o->flags.add_to(cmd);
  cmd->add_option("-o,--output", o->output, "write the mapped mesh (.obj with vt, .ply, .off)");
  cmd->add_option("--picture", o->picture, "draw the map (.png or .svg; see render)");
  cmd->add_option("--report-html", o->report_html, "write a self-contained HTML report (pictures, figures, 3-D view)");
  cmd->add_flag("--json", o->json, "print one JSON object");
  cmd->callback([o, &action] { action = [o] { return run_map(*o); }; });
}

}  // namespace brenier::tools

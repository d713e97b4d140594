// brenier-compute register SOURCE TARGET [--landmarks S T] [--domain] [--method] [--cut-hole]
// -o corr.csv [--morph out.obj] [--json]: surface registration (Alg. 7), the source's vertices
// placed on the target (jobs::run_register).
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>

#include "commands.hpp"
#include "common/error.hpp"
#include "common/parallel.hpp"
#include "jobs/jobs.hpp"
#include "request_flags.hpp"

namespace brenier::tools {
namespace {

struct RegisterOptions {
  std::string source, target;
  mesh::CleanOptions clean;
  options::RegisterFlags flags;
  std::string output, morph;
  bool json = false;
};

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

int run_register(const RegisterOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  const jobs::RegisterRequest r = o.flags.resolve();
  if (!o.morph.empty() && !mesh::parse_format(std::filesystem::path(o.morph).extension().string()))
    invalid("cannot tell the output format of '" + o.morph + "' from its extension");  // before the work
  const mesh::CleanMesh a = mesh::load_mesh(o.source, o.clean), b = mesh::load_mesh(o.target, o.clean);
  const double t_read = seconds_since(t0);
  jobs::RegisterOutcome out = jobs::run_register(a, b, o.source, o.target, r, hardware_threads());
  if (!o.output.empty()) write_output(o.output, jobs::correspondence_csv(out));
  if (!o.morph.empty()) mesh::write_mesh_file(o.morph, out.morph);

  nlohmann::json& j = out.report;
  j["seconds"]["read"] = t_read;
  j["seconds"]["total"] = seconds_since(t0);
  if (!o.output.empty()) j["output"] = o.output;
  if (!o.morph.empty()) j["morph"] = o.morph;
  if (o.json) {
    std::cout << j.dump(2) << std::endl;
    return kExitOk;
  }
  std::printf("%s -> %s (%s, %s maps, %zu landmarks): %zu vertices placed, %d domain folds, %d flipped morph faces, "
              "%d matching steps, %.3f s\n",
              o.source.c_str(), o.target.c_str(), jobs::domain_name(r.domain), jobs::map_method_name(r.method),
              r.source_landmarks.size(), out.rows.size(), j["domain_folded_faces"].get<int>(),
              j["morph_flipped_faces"].get<int>(), j["match"]["steps"].get<int>(), j["seconds"]["total"].get<double>());
  if (!o.output.empty()) std::printf("wrote %s\n", o.output.c_str());
  if (!o.morph.empty()) std::printf("wrote %s\n", o.morph.c_str());
  return kExitOk;
}

}  // namespace

void add_register(CLI::App& app, Action& action) {
  auto o = std::make_shared<RegisterOptions>();
  CLI::App* cmd = app.add_subcommand("register", "register a surface onto another (Alg. 7)");
  cmd->add_option("source", o->source, "the source mesh")->required();
  cmd->add_option("target", o->target, "the target mesh")->required();
  cmd->add_flag("--merge-duplicates", o->clean.merge_duplicates, "merge vertices with identical coordinates");
  o->flags.add_to(cmd);
  cmd->add_option("-o,--output", o->output,
                  "write the correspondence CSV: per source vertex the target face, its vertices, barycentric "
                  "coordinates and the point");
  cmd->add_option("--morph", o->morph, "write the source mesh placed on the target (.obj, .ply, .off)");
  cmd->add_flag("--json", o->json, "print one JSON object");
  cmd->callback([o, &action] { action = [o] { return run_register(*o); }; });
}

}  // namespace brenier::tools

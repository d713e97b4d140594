// brenier-compute: the engine on local files. Each subcommand registers itself on the app
// and returns its exit status through run(); errors are thrown as brenier::Error and turned
// into one stderr line and an exit code in one place (main.cpp).
#pragma once

#include <CLI/CLI.hpp>
#include <functional>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "jobs/jobs.hpp"
#include "mesh/io.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"

namespace brenier::tools {

/// Exit codes of every tool: 0 success, 2 bad input (the input's fault), 3 a solver that did
/// not converge, 1 anything else (a bug of ours or the machine's).
inline constexpr int kExitOk = 0;
inline constexpr int kExitFailure = 1;
inline constexpr int kExitBadInput = 2;
inline constexpr int kExitNotConverged = 3;

/// What a subcommand runs once CLI11 has parsed its options; returns the exit code.
using Action = std::function<int()>;

/// Options shared by every command that reads a mesh.
struct MeshInputOptions {
  std::string path;
  std::string format;  // empty: detect
  mesh::CleanOptions clean;
  void add_to(CLI::App* app);
  /// Reads and cleans; throws the read errors; the report tells the rest.
  mesh::CleanMesh load() const;
};

void add_inspect(CLI::App& app, Action& action);
void add_map(CLI::App& app, Action& action);
void add_omt_bench(CLI::App& app, Action& action);
/// distance, matrix, merge, mds and knn.
void add_distance(CLI::App& app, Action& action);
/// render: pictures of map and matrix results.
void add_render(CLI::App& app, Action& action);
/// register: surface registration (Alg. 7).
void add_register(CLI::App& app, Action& action);
/// omt-surface: Riemannian optimal transport on the surface (Alg. 4).
void add_omt_surface(CLI::App& app, Action& action);

/// Writes a picture or a report whole (Error(kInvalidArgument) naming the file otherwise).
void write_output(const std::string& path, const std::string& bytes);

/// The labels of `names` from a CSV of "name,label" lines (a first line "name,label" is a
/// header). Throws kNotFound for an unreadable file, kInvalidArgument for a bad line or a
/// name without a label.
std::vector<std::string> read_labels(const std::string& path, const std::vector<std::string>& names);

using jobs::problems_json;
using jobs::topology_json;

}  // namespace brenier::tools

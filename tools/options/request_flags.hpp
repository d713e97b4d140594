// The command-line flags of the job requests (core/jobs/requests.hpp), declared once and
// shared by brenier-compute (the engine on files) and brenier (the thin client of brenierd),
// so that a flag means the same, with the same checks, in both.
#pragma once

#include <CLI/CLI.hpp>
#include <string>

#include "jobs/requests.hpp"

namespace brenier::options {

/// A number above 0, or (non_negative_number) at least 0. CLI11's PositiveNumber and
/// NonNegativeNumber refuse with their range printed in full ("Value 0 not in range 0.000000 to
/// 1797693134862315708...", the lower end being the least positive double); these say what is wrong.
CLI::Validator positive_number();
CLI::Validator non_negative_number();

/// --domain disk|sphere, by name.
CLI::Option* add_domain(CLI::App* cmd, jobs::Domain& domain, const std::string& help);
/// --cut-hole and --hole-vertex V.
void add_cut_hole(CLI::App* cmd, bool& cut_hole, int& hole_vertex, const std::string& help);

/// map: --domain --method --markers --cut-hole --hole-vertex --tolerance --max-iterations
/// --weights FILE --t --allow-flips.
struct MapFlags {
  jobs::MapRequest request;
  std::string weights_file;
  void add_to(CLI::App* cmd);
  /// The request with the weights file read, validated.
  jobs::MapRequest resolve() const;
};

/// distance and matrix: --method --domain --cut-hole --tolerance --cost-tolerance
/// --refine-rotation --raw --rings --angles.
struct ShapeFlags {
  jobs::ShapeRequest request;
  void add_to(CLI::App* cmd);
};

/// distance: --center-a --boundary-a --center-b --boundary-b with the shape flags.
struct DistanceFlags {
  ShapeFlags shape;
  jobs::DiskMarkers a, b;
  void add_to(CLI::App* cmd);
  jobs::DistanceRequest resolve() const;
};

/// matrix: --markers FILE (a markers file, requests.hpp) with the shape flags.
struct MatrixFlags {
  ShapeFlags shape;
  std::string markers_file;
  void add_to(CLI::App* cmd);
  /// The request for these meshes (as given on the command line), markers looked up in
  /// the markers file, validated.
  jobs::MatrixRequest resolve(const std::vector<std::string>& meshes) const;
};

/// register: --domain --method --cut-hole --landmarks S T --tolerance --max-iterations.
struct RegisterFlags {
  jobs::RegisterRequest request;
  std::vector<std::string> landmark_files;  // the source's and the target's
  void add_to(CLI::App* cmd);
  /// The request with the landmark files read, validated.
  jobs::RegisterRequest resolve() const;
};

}  // namespace brenier::options

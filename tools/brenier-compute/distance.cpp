// brenier-compute distance | matrix | merge | mds | knn: shape distances between surfaces,
// distance matrices over datasets (in tiles for job arrays) and their analysis (sec. 4.4).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>

#include "commands.hpp"
#include "render/report.hpp"
#include "common/error.hpp"
#include "common/format.hpp"
#include "common/parallel.hpp"
#include "distance/analysis.hpp"
#include "distance/matrix.hpp"
#include "render/report.hpp"
#include "jobs/matrix_work.hpp"
#include "mesh/geometry.hpp"
#include "request_flags.hpp"

namespace brenier::tools {
namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

/// The reading options of every distance command.
struct ReadFlags {
  mesh::CleanOptions clean;
  void add_to(CLI::App* cmd) {
    cmd->add_flag("--merge-duplicates", clean.merge_duplicates, "merge vertices with identical coordinates");
    cmd->add_flag("--keep-largest", clean.keep_largest_component, "keep the largest connected component");
    cmd->add_flag("--fix-orientation", clean.fix_orientation, "orient each component consistently");
  }
  // Reads, checks and (with cut_hole) opens one surface; markers are input vertex numbers.
  distance::ShapeInput load(const std::string& path, const jobs::ShapeRequest& request,
                            jobs::DiskMarkers markers) const {
    const mesh::CleanMesh cm = mesh::load_mesh(path, clean);
    return jobs::shape_input(cm, std::filesystem::path(path).stem().string(), path, request, markers);
  }
};

// Names from file stems; the paths as given when two stems collide.
void unique_names(std::vector<distance::ShapeInput>& shapes, const std::vector<std::string>& paths) {
  std::map<std::string, int> count;
  for (const auto& s : shapes) ++count[s.name];
  for (size_t i = 0; i < shapes.size(); ++i)
    if (count[shapes[i].name] > 1) shapes[i].name = paths[i];
  count.clear();
  for (const auto& s : shapes)
    if (++count[s.name] > 1) invalid("the file " + s.name + " is given twice");
}

// ---- distance ----------------------------------------------------------------------------

struct DistanceOptions {
  options::DistanceFlags flags;
  ReadFlags read;
  std::string a, b, report_html;
  bool both = false, json = false;
};

int run_distance(const DistanceOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  const jobs::DistanceRequest request = o.flags.resolve();
  std::vector<distance::ShapeInput> in = {o.read.load(o.a, request.shape, request.a),
                                          o.read.load(o.b, request.shape, request.b)};
  if (in[0].name == in[1].name) in[1].name += " (b)";
  jobs::DistanceOutcome d = jobs::run_distance(in[0], in[1], request.shape, hardware_threads());
  const distance::PairResult& r = d.result;
  nlohmann::json& j = d.report;
  j["a"] = o.a;
  j["b"] = o.b;
  j["seconds"]["total"] = seconds_since(t0);
  if (!o.report_html.empty())
    write_output(o.report_html, render::figures_report_html("brenier: distance of " + d.a.name + " and " + d.b.name, j));
  if (o.json) {
    std::cout << j.dump(2) << std::endl;
  } else {
    std::printf("%s %s %s: %.10g\n", distance::method_name(request.shape.method), d.a.name.c_str(), d.b.name.c_str(),
                r.distance);
    if (o.both && request.shape.method == distance::Method::kWasserstein) {
      auto value = [](double x) {
        char text[32];
        std::snprintf(text, sizeof text, "%.10g", x);
        return std::isfinite(x) ? std::string(text) : std::string("not solved");
      };
      std::printf("forward (source %s) %s, backward (source %s) %s\n", d.a.name.c_str(), value(r.forward).c_str(),
                  d.b.name.c_str(), value(r.backward).c_str());
    }
    std::printf("normalization: %s; rotation %.6f rad; %.3f s\n", r.normalization.c_str(), r.rotation,
                seconds_since(t0));
  }
  if (!r.converged) fail(ErrorCode::kNotConverged, jobs::not_converged_message(r));
  return kExitOk;
}

// ---- matrix ------------------------------------------------------------------------------

struct MatrixCommand {
  options::MatrixFlags flags;
  ReadFlags read;
  std::vector<std::string> files;
  std::string output, tile, cache, work, report_html;
  int jobs = 0;
  bool progress = false, json = false;
};

// The shapes and the request of a matrix: from the files and flags, or from a matrix work
// file written by brenierd (--work: a Slurm array task computing one of a job's tiles).
struct MatrixInputs {
  jobs::MatrixRequest request;
  std::vector<distance::ShapeInput> shapes;
  std::string cache;
};

MatrixInputs matrix_inputs(const MatrixCommand& o, int threads) {
  MatrixInputs m;
  if (!o.work.empty()) {
    if (!o.files.empty()) invalid("give the meshes or --work, not both");
    const jobs::MatrixWork w = jobs::read_matrix_work(o.work);
    if (!o.tile.empty() && distance::parse_tile(o.tile).count != w.tiles)
      invalid("--tile " + o.tile + " does not split the matrix as the work file does (" + std::to_string(w.tiles) +
              " tiles)");
    m.request = w.request;
    m.shapes = jobs::matrix_inputs(w, threads);
    m.cache = o.cache.empty() ? w.cache : o.cache;
    return m;
  }
  if (o.files.size() < 2) invalid("a distance matrix needs at least two meshes (or --work FILE)");
  m.request = o.flags.resolve(o.files);
  m.shapes.resize(o.files.size());
  parallel_for(static_cast<int>(o.files.size()), threads, [&](int k) {
    m.shapes[k] = o.read.load(o.files[k], m.request.shape,
                              m.request.markers.empty() ? jobs::DiskMarkers{} : m.request.markers[k]);
  });
  unique_names(m.shapes, o.files);
  m.cache = o.cache;
  return m;
}

// A tile of an array with a cache: the task first prepares its share of the shapes (I, I+K,
// I+2K, ...), so that the array's tasks prepare each shape about once between them instead
// of every task preparing every shape its pairs need at the same moment.
void prepare_share(const std::vector<distance::ShapeInput>& shapes, const distance::MatrixOptions& mo) {
  std::error_code ec;
  std::filesystem::create_directories(mo.cache_dir, ec);
  if (ec) invalid("cannot create the cache directory " + mo.cache_dir + ": " + ec.message());
  std::vector<int> mine;
  for (int i = mo.tile.index; i < static_cast<int>(shapes.size()); i += mo.tile.count) mine.push_back(i);
  parallel_for(static_cast<int>(mine.size()), mo.jobs,
               [&](int k) { distance::cached_shape(shapes[mine[k]], mo.cache_dir, mo.solver_progress); });
}

int run_matrix(const MatrixCommand& o) {
  const auto t0 = std::chrono::steady_clock::now();
  // Before hours of work, not after: the output's folder must exist.
  const std::filesystem::path folder = std::filesystem::path(o.output).parent_path();
  if (!folder.empty() && !std::filesystem::is_directory(folder))
    invalid("cannot write " + o.output + ": the folder " + folder.string() + " does not exist");
  distance::MatrixOptions mo;
  mo.jobs = o.jobs > 0 ? o.jobs : hardware_threads();
  const MatrixInputs in = matrix_inputs(o, mo.jobs);
  const std::vector<distance::ShapeInput>& shapes = in.shapes;
  mo.method = in.request.shape.method;
  mo.wasserstein = jobs::wasserstein_options(in.request.shape);
  mo.cache_dir = in.cache;
  if (!o.tile.empty()) mo.tile = distance::parse_tile(o.tile);
  if (!o.tile.empty() && !mo.cache_dir.empty()) prepare_share(shapes, mo);
  if (o.progress)
    mo.progress = [](const std::string& stage, int done, int total) {
      if (done == total || done % std::max(1, total / 20) == 0)
        std::fprintf(stderr, "matrix: %s %d/%d\n", stage.c_str(), done, total);
    };
  const distance::MatrixTile tile = distance::compute_tile(shapes, mo);
  std::vector<std::string> failed;
  // Sphere pairs whose transport needed a lower density cap than the shapes' (the retry of
  // distance::transport_cost_sphere): the caps per direction and the W2 they add to the
  // shapes' own bounds.
  nlohmann::json lowered = nlohmann::json::array();
  for (const distance::PairEntry& e : tile.pairs) {
    const std::string pair = "(" + tile.names[e.i] + ", " + tile.names[e.j] + ")";
    if (!e.result.converged) failed.push_back(pair);
    const std::array<double, 2>& cap = e.result.lowered_cap;
    if (cap[0] > 0 || cap[1] > 0)
      lowered.push_back({{"pair", pair}, {"caps", cap}, {"w2_shift", std::ranges::max(e.result.lowered_shift)}});
  }
  if (!o.tile.empty()) {
    // Whole or absent: whoever watches for tile files (brenierd, a merge) never reads half of one.
    const std::string tmp = o.output + ".tmp." + std::to_string(::getpid());
    distance::write_tile(tile, tmp);
    std::filesystem::rename(tmp, o.output);
  } else {
    distance::write_matrix(o.output, tile.names, distance::assemble({tile}), tile.method);
  }
  const nlohmann::json summary{{"output", o.output},
                               {"method", tile.method},
                               {"shapes", tile.names.size()},
                               {"pairs", tile.pairs.size()},
                               {"tile", {{"index", tile.tile.index}, {"count", tile.tile.count}}},
                               {"not_converged", failed},
                               {"lowered_density_caps", lowered},
                               {"seconds", seconds_since(t0)}};
  if (!o.report_html.empty())
    write_output(o.report_html, render::matrix_report_html({distance::assemble({tile}), tile.names, {}}, summary));
  if (o.json)
    std::cout << summary.dump(2) << std::endl;
  else
    std::printf("wrote %s: %zu pairs of %zu shapes (%s), %.2f s\n", o.output.c_str(), tile.pairs.size(),
                tile.names.size(), tile.method.c_str(), seconds_since(t0));
  if (!failed.empty())
    fail(ErrorCode::kNotConverged, std::to_string(failed.size()) + " pairs did not converge (written as nan): " +
                                       failed.front() + (failed.size() > 1 ? " ..." : ""));
  return kExitOk;
}

// ---- merge, mds, knn ---------------------------------------------------------------------

int run_merge(const std::vector<std::string>& files, const std::string& output) {
  std::vector<distance::MatrixTile> tiles;
  for (const std::string& f : files) tiles.push_back(distance::read_tile(f));
  const Eigen::MatrixXd d = distance::assemble(tiles);
  distance::write_matrix(output, tiles.front().names, d, tiles.front().method);
  int missing = 0;
  for (Eigen::Index i = 0; i < d.size(); ++i) missing += !std::isfinite(d.data()[i]);
  std::printf("wrote %s: %zu shapes from %zu tiles\n", output.c_str(), tiles.front().names.size(), tiles.size());
  if (missing > 0)
    fail(ErrorCode::kNotConverged, std::to_string(missing / 2) + " pairs did not converge (written as nan)");
  return kExitOk;
}

int run_mds(const std::string& input, const std::string& output, int dims, bool json) {
  std::vector<std::string> names;
  Eigen::MatrixXd d;
  distance::read_matrix(input, names, d);
  const distance::Embedding e = distance::classical_mds(d, dims);
  std::string csv = "name";
  for (int c = 0; c < dims; ++c) csv += ",x" + std::to_string(c + 1);
  csv += "\n";
  for (size_t i = 0; i < names.size(); ++i) {
    csv += names[i];
    for (int c = 0; c < dims; ++c) {
      csv += ',';
      append_double(csv, e.coordinates(static_cast<Eigen::Index>(i), c));
    }
    csv += "\n";
  }
  std::ofstream os(output, std::ios::trunc);
  if (!os || !(os << csv) || !os.flush()) invalid("cannot write " + output);
  const std::vector<double> top(e.eigenvalues.data(), e.eigenvalues.data() + std::min<Eigen::Index>(dims, e.eigenvalues.size()));
  if (json)
    std::cout << nlohmann::json{{"output", output}, {"dims", dims}, {"eigenvalues", top},
                                {"captured", e.captured}, {"negative", e.negative}}
                     .dump(2)
              << std::endl;
  else
    std::printf("wrote %s: %zu shapes in %d dimensions, %.1f %% of the positive spectrum\n", output.c_str(),
                names.size(), dims, 100 * e.captured);
  return kExitOk;
}

int run_knn(const std::string& input, const std::string& labels_path, int k, int folds, bool json) {
  std::vector<std::string> names;
  Eigen::MatrixXd d;
  distance::read_matrix(input, names, d);
  const std::vector<std::string> labels = read_labels(labels_path, names);
  const distance::KnnResult r = distance::knn_classify(d, labels, k, folds);
  if (json) {
    nlohmann::json shapes = nlohmann::json::array();
    for (size_t i = 0; i < names.size(); ++i)
      shapes.push_back({{"name", names[i]}, {"label", labels[i]}, {"predicted", r.predicted[i]}});
    std::cout << nlohmann::json{{"k", r.k},
                                {"validation", folds == 0 ? "leave-one-out" : std::to_string(folds) + "-fold"},
                                {"correct", r.correct},
                                {"total", r.total},
                                {"accuracy", r.accuracy},
                                {"shapes", shapes}}
                     .dump(2)
              << std::endl;
  } else {
    std::printf("%d-NN, %s: %d of %d correct, accuracy %.1f %%\n", k,
                folds == 0 ? "leave-one-out" : (std::to_string(folds) + "-fold").c_str(), r.correct, r.total,
                100 * r.accuracy);
    for (size_t i = 0; i < names.size(); ++i)
      if (r.predicted[i] != labels[i])
        std::printf("  %s: %s, predicted %s\n", names[i].c_str(), labels[i].c_str(), r.predicted[i].c_str());
  }
  return kExitOk;
}

}  // namespace

std::vector<std::string> read_labels(const std::string& path, const std::vector<std::string>& names) {
  std::ifstream in(path);
  if (!in) fail(ErrorCode::kNotFound, "cannot read the labels file " + path);
  std::map<std::string, std::string> label;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || (n == 1 && line == "name,label")) continue;
    const size_t comma = line.rfind(',');
    if (comma == std::string::npos || comma == 0 || comma + 1 == line.size())
      invalid(path + ":" + std::to_string(n) + ": expected name,label");
    label[line.substr(0, comma)] = line.substr(comma + 1);
  }
  std::vector<std::string> out;
  for (const std::string& s : names) {
    auto it = label.find(s);
    if (it == label.end()) invalid(path + " has no label for " + s);
    out.push_back(it->second);
  }
  return out;
}

void add_distance(CLI::App& app, Action& action) {
  {
    auto o = std::make_shared<DistanceOptions>();
    CLI::App* cmd = app.add_subcommand("distance", "shape distance between two surfaces");
    cmd->add_option("a", o->a, "first mesh")->required();
    cmd->add_option("b", o->b, "second mesh")->required();
    o->flags.add_to(cmd);
    o->read.add_to(cmd);
    cmd->add_flag("--both", o->both, "wasserstein: also print both directions");
    cmd->add_option("--report-html", o->report_html, "write a self-contained HTML report of the figures");
    cmd->add_flag("--json", o->json, "print one JSON object");
    cmd->callback([o, &action] { action = [o] { return run_distance(*o); }; });
  }
  {
    auto o = std::make_shared<MatrixCommand>();
    CLI::App* cmd = app.add_subcommand("matrix", "distance matrix over a dataset (or one tile of it)");
    cmd->add_option("files", o->files, "meshes (or --work)");
    cmd->add_option("-o,--output", o->output, "matrix file (.csv, .npy, .json); with --tile, the tile file")
        ->required();
    o->flags.add_to(cmd);
    o->read.add_to(cmd);
    cmd->add_option("--jobs", o->jobs, "worker threads (default: the number of cores)")->check(CLI::Range(1, 1024));
    cmd->add_option("--tile", o->tile, "compute only tile I of K (0-based, e.g. 3/16) and write it for merge");
    cmd->add_option("--cache", o->cache, "directory keeping each shape's maps by content hash");
    cmd->add_option("--work", o->work, "a matrix job's work file written by brenierd (shapes, options, cache)");
    cmd->add_flag("--progress", o->progress, "report progress on stderr");
    cmd->add_option("--report-html", o->report_html, "write a self-contained HTML report (picture, matrix, figures)")
        ->excludes("--tile");
    cmd->add_flag("--json", o->json, "print a JSON summary");
    cmd->callback([o, &action] { action = [o] { return run_matrix(*o); }; });
  }
  {
    auto files = std::make_shared<std::vector<std::string>>();
    auto output = std::make_shared<std::string>();
    CLI::App* cmd = app.add_subcommand("merge", "assemble matrix tiles into the matrix");
    cmd->add_option("tiles", *files, "tile files written by matrix --tile")->required();
    cmd->add_option("-o,--output", *output, "matrix file (.csv, .npy, .json)")->required();
    cmd->callback([files, output, &action] { action = [files, output] { return run_merge(*files, *output); }; });
  }
  {
    struct Mds {
      std::string input, output;
      int dims = 2;
      bool json = false;
    };
    auto o = std::make_shared<Mds>();
    CLI::App* cmd = app.add_subcommand("mds", "classical multidimensional scaling of a distance matrix");
    cmd->add_option("matrix", o->input, "matrix (.csv or .json)")->required();
    cmd->add_option("-o,--output", o->output, "coordinates CSV")->required();
    cmd->add_option("--dims", o->dims, "dimensions (default 2)")->check(CLI::Range(1, 100));
    cmd->add_flag("--json", o->json, "print a JSON summary");
    cmd->callback([o, &action] { action = [o] { return run_mds(o->input, o->output, o->dims, o->json); }; });
  }
  {
    struct Knn {
      std::string input, labels;
      int k = 1, folds = 0;
      bool json = false;
    };
    auto o = std::make_shared<Knn>();
    CLI::App* cmd = app.add_subcommand("knn", "k-nearest-neighbour classification from a distance matrix");
    cmd->add_option("matrix", o->input, "matrix (.csv or .json)")->required();
    cmd->add_option("--labels", o->labels, "CSV of name,label")->required();
    cmd->add_option("--k", o->k, "neighbours (default 1)")->check(options::positive_number());
    cmd->add_option("--folds", o->folds, "k-fold cross-validation (default: leave-one-out)")->check(CLI::Range(2, 1 << 20));
    cmd->add_flag("--json", o->json, "print one JSON object");
    cmd->callback([o, &action] { action = [o] { return run_knn(o->input, o->labels, o->k, o->folds, o->json); }; });
  }
}

}  // namespace brenier::tools

// Distance matrices over a dataset (dissertation sec. 4.4): every shape prepared once (and
// cached on disk by content hash), the pairs i < j computed on a pool of threads, in tiles
// that separate processes or machines can compute and a merge assembles, bit-identical to
// one run.
#pragma once

#include <Eigen/Core>
#include <functional>
#include <string>
#include <vector>

#include "distance/distance.hpp"
#include "distance/shape.hpp"
#include "mesh/mesh.hpp"

namespace brenier::distance {

/// Tile `index` of `count` (0-based): a contiguous share of the pairs i < j in row-major order.
struct TileSpec {
  int index = 0;
  int count = 1;
};
/// "I/K" with 0 <= I < K; throws Error(kInvalidArgument) otherwise.
TileSpec parse_tile(const std::string& text);
/// The pairs (i < j) of tile t of an n-shape matrix, in row-major order.
std::vector<std::pair<int, int>> tile_pairs(int n, const TileSpec& t);

struct ShapeInput {
  std::string name;
  mesh::TriMesh mesh;
  ShapeOptions options;  // markers per shape; the rest must agree across shapes
};

struct MatrixOptions {
  Method method = Method::kOmtLinear;
  WassersteinOptions wasserstein;
  int jobs = 1;            // worker threads
  TileSpec tile;           // the whole matrix by default
  std::string cache_dir;   // prepared shapes are kept here by key (empty: no cache)
  /// Called (never concurrently) as shapes and pairs finish: stage "shapes" or "pairs".
  std::function<void(const std::string& stage, int done, int total)> progress;
  /// Passed to every solve (shapes and pairs; may be called from several workers at once):
  /// returning false cancels the tile (Error(kCancelled)).
  omt::Progress solver_progress;
};

/// Shape `in` prepared (prepare_shape), or read back from `cache_dir` when a file of the same
/// key is there; a fresh one is saved there (written whole, then renamed: safe between
/// processes). Empty cache_dir: no cache.
Shape cached_shape(const ShapeInput& in, const std::string& cache_dir, const omt::Progress& progress = {});

struct PairEntry {
  int i = 0, j = 0;
  PairResult result;
};

/// One tile's results with what identifies the matrix it belongs to.
struct MatrixTile {
  std::string method;
  std::string fingerprint;  // every option that changes a value
  std::vector<std::string> names, keys;  // all n shapes, in matrix order
  TileSpec tile;
  std::vector<PairEntry> pairs;
};

/// Prepares the shapes the tile needs (from the cache when there) and computes its pairs.
/// Throws the first shape's error (by index) when a shape cannot be prepared; pairs whose
/// transport did not converge are returned with converged = false.
MatrixTile compute_tile(const std::vector<ShapeInput>& shapes, const MatrixOptions& options);

/// The symmetric matrix with zero diagonal from tiles of one matrix, each present once.
/// Throws Error(kInvalidArgument) naming the problem for tiles of different matrices,
/// duplicates or missing tiles.
Eigen::MatrixXd assemble(const std::vector<MatrixTile>& tiles);

/// Tile files (JSON; doubles written so they read back to the same bits).
void write_tile(const MatrixTile& tile, const std::string& path);
MatrixTile read_tile(const std::string& path);

/// Writes the matrix as CSV (header row "name,<names...>", then one row per shape), NPY
/// (float64, n x n, C order) or JSON ({"names", "method", "matrix"}), chosen by the
/// extension of `path` (.csv, .npy, .json).
void write_matrix(const std::string& path, const std::vector<std::string>& names, const Eigen::MatrixXd& d,
                  const std::string& method);
/// Reads a matrix written as CSV or JSON; checks it is square, finite, symmetric with zero
/// diagonal (Error(kInvalidArgument) naming the entry otherwise).
void read_matrix(const std::string& path, std::vector<std::string>& names, Eigen::MatrixXd& d);

}  // namespace brenier::distance

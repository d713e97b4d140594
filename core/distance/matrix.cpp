#include "distance/matrix.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <sstream>

#include "common/error.hpp"
#include "common/format.hpp"
#include "common/check.hpp"
#include "common/parallel.hpp"
#include "common/version.hpp"

namespace brenier::distance {

TileSpec parse_tile(const std::string& text) {
  TileSpec t;
  char extra = 0;
  if (std::sscanf(text.c_str(), "%d/%d%c", &t.index, &t.count, &extra) != 2 || t.count < 1 || t.index < 0 ||
      t.index >= t.count)
    invalid("tile '" + text + "': expected I/K with 0 <= I < K (e.g. 0/4)");
  return t;
}

std::vector<std::pair<int, int>> tile_pairs(int n, const TileSpec& t) {
  const long long total = static_cast<long long>(n) * (n - 1) / 2;
  const long long first = total * t.index / t.count, last = total * (t.index + 1) / t.count;
  std::vector<std::pair<int, int>> out;
  long long l = 0;
  for (int i = 0; i < n && l < last; ++i) {
    if (l + (n - 1 - i) <= first) {  // the whole row lies before the tile
      l += n - 1 - i;
      continue;
    }
    for (int j = i + 1; j < n; ++j, ++l)
      if (l >= first && l < last) out.emplace_back(i, j);
  }
  return out;
}

namespace {

std::string matrix_fingerprint(const std::vector<ShapeInput>& shapes, const MatrixOptions& opt) {
  const ShapeOptions& s = shapes.front().options;
  for (const ShapeInput& x : shapes) {
    const ShapeOptions& o = x.options;
    if (o.quadrature.rings != s.quadrature.rings || o.quadrature.angles != s.quadrature.angles ||
        o.conformal_tolerance != s.conformal_tolerance || o.omt_tolerance != s.omt_tolerance ||
        o.transport_tolerance != s.transport_tolerance || o.cost_tolerance != s.cost_tolerance || o.sphere != s.sphere)
      invalid("shape '" + x.name + "' has other domain, quadrature or tolerance options than '" + shapes.front().name + "'");
  }
  char buf[256];
  std::snprintf(buf, sizeof buf, "%s;%s;quad=%dx%d;ktol=%.17g;otol=%.17g;wtol=%.17g;ctol=%.17g", method_name(opt.method),
                s.sphere ? "sphere" : "disk", s.quadrature.rings, s.quadrature.angles, s.conformal_tolerance, s.omt_tolerance,
                s.transport_tolerance, s.cost_tolerance);
  std::string out = buf + std::string(";engine=") + kNumericsVersion;
  if (opt.method == Method::kWasserstein) {
    std::snprintf(buf, sizeof buf, ";refine=%d;debias=%d", opt.wasserstein.refine_rotation ? 1 : 0,
                  opt.wasserstein.debias ? 1 : 0);
    out += buf;
    if (opt.wasserstein.exact_rotation) out += ";exact_rotation=1";  // (absent: the settings of earlier tiles)
  }
  return out;
}

}  // namespace

Shape cached_shape(const ShapeInput& in, const std::string& cache_dir, const omt::Progress& progress) {
  const std::string key = shape_key(in.mesh, in.options);
  const std::string path = cache_dir.empty() ? "" : cache_dir + "/" + key + ".shape";
  Shape s;
  if (path.empty() || !load_shape(path, s) || s.key != key) {
    s = prepare_shape(in.mesh, in.name, in.options, progress);
    if (!path.empty()) save_shape(s, path);
  }
  s.name = in.name;
  return s;
}

MatrixTile compute_tile(const std::vector<ShapeInput>& shapes, const MatrixOptions& opt) {
  const int n = static_cast<int>(shapes.size());
  if (n < 2) invalid("a distance matrix needs at least two shapes");
  if (opt.tile.count < 1 || opt.tile.index < 0 || opt.tile.index >= opt.tile.count) invalid("bad tile");
  MatrixTile tile;
  tile.method = method_name(opt.method);
  tile.fingerprint = matrix_fingerprint(shapes, opt);
  tile.tile = opt.tile;
  for (const ShapeInput& s : shapes) {
    tile.names.push_back(s.name);
    tile.keys.push_back(shape_key(s.mesh, s.options));
  }
  const std::vector<std::pair<int, int>> pairs = tile_pairs(n, opt.tile);
  std::vector<int> needed;
  {
    std::set<int> used;
    for (auto [i, j] : pairs) used.insert({i, j});
    needed.assign(used.begin(), used.end());
  }
  std::mutex mutex;
  int done = 0;
  auto tick = [&](const char* stage, int total) {
    std::lock_guard<std::mutex> lock(mutex);
    ++done;
    if (opt.progress) opt.progress(stage, done, total);
  };
  if (!opt.cache_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(opt.cache_dir, ec);
    if (ec) invalid("cannot create the cache directory " + opt.cache_dir + ": " + ec.message());
  }
  // Each shape once (Alg. 5 steps 1-4 and its OMT map), from the cache when it is there.
  std::vector<Shape> prepared(n);
  parallel_for(static_cast<int>(needed.size()), opt.jobs, [&](int k) {
    const int i = needed[k];
    prepared[i] = cached_shape(shapes[i], opt.cache_dir, opt.solver_progress);
    tick("shapes", static_cast<int>(needed.size()));
  });
  done = 0;
  tile.pairs.resize(pairs.size());
  parallel_for(static_cast<int>(pairs.size()), opt.jobs, [&](int k) {
    const auto [i, j] = pairs[k];
    PairEntry& e = tile.pairs[k];
    e.i = i;
    e.j = j;
    if (opt.solver_progress && !opt.solver_progress(0, 0)) fail(ErrorCode::kCancelled, "cancelled");
    WassersteinOptions wo = opt.wasserstein;
    if (opt.solver_progress) wo.progress = opt.solver_progress;
    e.result = opt.method == Method::kWasserstein ? wasserstein(prepared[i], prepared[j], wo)
                                                  : omt_linear(prepared[i], prepared[j]);
    tick("pairs", static_cast<int>(pairs.size()));
  });
  return tile;
}

Eigen::MatrixXd assemble(const std::vector<MatrixTile>& tiles) {
  if (tiles.empty()) invalid("no tiles to merge");
  const MatrixTile& t0 = tiles.front();
  const int n = static_cast<int>(t0.names.size());
  std::vector<char> seen(t0.tile.count, 0);
  for (const MatrixTile& t : tiles) {
    if (t.method != t0.method || t.fingerprint != t0.fingerprint)
      invalid("the tiles come from different computations (" + t0.fingerprint + " vs " + t.fingerprint + ")");
    if (t.names != t0.names || t.keys != t0.keys) invalid("the tiles are over different shapes");
    if (t.tile.count != t0.tile.count)
      invalid("the tiles split the matrix differently (" + std::to_string(t0.tile.count) + " and " +
              std::to_string(t.tile.count) + " tiles)");
    if (seen[t.tile.index]++) invalid("tile " + std::to_string(t.tile.index) + " is given twice");
  }
  for (int k = 0; k < t0.tile.count; ++k)
    if (!seen[k]) invalid("tile " + std::to_string(k) + "/" + std::to_string(t0.tile.count) + " is missing");
  Eigen::MatrixXd d = Eigen::MatrixXd::Constant(n, n, std::numeric_limits<double>::quiet_NaN());
  d.diagonal().setZero();
  for (const MatrixTile& t : tiles) {
    const std::vector<std::pair<int, int>> expect = tile_pairs(n, t.tile);
    if (expect.size() != t.pairs.size())
      invalid("tile " + std::to_string(t.tile.index) + " holds " + std::to_string(t.pairs.size()) + " pairs, not " +
              std::to_string(expect.size()));
    for (size_t k = 0; k < expect.size(); ++k) {
      const PairEntry& e = t.pairs[k];
      if (e.i != expect[k].first || e.j != expect[k].second)
        invalid("tile " + std::to_string(t.tile.index) + " holds pair (" + std::to_string(e.i) + ", " +
                std::to_string(e.j) + ") out of place");
      d(e.i, e.j) = d(e.j, e.i) = e.result.distance;
    }
  }
  return d;
}

// ---- files -------------------------------------------------------------------------------

namespace {

nlohmann::json number(double x) { return std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(nullptr); }
double number(const nlohmann::json& j) {
  return j.is_null() ? std::numeric_limits<double>::quiet_NaN() : j.get<double>();
}

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) out += c == '"' ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

std::vector<std::string> csv_split(const std::string& line) {
  std::vector<std::string> out(1);
  bool quoted = false;
  for (size_t k = 0; k < line.size(); ++k) {
    const char c = line[k];
    if (quoted) {
      if (c == '"' && k + 1 < line.size() && line[k + 1] == '"') out.back() += '"', ++k;
      else if (c == '"') quoted = false;
      else out.back() += c;
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      out.emplace_back();
    } else if (c != '\r') {
      out.back() += c;
    }
  }
  return out;
}

std::string g17(double x) {
  return std::isnan(x) ? "nan" : double_text(x);
}

std::string extension(const std::string& path) {
  std::string e = std::filesystem::path(path).extension().string();
  for (char& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return e;
}

void write_file(const std::string& path, const std::string& bytes) {
  std::ofstream os(path, std::ios::binary | std::ios::trunc);
  if (!os || !os.write(bytes.data(), static_cast<std::streamsize>(bytes.size())) || !os.flush())
    invalid("cannot write " + path);
}

std::string read_file(const std::string& path) {
  std::ifstream is(path, std::ios::binary);
  if (!is) fail(ErrorCode::kNotFound, "cannot read " + path);
  std::ostringstream ss;
  ss << is.rdbuf();
  return ss.str();
}

}  // namespace

void write_tile(const MatrixTile& t, const std::string& path) {
  nlohmann::json pairs = nlohmann::json::array();
  for (const PairEntry& e : t.pairs)
    pairs.push_back({e.i, e.j, number(e.result.distance), number(e.result.forward), number(e.result.backward),
                     e.result.rotation, e.result.converged});
  nlohmann::json j = {{"format", "brenier-matrix-tile"}, {"version", 1},       {"method", t.method},
                      {"fingerprint", t.fingerprint},    {"names", t.names},   {"keys", t.keys},
                      {"tile", {{"index", t.tile.index}, {"count", t.tile.count}}},
                      {"pairs", pairs}};
  write_file(path, j.dump() + "\n");
}

MatrixTile read_tile(const std::string& path) {
  MatrixTile t;
  try {
    const nlohmann::json j = nlohmann::json::parse(read_file(path));
    if (j.value("format", "") != "brenier-matrix-tile" || j.value("version", 0) != 1)
      invalid(path + " is not a brenier matrix tile");
    t.method = j.at("method").get<std::string>();
    t.fingerprint = j.at("fingerprint").get<std::string>();
    t.names = j.at("names").get<std::vector<std::string>>();
    t.keys = j.at("keys").get<std::vector<std::string>>();
    t.tile.index = j.at("tile").at("index").get<int>();
    t.tile.count = j.at("tile").at("count").get<int>();
    if (t.names.size() != t.keys.size() || t.names.size() < 2 || t.tile.count < 1 || t.tile.index < 0 ||
        t.tile.index >= t.tile.count)
      invalid(path + ": inconsistent tile header");
    const int n = static_cast<int>(t.names.size());
    for (const nlohmann::json& p : j.at("pairs")) {
      PairEntry e;
      e.i = p.at(0).get<int>();
      e.j = p.at(1).get<int>();
      if (e.i < 0 || e.j <= e.i || e.j >= n) invalid(path + ": pair index out of range");
      e.result.distance = number(p.at(2));
      e.result.forward = number(p.at(3));
      e.result.backward = number(p.at(4));
      e.result.rotation = p.at(5).get<double>();
      e.result.converged = p.at(6).get<bool>();
      t.pairs.push_back(e);
    }
  } catch (const nlohmann::json::exception& e) {
    invalid(path + ": not a readable tile (" + e.what() + ")");
  }
  return t;
}

void write_matrix(const std::string& path, const std::vector<std::string>& names, const Eigen::MatrixXd& d,
                  const std::string& method) {
  const int n = static_cast<int>(names.size());
  BRENIER_CHECK(d.rows() == n && d.cols() == n, "matrix and names disagree");
  const std::string ext = extension(path);
  if (ext == ".csv") {
    std::string s = "name";
    for (const std::string& x : names) {
      s += ',';
      s += csv_field(x);
    }
    s += "\n";
    for (int i = 0; i < n; ++i) {
      s += csv_field(names[i]);
      for (int j = 0; j < n; ++j) {
        s += ',';
        s += g17(d(i, j));
      }
      s += "\n";
    }
    write_file(path, s);
  } else if (ext == ".npy") {
    char dict[128];
    std::snprintf(dict, sizeof dict, "{'descr': '<f8', 'fortran_order': False, 'shape': (%d, %d), }", n, n);
    std::string header = dict;
    while ((10 + header.size() + 1) % 64 != 0) header += ' ';
    header += '\n';
    std::string s = "\x93NUMPY";
    s += '\x01';
    s += '\x00';
    s += static_cast<char>(header.size() & 0xff);
    s += static_cast<char>(header.size() >> 8);
    s += header;
    const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> rm = d;
    s.append(reinterpret_cast<const char*>(rm.data()), sizeof(double) * rm.size());  // little-endian host
    write_file(path, s);
  } else if (ext == ".json") {
    nlohmann::json rows = nlohmann::json::array();
    for (int i = 0; i < n; ++i) {
      nlohmann::json row = nlohmann::json::array();
      for (int j = 0; j < n; ++j) row.push_back(number(d(i, j)));
      rows.push_back(row);
    }
    write_file(path, nlohmann::json{{"names", names}, {"method", method}, {"matrix", rows}}.dump() + "\n");
  } else {
    invalid("matrix output " + path + ": the extension must be .csv, .npy or .json");
  }
}

void read_matrix(const std::string& path, std::vector<std::string>& names, Eigen::MatrixXd& d) {
  const std::string ext = extension(path), bytes = read_file(path);
  std::vector<std::vector<double>> rows;
  names.clear();
  if (ext == ".json") {
    try {
      const nlohmann::json j = nlohmann::json::parse(bytes);
      names = j.at("names").get<std::vector<std::string>>();
      for (const nlohmann::json& r : j.at("matrix")) {
        rows.emplace_back();
        for (const nlohmann::json& x : r) rows.back().push_back(number(x));
      }
    } catch (const nlohmann::json::exception& e) {
      invalid(path + ": not a readable matrix (" + e.what() + ")");
    }
  } else if (ext == ".csv") {
    std::istringstream in(bytes);
    std::string line;
    int line_no = 0;
    while (std::getline(in, line)) {
      ++line_no;
      if (line.empty() || line == "\r") continue;
      std::vector<std::string> f = csv_split(line);
      if (names.empty()) {
        if (f.size() < 2) invalid(path + ": the header must be name,<shape names...>");
        names.assign(f.begin() + 1, f.end());
        continue;
      }
      if (f.size() != names.size() + 1)
        invalid(path + ":" + std::to_string(line_no) + ": " + std::to_string(f.size() - 1) + " values for " +
                std::to_string(names.size()) + " shapes");
      if (f[0] != names[rows.size()])
        invalid(path + ":" + std::to_string(line_no) + ": row '" + f[0] + "' where '" + names[rows.size()] +
                "' was expected");
      rows.emplace_back();
      for (size_t k = 1; k < f.size(); ++k) {
        char* end = nullptr;
        const double x = std::strtod(f[k].c_str(), &end);
        if (end == f[k].c_str() || *end != '\0')
          invalid(path + ":" + std::to_string(line_no) + ": '" + f[k] + "' is not a number");
        rows.back().push_back(x);
      }
    }
  } else {
    invalid("matrix " + path + ": the extension must be .csv or .json");
  }
  const int n = static_cast<int>(names.size());
  if (n < 2 || static_cast<int>(rows.size()) != n) invalid(path + ": a square matrix with a row per shape is needed");
  d.resize(n, n);
  for (int i = 0; i < n; ++i) {
    if (static_cast<int>(rows[i].size()) != n) invalid(path + ": row " + std::to_string(i) + " has the wrong length");
    for (int j = 0; j < n; ++j) d(i, j) = rows[i][j];
  }
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const std::string at = path + ": entry (" + names[i] + ", " + names[j] + ")";
      if (!std::isfinite(d(i, j))) invalid(at + " is not a finite number (a pair that did not converge?)");
      if (i == j && d(i, j) != 0) invalid(at + " on the diagonal is not 0");
      if (d(i, j) < 0) invalid(at + " is negative");
      if (std::abs(d(i, j) - d(j, i)) > 1e-12 * std::max(1.0, std::abs(d(i, j))))
        invalid(at + " differs from its mirror: the matrix is not symmetric");
    }
}

}  // namespace brenier::distance

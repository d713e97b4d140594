// The matrix job's work file (matrix_work.hpp): JSON, read back to the same request bit for bit.
#include "jobs/matrix_work.hpp"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/parallel.hpp"
#include "jobs/jobs.hpp"
#include "mesh/io.hpp"
#include "mesh/validate.hpp"

namespace brenier::jobs {

namespace {

constexpr int kWorkVersion = 1;

nlohmann::json to_json(const ShapeRequest& r) {
  return {{"method", distance::method_name(r.method)},
          {"domain", domain_name(r.domain)},
          {"cut_hole", r.cut_hole},
          {"tolerance", r.tolerance},
          {"cost_tolerance", r.cost_tolerance},
          {"refine_rotation", r.refine_rotation},
          {"raw", r.raw},
          {"exact_rotation", r.exact_rotation},
          {"rings", r.rings},
          {"angles", r.angles}};
}

ShapeRequest shape_from_json(const nlohmann::json& j) {
  ShapeRequest r;
  r.method = distance::parse_method(j.at("method").get<std::string>());
  const auto domain = find_domain(j.at("domain").get<std::string>());
  if (!domain) invalid("unknown domain " + j.at("domain").get<std::string>());
  r.domain = *domain;
  r.cut_hole = j.at("cut_hole").get<bool>();
  r.tolerance = j.at("tolerance").get<double>();
  r.cost_tolerance = j.at("cost_tolerance").get<double>();
  r.refine_rotation = j.at("refine_rotation").get<bool>();
  r.raw = j.at("raw").get<bool>();
  r.exact_rotation = j.value("exact_rotation", false);
  r.rings = j.at("rings").get<int>();
  r.angles = j.at("angles").get<int>();
  return r;
}

}  // namespace

void write_matrix_work(const MatrixWork& w, const std::string& path) {
  nlohmann::json shapes = nlohmann::json::array();
  for (size_t k = 0; k < w.shapes.size(); ++k) {
    nlohmann::json s = {{"name", w.shapes[k].name}, {"path", w.shapes[k].path}, {"format", w.shapes[k].format}};
    if (!w.request.markers.empty())
      s["markers"] = {w.request.markers[k].center, w.request.markers[k].boundary};
    shapes.push_back(std::move(s));
  }
  const nlohmann::json j = {{"brenier_matrix_work", kWorkVersion},
                            {"request", to_json(w.request.shape)},
                            {"shapes", shapes},
                            {"cache", w.cache},
                            {"tiles", w.tiles}};
  const std::string tmp = path + ".tmp." + std::to_string(::getpid());
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out << j.dump(2) << '\n';
    if (!out) invalid("cannot write " + tmp);
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) invalid("cannot write " + path + ": " + ec.message());
}

MatrixWork read_matrix_work(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) invalid("cannot read the matrix work file " + path);
  MatrixWork w;
  try {
    const nlohmann::json j = nlohmann::json::parse(in);
    if (j.at("brenier_matrix_work").get<int>() != kWorkVersion)
      invalid("version " + j.at("brenier_matrix_work").dump() + " (this brenier-compute reads version " +
              std::to_string(kWorkVersion) + ")");
    w.request.shape = shape_from_json(j.at("request"));
    for (const auto& s : j.at("shapes")) {
      w.shapes.push_back({s.at("name").get<std::string>(), s.at("path").get<std::string>(),
                          s.at("format").get<std::string>()});
      if (s.contains("markers"))
        w.request.markers.push_back({s.at("markers").at(0).get<int>(), s.at("markers").at(1).get<int>()});
    }
    w.cache = j.at("cache").get<std::string>();
    w.tiles = j.at("tiles").get<int>();
    w.request.validate(w.shapes.size());
    if (w.tiles < 1) invalid("tiles must be at least 1");
    for (const auto& s : w.shapes)
      if (!mesh::parse_format(s.format)) invalid("unknown mesh format " + s.format + " of " + s.name);
  } catch (const nlohmann::json::exception& e) {
    invalid("the matrix work file " + path + " is malformed: " + e.what());
  } catch (const Error& e) {
    invalid("the matrix work file " + path + ": " + e.what());
  }
  return w;
}

std::vector<distance::ShapeInput> matrix_inputs(const MatrixWork& w, int threads) {
  std::vector<distance::ShapeInput> in(w.shapes.size());
  parallel_for(static_cast<int>(w.shapes.size()), threads, [&](int k) {
    const MatrixWork::Shape& s = w.shapes[k];
    const mesh::CleanMesh cm = mesh::clean(mesh::read_soup_file(s.path, mesh::parse_format(s.format)));
    in[k] = shape_input(cm, s.name, s.name, w.request.shape,
                        w.request.markers.empty() ? DiskMarkers{} : w.request.markers[k]);
  });
  return in;
}

void unique_names(std::vector<std::string>& names, const std::vector<std::string>& ids) {
  std::map<std::string, int> count;
  for (const auto& n : names) ++count[n];
  for (size_t k = 0; k < names.size(); ++k)
    if (count[names[k]] > 1) names[k].append("#").append(ids[k], 0, 12);
}

}  // namespace brenier::jobs

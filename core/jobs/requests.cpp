// The requests' names and their validation: every front end's one place for the checks
// that need no mesh (requests.hpp).
#include "jobs/requests.hpp"

#include <array>
#include <cerrno>
#include <cstdint>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "common/error.hpp"

namespace brenier {
namespace {

// Each enum's names, in the enum's order: one table for both directions.
template <class E, size_t N>
struct Names {
  std::array<const char*, N> name;
  const char* of(E e) const { return name[static_cast<size_t>(e)]; }
  std::optional<E> find(std::string_view s) const {
    for (size_t k = 0; k < N; ++k)
      if (s == name[k]) return static_cast<E>(k);
    return std::nullopt;
  }
};
constexpr Names<distance::Method, 2> kMethods{{"wasserstein", "omt-linear"}};
constexpr Names<mesh::Domain, 2> kDomains{{"disk", "sphere"}};
constexpr Names<jobs::MapMethod, 2> kMapMethods{{"conformal", "area-preserving"}};

}  // namespace

namespace distance {

const char* method_name(Method m) { return kMethods.of(m); }
std::optional<Method> find_method(std::string_view name) { return kMethods.find(name); }

Method parse_method(const std::string& name) {
  if (auto m = find_method(name)) return *m;
  invalid("unknown distance method '" + name + "' (wasserstein or omt-linear)");
}

}  // namespace distance

namespace mesh {

const char* domain_name(Domain d) { return kDomains.of(d); }
std::optional<Domain> find_domain(std::string_view name) { return kDomains.find(name); }

}  // namespace mesh

namespace jobs {
namespace {

bool finite_at_least(double x, double lo) { return std::isfinite(x) && x >= lo; }

void check_marker_pair(const DiskMarkers& m, const std::string& whose) {
  if (!m.given()) return;
  if (m.center < 0 || m.boundary < 0)
    invalid(whose + "{markers} are two vertex numbers, the center and a boundary vertex (both or neither)");
}

// An integer that is the whole of `text` (leading and trailing blanks allowed).
std::optional<int> whole_int(const std::string& text) {
  const char* s = text.c_str();
  char* end = nullptr;
  const long v = std::strtol(s, &end, 10);
  if (end == s) return std::nullopt;
  while (*end == ' ' || *end == '\t' || *end == '\r') ++end;
  if (*end != '\0' || v < -1 || v > (1L << 31) - 1) return std::nullopt;
  return static_cast<int>(v);
}

}  // namespace

const char* map_method_name(MapMethod m) { return kMapMethods.of(m); }
std::optional<MapMethod> find_map_method(std::string_view name) { return kMapMethods.find(name); }

void MapRequest::validate() const {
  const bool sphere = domain == Domain::kSphere;
  if (sphere && !markers.empty() && markers.size() != 3)
    invalid("sphere {markers} are three vertices (sent to 0, 1, infinity)");
  if (!sphere && !markers.empty() && markers.size() != 2)
    invalid("disk {markers} are two vertices: the center and a boundary vertex");
  for (int v : markers)
    if (v < 0) invalid("{markers} are vertex numbers; " + std::to_string(v) + " is not");
  if (sphere && cut_hole) invalid("{cut_hole} applies to the disk domain");
  if (hole_vertex < -1) invalid("{hole_vertex} must be a vertex number");
  if (hole_vertex >= 0 && !cut_hole) invalid("{hole_vertex} goes with {cut_hole}");
  if (!finite_at_least(tolerance, 0)) invalid("{tolerance} must be a positive number");
  if (max_iterations < 1 || max_iterations > kMaxIterations)
    invalid("{max_iterations} must lie in [1, " + std::to_string(kMaxIterations) + "]");
  if (!(t >= 0 && t <= 1)) invalid("{t} must lie in [0, 1]");
  if (method == MapMethod::kConformal && (t > 0 || !weights.empty()))
    invalid("{t} and {weights} apply to the area-preserving method");
  for (size_t i = 0; i < weights.size(); ++i)
    if (!(weights[i] > 0) || !std::isfinite(weights[i]))
      invalid("weight " + std::to_string(i) + " is " + std::to_string(weights[i]) + "; {weights} must be positive numbers");
  if (!finite_at_least(refine_mean_tolerance, 0)) invalid("{refine_mean_tolerance} must be a positive number");
  if (!finite_at_least(refine_p95_tolerance, 0)) invalid("{refine_p95_tolerance} must be a positive number");
  if ((refine_mean_tolerance > 0 || refine_p95_tolerance > 0) && (method == MapMethod::kConformal || !refine || t > 0))
    invalid("{refine_mean_tolerance} and {refine_p95_tolerance} stop the area-preserving refinement, which does not "
            "run with the conformal method, {no_refine} or {t} above 0");
}

void RegisterRequest::validate() const {
  if (source_landmarks.size() != target_landmarks.size())
    invalid("the source has " + std::to_string(source_landmarks.size()) + " landmarks and the target " +
            std::to_string(target_landmarks.size()) + "; {landmarks} are paired by order");
  if (source_landmarks.size() > kMaxLandmarks)
    invalid(std::to_string(source_landmarks.size()) + " {landmarks}; at most " + std::to_string(kMaxLandmarks));
  for (const auto* list : {&source_landmarks, &target_landmarks}) {
    const char* which = list == &source_landmarks ? "source" : "target";
    for (size_t i = 0; i < list->size(); ++i) {
      if ((*list)[i] < 0)
        invalid(std::string(which) + " landmark " + std::to_string(i + 1) + " is " + std::to_string((*list)[i]) +
                "; {landmarks} are vertex numbers");
      for (size_t j = 0; j < i; ++j)
        if ((*list)[j] == (*list)[i])
          invalid(std::string(which) + " landmarks " + std::to_string(j + 1) + " and " + std::to_string(i + 1) +
                  " are the same vertex " + std::to_string((*list)[i]));
    }
  }
  if (domain == Domain::kSphere && cut_hole) invalid("{cut_hole} applies to the disk domain");
  if (isometric_sphere && !isometric)
    invalid("{harmonic_only} keeps g without the isometric refinement and {isometric_sphere} asks for it; give one of them");
  if (!finite_at_least(tolerance, 0)) invalid("{tolerance} must be a positive number");
  if (max_iterations < 1 || max_iterations > MapRequest::kMaxIterations)
    invalid("{max_iterations} must lie in [1, " + std::to_string(MapRequest::kMaxIterations) + "]");
}

void ShapeRequest::validate() const {
  const bool sphere = domain == Domain::kSphere;
  if (sphere && cut_hole) invalid("{cut_hole} applies to the disk domain");
  if (sphere && refine_rotation)
    invalid("{refine_rotation} applies to the disk domain (on the sphere the frame's half-turns are compared)");
  if (!(tolerance > 0) || !std::isfinite(tolerance)) invalid("{tolerance} must be a positive number");
  if (!finite_at_least(cost_tolerance, 0) || cost_tolerance > 1)
    invalid("{cost_tolerance} must lie in [0, 1] (0: off)");
  if (rings < 1 || rings > 4096) invalid("{rings} must lie in [1, 4096]");
  if (angles < 4 || angles > 65536) invalid("{angles} must lie in [4, 65536]");
  // Each shape stores and locates rings x angles samples: bounded together, or a request of
  // a few bytes asks for gigabytes per shape.
  if (int64_t{rings} * angles > kMaxSamples)
    invalid("{rings} x {angles} = " + std::to_string(int64_t{rings} * angles) + " quadrature samples; at most " +
            std::to_string(kMaxSamples));
}

void DistanceRequest::validate() const {
  shape.validate();
  if (a.given() != b.given()) invalid("give {markers} for both meshes or neither");
  check_marker_pair(a, "the first mesh's ");
  check_marker_pair(b, "the second mesh's ");
}

void MatrixRequest::validate(size_t meshes) const {
  shape.validate();
  if (meshes < 2) invalid("a distance matrix needs at least two meshes");
  if (!markers.empty() && markers.size() != meshes)
    invalid(std::to_string(markers.size()) + " {markers} for " + std::to_string(meshes) +
            " meshes (one per mesh, or none)");
  for (size_t k = 0; k < markers.size(); ++k) {
    if (!markers[k].given()) invalid("mesh " + std::to_string(k) + " has no {markers} (markers for every mesh or none)");
    check_marker_pair(markers[k], "mesh " + std::to_string(k) + "'s ");
  }
}

std::vector<double> read_weights_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) invalid("cannot read the weights file " + path);
  std::vector<double> w;
  std::string tok;
  while (in >> tok) {
    char* end = nullptr;
    const double x = std::strtod(tok.c_str(), &end);
    if (end == tok.c_str() || *end != '\0' || !(x > 0) || !std::isfinite(x))
      invalid(path + ": weight " + std::to_string(w.size()) + " is '" + tok + "'; weights must be positive numbers");
    w.push_back(x);
  }
  if (w.empty()) invalid(path + ": no weights");
  return w;
}

std::vector<SiteEntry> read_sites_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) invalid("cannot read the sites file " + path);
  std::vector<SiteEntry> out;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    for (char& c : line)
      if (c == ',' || c == '\t' || c == '\r') c = ' ';
    std::istringstream words(line);
    std::vector<std::string> w;
    for (std::string t; words >> t;) w.push_back(t);
    if (w.empty() || w[0][0] == '#') continue;
    SiteEntry e;
    e.line = n;
    auto bad = [&] {
      invalid(path + ":" + std::to_string(n) + ": '" + line + "' is neither a vertex number nor three coordinates");
    };
    if (w.size() == 1) {
      char* end = nullptr;
      errno = 0;
      const long v = std::strtol(w[0].c_str(), &end, 10);
      if (*end != '\0' || errno != 0 || v < 0 || v > INT32_MAX) bad();
      e.vertex = static_cast<int>(v);
    } else if (w.size() == 3) {
      for (size_t k = 0; k < 3; ++k) {
        char* end = nullptr;
        e.point[k] = std::strtod(w[k].c_str(), &end);
        if (*end != '\0' || !std::isfinite(e.point[k])) bad();
      }
    } else {
      bad();
    }
    out.push_back(e);
  }
  if (out.empty()) invalid(path + ": no sites");
  return out;
}

std::vector<int> read_landmarks_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) invalid("cannot read the landmarks file " + path);
  std::vector<int> out;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    while (!line.empty() && (line.back() == '\r' || line.back() == ' ' || line.back() == '\t')) line.pop_back();
    size_t b = line.find_first_not_of(" \t");
    if (b == std::string::npos || line[b] == '#') continue;
    const std::string tok = line.substr(b);
    char* end = nullptr;
    errno = 0;
    const long v = std::strtol(tok.c_str(), &end, 10);
    if (end == tok.c_str() || *end != '\0' || errno != 0 || v < 0 || v > INT32_MAX)
      invalid(path + ":" + std::to_string(n) + ": '" + tok + "' is not a vertex number");
    out.push_back(static_cast<int>(v));
  }
  return out;
}

MarkersFile read_markers_file(const std::string& path) {
  std::ifstream in(path);
  if (!in) invalid("cannot read the markers file " + path);
  MarkersFile out;
  out.path = path;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    const size_t c1 = line.find(','), c2 = c1 == std::string::npos ? c1 : line.find(',', c1 + 1);
    std::optional<int> center, boundary;
    if (c1 != std::string::npos && c2 != std::string::npos && line.find(',', c2 + 1) == std::string::npos) {
      center = whole_int(line.substr(c1 + 1, c2 - c1 - 1));
      boundary = whole_int(line.substr(c2 + 1));
    }
    if (c1 == 0 || !center || !boundary || *center < 0 || *boundary < 0)
      invalid(path + ":" + std::to_string(n) + ": expected mesh,center_vertex,boundary_vertex");
    out.entries.push_back({line.substr(0, c1), DiskMarkers{*center, *boundary}});
  }
  return out;
}

DiskMarkers MarkersFile::of(const std::string& mesh) const {
  const std::string stem = std::filesystem::path(mesh).stem().string();
  for (const std::string& key : {mesh, stem})
    for (const auto& [name, m] : entries)
      if (name == key) return m;
  invalid(path + " has no markers for " + mesh + " (markers for every mesh or none)");
}

}  // namespace jobs
}  // namespace brenier

// What a caller asks of each kind of job, typed and validated in one place. brenier-compute
// (command-line flags), the thin CLI (the same flags, sent as a proto spec) and brenierd (the
// spec received) all build these and call validate(); the mesh-dependent checks (vertex
// numbers, topology) follow when the job runs (jobs.hpp). No numerics here, so that the thin
// client links it without the engine.
//
// Messages name an option by its field in braces ("{tolerance}"): each front end renders
// them as its flag or its proto field (common/error.hpp, name_options).
#pragma once

#include <cstdint>
#include <optional>
#include <array>
#include <string>
#include <string_view>
#include <vector>

#include "distance/method.hpp"
#include "mesh/domain.hpp"

namespace brenier::jobs {

/// The parameter domain of a map or of the shapes of a distance.
using mesh::Domain;
using mesh::domain_name;
using mesh::find_domain;

/// Conformal (Alg. 1, sec. 3.2.5) or area-preserving (Alg. 3, the OMT map of the conformal
/// image's area measure).
enum class MapMethod { kConformal, kAreaPreserving };
const char* map_method_name(MapMethod m);
std::optional<MapMethod> find_map_method(std::string_view name);

struct MapRequest {
  Domain domain = Domain::kDisk;
  MapMethod method = MapMethod::kConformal;
  /// Input vertex numbers: disk {center sent to 0, boundary vertex sent to 1}; sphere
  /// {v0, v1, vinf} sent to 0, 1 and infinity; empty: the Moebius normalization instead.
  std::vector<int> markers;
  bool cut_hole = false;   // disk: open a closed genus-0 mesh by removing one vertex's star
  int hole_vertex = -1;    // with cut_hole: that vertex (-1: the one that best splits it)
  double tolerance = 0;    // 0: the method's default (1e-7 rad; 1e-8 relative cell mass)
  int max_iterations = 200;
  std::vector<double> weights;  // area-preserving: one positive weight per input vertex
  double t = 0;                 // area-preserving: phi_t, 0 area-preserving .. 1 conformal
  bool allow_flips = false;     // return a map that folds faces instead of failing
  bool refine = true;           // area-preserving: the face-by-face area refinement (omt/area_refinement.hpp)
  /// The refinement's stop: mean and 95th percentile of |log area ratio| (0: its defaults,
  /// omt::AreaRefineOptions). Looser stops take fewer Newton steps.
  double refine_mean_tolerance = 0, refine_p95_tolerance = 0;

  static constexpr int kMaxIterations = 100000;
  /// Error(kInvalidArgument) naming the field for anything that cannot run on any mesh.
  void validate() const;
  int center() const { return domain == Domain::kDisk && markers.size() == 2 ? markers[0] : -1; }
  int boundary() const { return domain == Domain::kDisk && markers.size() == 2 ? markers[1] : -1; }
};

/// Options of the shapes and transports, shared by distance and matrix jobs.
struct ShapeRequest {
  distance::Method method = distance::Method::kWasserstein;
  Domain domain = Domain::kDisk;
  bool cut_hole = false;
  double tolerance = 1e-3;       // the Wasserstein transports' max relative cell-mass error
  double cost_tolerance = 1e-6;  // ... or the relative dual gap of their cost (0: off)
  bool refine_rotation = false;  // disk: refine the best turn by exact evaluations
  bool exact_rotation = false;   // choose the turn or half-turn by the exact cost, with a certificate
  bool raw = false;              // eq. 3.31 as it stands, no quantization bias removed
  int rings = 64, angles = 256;  // the quadrature of the OMT-map samples (Def. 2.24)
  static constexpr int64_t kMaxSamples = int64_t{1} << 20;  // rings x angles at most

  void validate() const;
};

/// One mesh's disk markers (Def. 2.24): an interior vertex sent to 0, a boundary vertex to 1.
/// Input vertex numbers; both or neither.
struct DiskMarkers {
  int center = -1, boundary = -1;
  bool given() const { return center >= 0 || boundary >= 0; }
};

struct DistanceRequest {
  ShapeRequest shape;
  DiskMarkers a, b;  // both meshes' or neither's
  void validate() const;
};

struct MatrixRequest {
  ShapeRequest shape;
  std::vector<DiskMarkers> markers;  // one per mesh, or empty
  void validate(size_t meshes) const;
};

/// Surface registration (Alg. 7): the source's vertices placed on the target through their
/// parameter domains, f = phi2^-1 o g o phi1.
struct RegisterRequest {
  Domain domain = Domain::kDisk;
  MapMethod method = MapMethod::kAreaPreserving;  // phi1, phi2: area-preserving or conformal maps
  bool cut_hole = false;  // disk: open closed genus-0 meshes (at the first landmark pair if any)
  /// Input vertex numbers of each mesh, paired by order (landmark k of the source goes onto
  /// landmark k of the target).
  std::vector<int> source_landmarks, target_landmarks;
  double tolerance = 0;  // the maps' tolerance (0: their default)
  int max_iterations = 200;
  /// After g, move the source's domain points toward an isometry of the two surfaces
  /// (registration/isometric_refine.hpp), landmarks held, no face turned over, unless
  /// `isometric` is off: on the disk, and on the sphere by the area-preserving route; the
  /// sphere's conformal route only with `isometric_sphere` too (on crowded conformal sphere
  /// maps it helped cow's pairs and set camel's back; on the OMT domains it lowered every
  /// median of cow, camel, bear, triceratops, homer and bull; bench/RESULTS.md, sessions 67
  /// and 68).
  bool isometric = true;
  bool isometric_sphere = false;
  /// Whether the refinement runs for this request.
  bool refines() const { return isometric && (domain != Domain::kSphere || method == MapMethod::kAreaPreserving || isometric_sphere); }

  static constexpr size_t kMaxLandmarks = 1000;  // each matching step solves a dense (L+3)^2 system
  void validate() const;
};

/// A landmarks file: one vertex number per line (blank lines and lines starting with '#'
/// skipped). Error(kInvalidArgument) naming the file and line.
std::vector<int> read_landmarks_file(const std::string& path);

/// One site of a sites file: a vertex number of the input mesh, or a point (x, y, z) that
/// must lie on the surface.
struct SiteEntry {
  int line = 0;
  int vertex = -1;  // >= 0: a vertex number
  std::array<double, 3> point{};
};
/// A sites file: one site per line, either one vertex number or three coordinates
/// (separated by spaces, tabs or commas); blank lines and lines starting with '#' skipped.
/// Error(kInvalidArgument) naming the file and line.
std::vector<SiteEntry> read_sites_file(const std::string& path);

/// Whitespace-separated positive weights (Error(kInvalidArgument) naming the file and the
/// entry otherwise); their count is checked against the mesh when the job runs.
std::vector<double> read_weights_file(const std::string& path);

/// A markers file: one line `mesh,center_vertex,boundary_vertex` per mesh (a file path or
/// its stem; blank lines and lines starting with '#' skipped), read with one parser for every
/// front end. Error(kInvalidArgument) naming the file and line.
struct MarkersFile {
  std::string path;
  std::vector<std::pair<std::string, DiskMarkers>> entries;
  /// The markers of `mesh`, looked up by the path as given, then by its stem;
  /// Error(kInvalidArgument) when the file has none for it.
  DiskMarkers of(const std::string& mesh) const;
};
MarkersFile read_markers_file(const std::string& path);

}  // namespace brenier::jobs

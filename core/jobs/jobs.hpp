// What each kind of job computes, from cleaned meshes to outputs and a JSON report: one code
// path shared by brenier-compute (files) and brenierd (uploads, blobs), so both give the same
// answers and the same errors. No I/O here but what the caller asks for.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "distance/distance.hpp"
#include "distance/matrix.hpp"
#include "jobs/requests.hpp"
#include "mesh/io.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"
#include "omt/area_preserving.hpp"

namespace brenier::jobs {

/// One progress report of a running job: the stage ("conformal", "omt", "shapes",
/// "pairs", ...), an estimate of the whole job's completed fraction in [0, 1], and the
/// current solve's Newton iteration and residual (0 where a stage has none).
struct Progress {
  std::string stage;
  double fraction = 0;
  int iteration = 0;
  double residual = 0;
};
/// Called as the work goes on (never concurrently for one job). Returning false cancels:
/// the numerical loop that called it throws Error(kCancelled).
using ProgressSink = std::function<bool(const Progress&)>;

/// JSON of a cleaning report's problems: [{severity, code, message, count}, ...].
nlohmann::json problems_json(const mesh::Report& report);
/// JSON of a topology: vertices, edges, faces, components, boundary_loops, euler, genus,
/// manifold, class.
nlohmann::json topology_json(const mesh::Topology& t);

// ---- map ---------------------------------------------------------------------------------

struct MapOutcome {
  mesh::TriMesh surface;     // the mesh that was mapped (the input's order; a cut star removed)
  mesh::Vertices positions;  // #V by 3: disk with z = 0, or on the unit sphere
  bool disk = true;
  /// The conformal map an area-preserving map started from (#V by 3, as `positions`); empty
  /// for a conformal map.
  mesh::Vertices conformal;
  std::vector<int> vertex_origin;  // #V of `surface`: its input vertex number
  std::vector<int> face_origin;    // #F of `surface`: its face in the cleaned mesh
  int cut_vertex = -1;             // the input vertex a cut hole removed (-1: none)
  /// mesh, cut_hole_vertex, domain, method, seconds{map}, conformal{...}, omt{...},
  /// quality{...}, problems (the DESIGN.md contract; the caller adds seconds.read/total).
  nlohmann::json report;
};

/// Validates the request, checks it against the mesh (domain, markers, weights) and computes the map
/// (conformal: Alg. 1 / sec. 3.2.5; area-preserving: Alg. 3 / sec. 3.2.5). `what` names the
/// mesh in messages. Throws Error(kInvalidArgument) for a request that does not fit the
/// mesh, Error(kNotConverged) for a solve that did not converge or a map that folds faces
/// (unless allow_flips), Error(kCancelled) when `progress` returned false. `pole` chooses
/// an area-preserving sphere map's stereographic pole (omt::AreaPreservingOptions::pole).
MapOutcome run_map(const mesh::CleanMesh& cm, const std::string& what, const MapRequest& request,
                   const ProgressSink& progress = {}, const omt::PoleChooser& pole = {});

/// The mapped mesh as a file: the disk map as `vt u v` per vertex (OBJ) or u, v properties
/// (PLY) on the input's positions, the sphere map as positions on the sphere.
std::string map_mesh_bytes(const MapOutcome& map, mesh::Format format);
void write_map_file(const MapOutcome& map, const std::string& path);

// ---- distances ---------------------------------------------------------------------------

/// The shape options of every shape of a validated request.
distance::ShapeOptions shape_options(const ShapeRequest& request);
distance::WassersteinOptions wasserstein_options(const ShapeRequest& request);

/// A cleaned, valid mesh made ready for the distances: checked against the domain, opened
/// with a cut hole when asked, its markers (input vertex numbers, -1: none; both or neither)
/// carried to the mesh's numbering. `what` names it in messages.
distance::ShapeInput shape_input(const mesh::CleanMesh& cm, const std::string& name, const std::string& what,
                                 const ShapeRequest& request, DiskMarkers markers = {});

/// JSON of one pair: method, distance, rotation_rad, normalization, converged and, for the
/// Wasserstein distance, forward/backward, raw_*, newton_iterations, max_relative_area_error.
nlohmann::json pair_json(const distance::PairResult& r, distance::Method method);
/// JSON of a prepared shape: name, vertices, faces, key, normalization, iterations (and on the
/// sphere merged_vertices and merge_shift).
nlohmann::json shape_json(const distance::Shape& s);

struct DistanceOutcome {
  distance::PairResult result;
  distance::Shape a, b;
  nlohmann::json report;  // pair_json + domain + shapes + seconds{shapes, pair}
};

/// Both shapes prepared (on two threads when `threads` > 1), then the pair. A transport that
/// did not converge leaves result.converged false (the caller decides); other failures throw.
DistanceOutcome run_distance(const distance::ShapeInput& a, const distance::ShapeInput& b,
                             const ShapeRequest& request, int threads, const ProgressSink& progress = {});

/// What to say of a pair whose transport did not converge (its worst cell-mass error).
std::string not_converged_message(const distance::PairResult& r);

// ---- registration ------------------------------------------------------------------------

/// Where one source vertex lands on the target: an input vertex of the source, the target's
/// input face (polygon) and, for its triangle, the three input vertices and barycentric
/// coordinates, and the point itself.
struct CorrespondenceRow {
  int source_vertex = -1;
  int64_t target_face = -1;
  std::array<int, 3> target_vertices{};
  Eigen::Vector3d bary = Eigen::Vector3d(1, 0, 0);
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
};

struct RegisterOutcome {
  std::vector<CorrespondenceRow> rows;  // one per vertex of the cleaned source mesh
  /// The source's cleaned mesh placed on the target: its faces over the rows' positions.
  mesh::TriMesh morph;
  /// Where each morph vertex lies on the cleaned target mesh (its face, bary).
  std::vector<std::pair<int, Eigen::Vector3d>> target_points;
  /// domain, method, landmarks, source{map report}, target{map report}, match{rotation_rad,
  /// steps, max_landmark_error}, domain_folded_faces, morph_flipped_faces, seconds{...}.
  nlohmann::json report;
};

/// Alg. 7: both meshes mapped onto the domain (run_map: area-preserving or conformal,
/// bijective), g matching the landmarks (registration/domain_match.hpp), and every source
/// vertex located on the target through g. Meshes must have one topology class that fits
/// the domain; landmark vertex numbers must be vertices of their meshes. Throws
/// Error(kInvalidArgument) for input that does not fit, kNotConverged when a map does not
/// converge, kCancelled when `progress` returned false. `threads` > 1 maps both meshes at once.
RegisterOutcome run_register(const mesh::CleanMesh& source, const mesh::CleanMesh& target, const std::string& source_what,
                             const std::string& target_what, const RegisterRequest& request, int threads = 1,
                             const ProgressSink& progress = {});

/// The correspondence as CSV: a header, then source_vertex,target_face,target_v0,target_v1,
/// target_v2,b0,b1,b2,x,y,z per row (17 significant digits).
std::string correspondence_csv(const RegisterOutcome& r);

/// Progress callbacks of the numerical loops (omt::Progress) reporting into `sink` under
/// `stage`, the fraction estimated from the residual's way down to `tolerance` and mapped
/// into [from, to] of the whole job. Empty when the sink is.
omt::Progress solver_progress(const ProgressSink& sink, const std::string& stage, double tolerance, double from,
                              double to);

}  // namespace brenier::jobs

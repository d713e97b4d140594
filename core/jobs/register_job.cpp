// Surface registration (dissertation sec. 4.3, Alg. 7): f = phi2^-1 o g o phi1, phi_i the
// maps of the two meshes onto one parameter domain (run_map), g the landmark-matching
// bijection of the domain (registration/domain_match.hpp), and the target located through
// its own map (registration/correspondence.hpp).
#include <atomic>
#include <chrono>
#include <cstdio>
#include <exception>
#include <future>
#include <mutex>
#include <optional>
#include <sstream>
#include <unordered_map>

#include "common/error.hpp"
#include "common/format.hpp"
#include "conformal/conformal_map.hpp"
#include "jobs/jobs.hpp"
#include "mesh/topology.hpp"
#include "register/correspondence.hpp"
#include "register/domain_match.hpp"
#include "register/isometric_refine.hpp"

namespace brenier::jobs {

namespace {

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Input vertex number -> vertex of `origin`'s mesh (-1: none).
std::vector<int> inverse(const std::vector<int>& origin, int64_t inputs) {
  std::vector<int> to(static_cast<size_t>(inputs), -1);
  for (size_t i = 0; i < origin.size(); ++i) to[static_cast<size_t>(origin[i])] = static_cast<int>(i);
  return to;
}

void check_landmarks(const std::vector<int>& landmarks, const mesh::CleanMesh& cm, const std::string& what) {
  const std::vector<int> to = inverse(cm.vertex_origin, cm.input_vertices);
  for (size_t k = 0; k < landmarks.size(); ++k) {
    const int v = landmarks[k];
    if (v >= cm.input_vertices)
      invalid(what + ": landmark " + std::to_string(k + 1) + " is vertex " + std::to_string(v) + ", but the mesh has " +
              std::to_string(cm.input_vertices) + " vertices");
    if (to[static_cast<size_t>(v)] < 0)
      invalid(what + ": landmark " + std::to_string(k + 1) + " is vertex " + std::to_string(v) +
              ", which cleaning merged or dropped (not a vertex of the surface)");
  }
}

// One mesh's progress into a share [from, to] of the whole job, under "<side> <stage>".
ProgressSink share(const ProgressSink& sink, std::mutex& m, const std::string& side, double from, double to) {
  if (!sink) return {};
  return [&sink, &m, side, from, to](const Progress& p) {
    std::lock_guard<std::mutex> lock(m);
    return sink(Progress{side + " " + p.stage, from + (to - from) * p.fraction, p.iteration, p.residual});
  };
}

// The landmark pairs in domain coordinates (the first pair is the cut holes with cut_hole).
std::vector<registration::LandmarkPair> domain_landmarks(const RegisterRequest& r, const MapOutcome& a,
                                                         const MapOutcome& b, int64_t inputs_a, int64_t inputs_b) {
  const std::vector<int> ta = inverse(a.vertex_origin, inputs_a), tb = inverse(b.vertex_origin, inputs_b);
  const std::vector<char> bb = mesh::boundary_flags(b.surface);
  std::vector<registration::LandmarkPair> out;
  for (size_t k = r.cut_hole ? 1 : 0; k < r.source_landmarks.size(); ++k) {
    const int sa = r.source_landmarks[k], sb = r.target_landmarks[k];
    const int ia = ta[static_cast<size_t>(sa)], ib = tb[static_cast<size_t>(sb)];
    if (ia < 0 || ib < 0)
      invalid("landmark " + std::to_string(k + 1) + " (" + std::to_string(sa) + " -> " + std::to_string(sb) +
              ") is a cut hole's vertex; with {cut_hole}, only the first landmark pair marks the holes");
    registration::LandmarkPair p;
    p.vertex = ia;
    p.q = b.positions.row(ib).transpose();
    if (r.domain == Domain::kDisk) p.q_on_boundary = bb[static_cast<size_t>(ib)];
    p.name = std::to_string(k + 1) + " (" + std::to_string(sa) + " -> " + std::to_string(sb) + ")";
    out.push_back(std::move(p));
  }
  return out;
}

// The bary of surface face `sf` of map `m` re-expressed on the cleaned mesh's face.
std::pair<int, Eigen::Vector3d> on_cleaned(const MapOutcome& m, const mesh::CleanMesh& cm, int sf,
                                           const Eigen::Vector3d& bary) {
  const int c = m.face_origin[static_cast<size_t>(sf)];
  Eigen::Vector3d out = Eigen::Vector3d::Zero();
  for (int k = 0; k < 3; ++k) {
    const int input = m.vertex_origin[static_cast<size_t>(m.surface.F(sf, k))];
    for (int j = 0; j < 3; ++j)
      if (cm.vertex_origin[static_cast<size_t>(cm.mesh.F(c, j))] == input) out[j] += bary[k];
  }
  return {c, out};
}

CorrespondenceRow row_at(const mesh::CleanMesh& tgt, int source_input, int cleaned_face, const Eigen::Vector3d& bary) {
  CorrespondenceRow row;
  row.source_vertex = source_input;
  row.target_face = tgt.face_origin[static_cast<size_t>(cleaned_face)];
  row.bary = bary;
  for (int j = 0; j < 3; ++j) {
    const int v = tgt.mesh.F(cleaned_face, j);
    row.target_vertices[static_cast<size_t>(j)] = tgt.vertex_origin[static_cast<size_t>(v)];
    row.position += bary[j] * tgt.mesh.V.row(v).transpose();
  }
  return row;
}

// Corresponding stereographic poles for the sphere's area-preserving route (sec. 3.2.5).
// The transport runs in the stereographic plane and commutes only with turns about its
// pole, so two meshings of one shape, each mapped from the pole its own mesh suggests, get
// maps that differ by more than a rotation, more than the landmark steps can carry (bear's
// two centroid maps disagreed by 0.37, median chord, where their conformal maps agree to
// 0.0002; with corresponding poles by 0.0045, bench/RESULTS.md, session 32). So the source
// keeps its own pole, and the target's is that pole carried over by the
// rotation that best takes the source's conformal landmarks onto the target's (the two
// conformal maps, both Moebius-centred, agree up to about a rotation).
class PoleLink {
 public:
  PoleLink(std::vector<int> source_landmarks, std::vector<int> target_landmarks)
      : ls_(std::move(source_landmarks)), lt_(std::move(target_landmarks)), seen_(source_.get_future().share()) {}

  omt::PoleChooser source() {
    return [this](const mesh::Vertices& X, const Eigen::Vector3d& own) {
      if (!published_.exchange(true)) source_.set_value({X, own});
      return own;
    };
  }
  omt::PoleChooser target() {
    return [this](const mesh::Vertices& X, const Eigen::Vector3d&) -> Eigen::Vector3d {
      const auto& [Xa, pole] = seen_.get();  // rethrows the source's failure
      return registration::landmark_rotation(Xa, ls_, X, lt_) * pole;
    };
  }
  // Called when the source's map ended without publishing its pole (it failed first), so
  // that the target does not wait for it.
  void source_ended(std::exception_ptr failure) {
    if (published_.exchange(true)) return;
    if (!failure) failure = std::make_exception_ptr(Error(ErrorCode::kInternal, "the source's map chose no pole"));
    source_.set_exception(failure);
  }

 private:
  std::vector<int> ls_, lt_;
  std::promise<std::pair<mesh::Vertices, Eigen::Vector3d>> source_;
  std::shared_future<std::pair<mesh::Vertices, Eigen::Vector3d>> seen_;
  std::atomic<bool> published_{false};
};

int domain_folds(const mesh::TriMesh& m, const mesh::Vertices& X, bool sphere) {
  int n = 0;
  for (int f = 0; f < m.num_faces(); ++f) n += conformal::face_folded(m, X, f, sphere);
  return n;
}

// The two meshes' maps onto the domain (at once with threads > 1); the sphere's OMT maps with
// corresponding poles (PoleLink).
std::pair<MapOutcome, MapOutcome> map_both(const mesh::CleanMesh& source, const mesh::CleanMesh& target,
                                           const std::string& source_what, const std::string& target_what,
                                           const RegisterRequest& r, int threads, const ProgressSink& progress) {
  MapRequest mr;
  mr.domain = r.domain;
  mr.method = r.method;
  mr.cut_hole = r.cut_hole;
  mr.tolerance = r.tolerance;
  mr.max_iterations = r.max_iterations;
  // The sphere's OMT route registers the centroid maps (Alg. 3 as it stands). The face-by-face
  // refinement is a local descent whose answer is not unique (any area-preserving map composed
  // with it is another), so two meshings of one shape drift apart under it: cow's maps with
  // corresponding poles disagree by 0.05 (median chord) as centroid maps and by 0.15 refined
  // (bench/RESULTS.md, session 32).
  const bool sphere = r.domain == Domain::kSphere;
  if (sphere) mr.refine = false;
  MapRequest ms = mr, mt = mr;
  if (r.cut_hole && !r.source_landmarks.empty()) {
    ms.hole_vertex = r.source_landmarks[0];
    mt.hole_vertex = r.target_landmarks[0];
  }
  std::mutex m;
  std::optional<PoleLink> poles;
  if (sphere && r.method == MapMethod::kAreaPreserving) {
    std::vector<int> ls, lt;
    const std::vector<int> ta = inverse(source.vertex_origin, source.input_vertices),
                           tb = inverse(target.vertex_origin, target.input_vertices);
    for (size_t k = 0; k < r.source_landmarks.size(); ++k) {
      ls.push_back(ta[static_cast<size_t>(r.source_landmarks[k])]);
      lt.push_back(tb[static_cast<size_t>(r.target_landmarks[k])]);
    }
    poles.emplace(std::move(ls), std::move(lt));
  }
  auto map_source = [&] {
    try {
      MapOutcome out = run_map(source, source_what, ms, share(progress, m, "source", 0, 0.45),
                               poles ? poles->source() : omt::PoleChooser{});
      if (poles) poles->source_ended(nullptr);
      return out;
    } catch (...) {
      if (poles) poles->source_ended(std::current_exception());
      throw;
    }
  };
  auto map_target = [&] {
    return run_map(target, target_what, mt, share(progress, m, "target", 0.45, 0.9),
                   poles ? poles->target() : omt::PoleChooser{});
  };
  if (threads > 1) {
    auto fa = std::async(std::launch::async, map_source);
    MapOutcome b = map_target();
    return {fa.get(), std::move(b)};
  }
  MapOutcome a = map_source();
  return {std::move(a), map_target()};
}

}  // namespace

RegisterOutcome run_register(const mesh::CleanMesh& source, const mesh::CleanMesh& target, const std::string& source_what,
                             const std::string& target_what, const RegisterRequest& r, int threads,
                             const ProgressSink& progress) {
  r.validate();
  mesh::require_valid(source, source_what);
  mesh::require_valid(target, target_what);
  const mesh::Topology ts = mesh::compute_topology(source.mesh), tt = mesh::compute_topology(target.mesh);
  if (ts.mesh_class != tt.mesh_class || ts.genus != tt.genus || ts.boundary_loops != tt.boundary_loops)
    invalid("the source is a " + std::string(mesh::class_name(ts.mesh_class)) + " (genus " + std::to_string(ts.genus) + ", " +
            std::to_string(ts.boundary_loops) + " boundary loops) and the target a " + mesh::class_name(tt.mesh_class) +
            " (genus " + std::to_string(tt.genus) + ", " + std::to_string(tt.boundary_loops) +
            " boundary loops): meshes of different topology cannot be registered");
  check_landmarks(r.source_landmarks, source, source_what);
  check_landmarks(r.target_landmarks, target, target_what);
  const bool sphere = r.domain == Domain::kSphere;

  const auto t0 = std::chrono::steady_clock::now();
  auto [a, b] = map_both(source, target, source_what, target_what, r, threads, progress);
  const double t_maps = seconds_since(t0);
  if (progress && !progress(Progress{"match", 0.9, 0, 0})) fail(ErrorCode::kCancelled, "cancelled");

  const auto t1 = std::chrono::steady_clock::now();
  const auto pairs = domain_landmarks(r, a, b, source.input_vertices, target.input_vertices);
  // From the landmarks' least-squares turn; from their least-squares Moebius map where the
  // turn's steps fold (domain_match.hpp). A Moebius start first was no more accurate on the
  // conformal route (bench/RESULTS.md, session 31).
  const registration::MatchStart start = registration::MatchStart::kRotation;
  registration::DomainMatch g =
      sphere ? registration::match_spheres(a.positions, a.surface.F, pairs, start)
             : registration::match_disks(a.positions, a.surface.F, pairs, start);
  nlohmann::json isometric = {{"applied", false}};
  std::vector<mesh::SurfacePoint> located;  // g's points in the target's domain mesh, where the refinement found them
  if (r.refines()) {
    std::vector<int> fixed;
    for (const auto& p : pairs) fixed.push_back(p.vertex);
    const auto t_iso = std::chrono::steady_clock::now();
    registration::IsometricRefineOptions io;
    if (progress) {  // the stage "isometric" within the match's share, cancellable at each step
      io.keep_going = [&](int step, double energy) {
        return progress(Progress{"isometric", 0.9 + 0.09 * step / io.max_iterations, step, energy});
      };
    }
    registration::IsometricRefineResult ir =
        registration::refine_isometric(a.surface, g.mapped, b.surface, b.positions, fixed, sphere, io);
    g.mapped = std::move(ir.mapped);
    located = std::move(ir.located);
    isometric = {{"applied", true},
                 {"iterations", ir.iterations},
                 {"converged", ir.converged},
                 {"energy_before", ir.energy_before},
                 {"energy_after", ir.energy_after},
                 {"shortened_steps", ir.shortened_steps},
                 {"seconds", seconds_since(t_iso)}};
  }
  const int folds = domain_folds(a.surface, g.mapped, sphere);
  const std::vector<mesh::SurfacePoint> at = located.size() == static_cast<size_t>(g.mapped.rows())
                                                 ? std::move(located)
                                                 : registration::locate(b.surface.F, b.positions, g.mapped, sphere);
  const double t_match = seconds_since(t1);

  RegisterOutcome out;
  // Rows in the cleaned source's order; the cut vertex goes onto the target's cut vertex.
  const std::vector<int> surface_of = inverse(a.vertex_origin, source.input_vertices);
  out.morph.F = source.mesh.F;
  out.morph.V.resize(source.mesh.num_vertices(), 3);
  for (int j = 0; j < source.mesh.num_vertices(); ++j) {
    const int input = source.vertex_origin[static_cast<size_t>(j)];
    const int i = surface_of[static_cast<size_t>(input)];
    std::pair<int, Eigen::Vector3d> c{-1, Eigen::Vector3d::Zero()};
    if (i >= 0) {
      c = on_cleaned(b, target, at[static_cast<size_t>(i)].face, at[static_cast<size_t>(i)].bary);
    } else {  // the source's cut vertex
      const std::vector<int> tcl = inverse(target.vertex_origin, target.input_vertices);
      const int hole = tcl[static_cast<size_t>(b.cut_vertex)];
      for (int f = 0; f < target.mesh.num_faces() && c.second.sum() == 0; ++f)
        for (int k = 0; k < 3; ++k)
          if (target.mesh.F(f, k) == hole) c = {f, Eigen::Vector3d::Unit(k)};
      if (c.first < 0) fail(ErrorCode::kInternal, "the target's cut vertex has no face");
    }
    out.rows.push_back(row_at(target, input, c.first, c.second));
    out.target_points.push_back(c);
    out.morph.V.row(j) = out.rows.back().position.transpose();
  }
  std::vector<int> corner_face;
  for (const auto& c : out.target_points) corner_face.push_back(c.first);
  const int morph_flips = registration::flipped_morph_faces(out.morph.F, out.morph.V, target.mesh, corner_face);

  nlohmann::json& j = out.report;
  j["domain"] = domain_name(r.domain);
  j["method"] = map_method_name(r.method);
  j["landmarks"] = r.source_landmarks.size();
  j["source"] = a.report;
  j["target"] = b.report;
  j["match"] = {{"start", g.start == registration::MatchStart::kMobius ? "mobius" : "rotation"},
                {"fell_back", g.start != start},
                {"rotation_rad", g.rotation_angle},
                {"mobius_a", {g.mobius_a.x(), g.mobius_a.y(), g.mobius_a.z()}},
                {"start_rms", g.start_rms},
                {"steps", g.steps},
                {"max_landmark_error", g.max_landmark_error},
                {"slivers_let_turn", g.slivers_let_turn},
                {"mended_faces", g.mended_faces}};
  j["isometric"] = isometric;
  j["domain_folded_faces"] = folds;
  j["morph_flipped_faces"] = morph_flips;
  j["seconds"] = {{"maps", t_maps}, {"match", t_match}};
  return out;
}

std::string correspondence_csv(const RegisterOutcome& r) {
  std::string o = "source_vertex,target_face,target_v0,target_v1,target_v2,b0,b1,b2,x,y,z\n";
  o.reserve(o.size() + r.rows.size() * 160);
  for (const auto& row : r.rows) {
    append_int(o, row.source_vertex);
    for (long long k : {static_cast<long long>(row.target_face), static_cast<long long>(row.target_vertices[0]),
                        static_cast<long long>(row.target_vertices[1]), static_cast<long long>(row.target_vertices[2])}) {
      o += ',';
      append_int(o, k);
    }
    for (double x : {row.bary[0], row.bary[1], row.bary[2], row.position[0], row.position[1], row.position[2]}) {
      o += ',';
      append_double(o, x);
    }
    o += '\n';
  }
  return o;
}

}  // namespace brenier::jobs

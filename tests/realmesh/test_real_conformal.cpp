// Conformal maps of every disk-class and sphere-class mesh of data/meshes: converged Newton,
// boundary on the unit circle, and no folded face -- the cases where BFF and CGAL's
// discrete conformal map fold (mannequin-devil, three_peaks, armadillo, camel, man, dino).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>

#include "common/error.hpp"
#include "conformal/conformal_map.hpp"
#include "mesh/geometry.hpp"
#include "mesh/topology.hpp"
#include "mesh/validate.hpp"
#include "distance/distance.hpp"
#include "jobs/jobs.hpp"
#include "omt/area_preserving.hpp"
#include "quality/quality.hpp"
#include "register/evaluation.hpp"

using namespace brenier;
namespace fs = std::filesystem;

namespace {

struct Case {
  std::string name;
  mesh::TriMesh mesh;
};

std::vector<Case> meshes_of_class(mesh::MeshClass cls) {
  std::vector<Case> out;
  for (const auto& e : fs::directory_iterator(BRENIER_TEST_DATA_DIR)) {
    if (!e.is_regular_file() || e.path().filename().string()[0] == '.') continue;
    try {
      mesh::CleanMesh cm = mesh::load_mesh(e.path().string());
      if (cm.valid() && mesh::compute_topology(cm.mesh).mesh_class == cls)
        out.push_back({e.path().filename().string(), std::move(cm.mesh)});
    } catch (const Error&) {
    }
  }
  std::sort(out.begin(), out.end(), [](const Case& a, const Case& b) { return a.name < b.name; });
  return out;
}

// Each named mesh's area-preserving map has mean |log area ratio| below `ratio` times its
// conformal map's (and, when asked, no folded face).
template <class Map>
void expect_area_distortion_below(std::initializer_list<const char*> names, Map map, quality::Target target,
                                  double ratio, bool no_folds = false) {
  for (const char* name : names) {
    SCOPED_TRACE(name);
    mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / name).string());
    ASSERT_TRUE(cm.valid());
    omt::AreaPreservingMap ap = map(cm.mesh);
    auto q = quality::measure(cm.mesh, ap.positions, target);
    auto qc = quality::measure(cm.mesh, ap.conformal.positions, target);
    if (no_folds) {
      EXPECT_EQ(q.flipped_faces, 0);
    }
    EXPECT_LT(q.area_distortion_log_abs.mean, ratio * qc.area_distortion_log_abs.mean)
        << q.area_distortion_log_abs.mean << " vs conformal " << qc.area_distortion_log_abs.mean;
  }
}

// The median normalized geodesic error (registration_errors, 300 samples) of a
// registration's correspondence against its ground-truth pair.
double median_error(const registration::TruthPair& p, const jobs::RegisterOutcome& out) {
  std::vector<registration::SurfacePoint> found;
  for (const auto& [f, w] : out.target_points) found.push_back({f, w});
  std::vector<double> e = registration::registration_errors(p, found, 300);
  std::nth_element(e.begin(), e.begin() + static_cast<long>(e.size() / 2), e.end());
  return e[e.size() / 2];
}

}  // namespace

TEST(RealConformal, EveryDiskMeshMapsOntoTheDiskUnfolded) {
  auto cases = meshes_of_class(mesh::MeshClass::kDisk);
  ASSERT_GE(cases.size(), 20u);
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    conformal::ConformalMap map = conformal::map_to_disk(c.mesh);
    EXPECT_TRUE(map.converged) << map.max_curvature_error;
    EXPECT_LE(map.max_curvature_error, 1e-7);
    EXPECT_EQ(quality::measure(c.mesh, map.positions, quality::Target::kPlane).flipped_faces, 0);
    const auto loops = mesh::boundary_loops(c.mesh);  // (a named copy: [0] of a temporary dangles)
    for (int v : loops[0])
      EXPECT_NEAR(map.positions.row(v).head<2>().norm(), 1.0, 1e-14);
    EXPECT_LE(map.positions.leftCols(2).rowwise().norm().maxCoeff(), 1.0 + 1e-14);
  }
}

TEST(RealConformal, EverySphereMeshMapsOntoTheSphereUnfolded) {
  auto cases = meshes_of_class(mesh::MeshClass::kSphere);
  ASSERT_GE(cases.size(), 40u);
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    conformal::ConformalMap map = conformal::map_to_sphere(c.mesh);
    EXPECT_TRUE(map.converged) << map.max_curvature_error;
    EXPECT_EQ(quality::measure(c.mesh, map.positions, quality::Target::kSphere).flipped_faces, 0);
    EXPECT_EQ(map.folded_faces, 0);
    EXPECT_LT((map.positions.rowwise().norm().array() - 1.0).abs().maxCoeff(), 1e-12);
  }
}

TEST(RealConformal, ClosedMeshesOpenedWithAHoleMapOntoTheDisk) {
  for (const char* name : {"armadillo.off", "camel.off", "man.off", "dino.off", "bunny00.off", "cow.off"}) {
    SCOPED_TRACE(name);
    mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / name).string());
    ASSERT_TRUE(cm.valid());
    mesh::CutHole cut = mesh::cut_hole(cm.mesh);
    conformal::ConformalMap map = conformal::map_to_disk(cut.mesh);
    EXPECT_TRUE(map.converged);
    EXPECT_EQ(quality::measure(cut.mesh, map.positions, quality::Target::kPlane).flipped_faces, 0);
  }
}

TEST(RealAreaPreserving, EveryDiskMeshGetsAnUnfoldedAreaPreservingMap) {
  auto cases = meshes_of_class(mesh::MeshClass::kDisk);
  ASSERT_GE(cases.size(), 20u);
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    omt::AreaPreservingMap ap = omt::area_preserving_disk(c.mesh);
    EXPECT_TRUE(ap.omt.converged) << ap.omt.max_relative_error;
    EXPECT_LE(ap.omt.max_relative_error, 1e-8);
    EXPECT_EQ(ap.omt.cells.empty_cells, 0);
    EXPECT_EQ(quality::measure(c.mesh, ap.positions, quality::Target::kPlane).flipped_faces, 0);
    // Cell masses are the vertex masses (eq. 3.30) scaled to pi.
    Eigen::VectorXd nu = omt::vertex_masses(c.mesh);
    nu *= std::numbers::pi / nu.sum();
    EXPECT_LE(((ap.omt.cells.mass - nu).array().abs() / nu.array()).maxCoeff(), 1e-8);
  }
}

TEST(RealAreaPreserving, TheCoarseToFineStartGivesTheSameMap) {
  // AreaPreservingOptions::multilevel_from: large disk maps start the transport from the
  // coarse levels. The transport's solution is unique (up to a constant height), so the map
  // from that start must be the plain start's, cell for cell, to the mass tolerance.
  mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / "lion-head.off").string());
  ASSERT_TRUE(cm.valid());
  omt::AreaPreservingOptions plain, coarse;
  plain.multilevel_from = 0;
  coarse.multilevel_from = 1000;
  plain.refine.enabled = coarse.refine.enabled = false;
  const omt::AreaPreservingMap a = omt::area_preserving_disk(cm.mesh, plain);
  const omt::AreaPreservingMap b = omt::area_preserving_disk(cm.mesh, coarse);
  EXPECT_EQ(a.omt.levels, 1);
  EXPECT_GT(b.omt.levels, 1) << "the first step from the plain start is damped here: the coarse start is taken";
  ASSERT_TRUE(a.omt.converged && b.omt.converged);
  EXPECT_LE(b.omt.max_relative_error, 1e-8);
  EXPECT_EQ(b.omt.cells.empty_cells, 0);
  EXPECT_LE((a.positions - b.positions).rowwise().norm().maxCoeff(), 1e-6);
  EXPECT_EQ(quality::measure(cm.mesh, b.positions, quality::Target::kPlane).flipped_faces, 0);
}

namespace {

// A mesh's area-preserving map without and with the refinement's reweighted rounds
// (AreaRefineOptions::reweighted_rounds), checked for what the rounds promise: a round's map is
// kept only where it is better, so no statistic gets worse than the stages' (the p95 not beyond
// the tolerance), and the map stays bijective. Returns the two refinements' results.
std::pair<omt::AreaRefinement, omt::AreaRefinement> with_and_without_rounds(const char* name, bool sphere) {
  mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / name).string());
  EXPECT_TRUE(cm.valid());
  omt::AreaPreservingOptions stages_only;
  stages_only.refine.reweighted_rounds = 0;
  auto map = [&](const omt::AreaPreservingOptions& o) {
    return sphere ? omt::area_preserving_sphere(cm.mesh, o) : omt::area_preserving_disk(cm.mesh, o);
  };
  const omt::AreaPreservingMap a = map(stages_only), b = map(omt::AreaPreservingOptions());
  EXPECT_TRUE(a.refinement.ran && b.refinement.ran);
  EXPECT_FALSE(a.refinement.converged) << "a mesh the rounds run on";
  EXPECT_LE(b.refinement.after.mean, a.refinement.after.mean);
  EXPECT_LE(b.refinement.after.max, a.refinement.after.max);
  EXPECT_LE(b.refinement.after.p95, std::max(a.refinement.after.p95, b.refinement.p95_tolerance));
  const quality::MapQuality q =
      quality::measure(cm.mesh, b.positions, sphere ? quality::Target::kSphere : quality::Target::kPlane);
  EXPECT_EQ(q.flipped_faces, 0);
  EXPECT_TRUE(quality::covers_once(q.degree));
  EXPECT_NEAR(q.area_distortion_log_abs.mean, b.refinement.after.mean, 1e-12);
  return {a.refinement, b.refinement};
}

}  // namespace

TEST(RealAreaPreserving, ReweightedRoundsTakeCornerToTheBarAndSetNoMapBack) {
  // On the disk, after the stages: corner_with_sharp_edge, which the stages leave at mean
  // 0.0213, meets issue 26's bar through the rounds (bench/RESULTS.md, session 75); the patches
  // that stay off it keep their maps or better ones.
  for (const char* name : {"corner_with_sharp_edge.off", "patch-13.off", "patch-21.off", "patch-23.off",
                           "mesh_with_colors.off"}) {
    SCOPED_TRACE(name);
    const auto [a, b] = with_and_without_rounds(name, false);
    if (std::string(name) == "corner_with_sharp_edge.off") {
      EXPECT_GT(a.after.mean, 0.02);
      EXPECT_LE(b.after.mean, 0.02);
      EXPECT_LE(b.after.p95, 0.1);
    }
  }
  // On the sphere, after the chord stages: the coarse meshes whose stages stop far above the
  // bar come out better in every statistic (cross 0.0415 -> 0.0282, u 0.1244 -> 0.096); the
  // corner tetrahedron, whose inscribed maps cannot meet its targets, keeps its map.
  for (const char* name : {"cross.off", "cross_quad.off", "u.off", "tetrahedron.off"}) {
    SCOPED_TRACE(name);
    const auto [a, b] = with_and_without_rounds(name, true);
    if (std::string(name) == "tetrahedron.off")
      EXPECT_EQ(b.after.mean, a.after.mean);
    else
      EXPECT_LT(b.after.mean, 0.8 * a.after.mean);
  }
}

TEST(RealAreaPreserving, AreaDistortionFallsFarBelowTheConformalMaps) {
  expect_area_distortion_below(
      {"lion-head.off", "cylinder.off", "cylinder_locally_refined.off", "mannequin-devil.off"},
      [](const mesh::TriMesh& m) { return omt::area_preserving_disk(m); }, quality::Target::kPlane, 0.2);
}

TEST(RealAreaPreserving, EverySphereMeshGetsABijectiveAreaPreservingMap) {
  // Onto the sphere (sec. 3.2.5). Where the conformal sphere map packs neighbouring vertices
  // 1e-10 to 1e-15 apart (bull, camel, cow, dino, diplodocus, man), the transport starts
  // from a spread map instead (area_preserving_sphere). Every returned map has converged
  // masses and reports its folds and covering degree truthfully, and every sphere mesh of
  // data/meshes must map bijectively (2026-11-24, session 10: all 59; man was the last, its
  // spread start torn by Tutte steps between stages). A map that cannot be made must fail
  // with kNotConverged, never come back wrong; that too fails this test.
  // The face-by-face refinement runs, as by default, but capped at 12 Newton steps: every
  // step must keep the map bijective, which this checks; running it to its tolerance on every
  // mesh (armadillo, diplodocus, camel: 14-41 s each) is bench/bench_area_refinement.py's job.
  auto cases = meshes_of_class(mesh::MeshClass::kSphere);
  ASSERT_GE(cases.size(), 50u);
  int unfolded = 0, limit = 0;
  std::string failures;
  omt::AreaPreservingOptions options;
  options.refine.max_iterations = 12;
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    omt::AreaPreservingMap ap;
    try {
      ap = omt::area_preserving_sphere(c.mesh, options);
    } catch (const Error& e) {
      EXPECT_EQ(e.code(), ErrorCode::kNotConverged) << e.what();
      ++limit;
      failures += " " + c.name;
      continue;
    }
    EXPECT_TRUE(ap.omt.converged);
    EXPECT_LE(ap.omt.max_relative_error, 1e-8);
    Eigen::VectorXd nu = omt::vertex_masses(c.mesh);
    nu *= 4 * std::numbers::pi / nu.sum();
    EXPECT_LE(((ap.omt.cells.mass - nu).array().abs() / nu.array()).maxCoeff(), 1e-8);
    const quality::MapQuality q = quality::measure(c.mesh, ap.positions, quality::Target::kSphere);
    EXPECT_EQ(q.flipped_faces, ap.folded_faces);
    EXPECT_NEAR(q.degree, ap.degree, 1e-9);
    EXPECT_NEAR(q.degree, std::round(q.degree), 1e-6) << "a closed surface covers the sphere a whole number of times";
    // A bijection: no face turned inward and the sphere covered once (cactus and u once
    // passed the first test alone, wrapped 4 times around the sphere).
    if (ap.refinement.ran && !ap.refinement.kept_start) {
      EXPECT_LE(ap.refinement.after.mean, ap.refinement.before.mean) << "the refinement made the map worse";
    }
    if (q.flipped_faces == 0 && std::abs(q.degree - 1) < 1e-6)
      ++unfolded;
    else
      failures += " " + c.name + "(" + std::to_string(q.flipped_faces) + " folds, degree " +
                  std::to_string(std::lround(q.degree)) + ")";
  }
  EXPECT_EQ(unfolded, static_cast<int>(cases.size()))
      << "failed:" << failures << " (" << limit << " at the precision limit)";
}

TEST(RealAreaPreserving, SphereAreaDistortionFallsFarBelowTheConformalMaps) {
  expect_area_distortion_below(
      {"bear.off", "bear_bis.off", "ellipe0.003.off", "retinal.off"},
      [](const mesh::TriMesh& m) { return omt::area_preserving_sphere(m); }, quality::Target::kSphere, 0.3,
      /*no_folds=*/true);
}

TEST(RealAreaPreserving, SpreadStartsRefineBelowTheBar) {
  // camel's conformal sphere map packs the legs' vertices 1e-5..1e-4 apart, so its transport
  // starts from a spread map, whose centroid map is off by mean |log area ratio| 0.33 with
  // faces 50x too small or large. Nearly every Newton step of the refinement is then bounded
  // by a few faces about to turn over, at t ~ 0.1-0.3; the steps go to 0.9 of that bound
  // (detail::first_turn_on_sphere) and the default run meets both tolerances, bijective. With
  // the bound found by halving alone it stopped at 0.0141. handle's refinement then stopped at
  // the first step that raised its mean, 0.0215; its stages now wait three steps and keep their
  // best map, and it meets issue 26's bar (mean <= 0.02, p95 <= 0.1; session 55, bench/RESULTS.md).
  // part's and spool's arms stalled the stages begun at theta = 0.999 (0.0456 and 0.0227); from
  // starts as far from their areas as these (0.45, 0.48) the sphere's stages now begin at 0.98
  // and reach the bar (0.0165 and 0.0115; session 56).
  struct Want {
    const char* name;
    bool tolerances;  // the default tolerances (0.01 / 0.05), else the bar
  };
  for (const Want& w : {Want{"camel.off", true}, Want{"handle.off", false}, Want{"part.off", false},
                        Want{"spool.off", false}}) {
    SCOPED_TRACE(w.name);
    mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / w.name).string());
    ASSERT_TRUE(cm.valid());
    const omt::AreaPreservingMap ap = omt::area_preserving_sphere(cm.mesh);
    ASSERT_TRUE(ap.refinement.ran);
    EXPECT_GT(ap.refinement.before.mean, 0.3);
    const double mean = w.tolerances ? 0.01 : 0.02, p95 = w.tolerances ? 0.05 : 0.1;
    EXPECT_LE(ap.refinement.after.mean, mean) << ap.refinement.iterations << " steps";
    EXPECT_LE(ap.refinement.after.p95, p95);
    if (w.tolerances) {
      EXPECT_TRUE(ap.refinement.converged);
    }
    const quality::MapQuality q = quality::measure(cm.mesh, ap.positions, quality::Target::kSphere);
    EXPECT_EQ(q.flipped_faces, 0);
    EXPECT_TRUE(quality::covers_once(q.degree));
  }
}

TEST(RealRegister, BearOntoARemeshedBentCopyByBothRoutesOfTheSphere) {
  // Alg. 7 on the sphere, both routes, against ground truth: bear.off bent and remeshed, six
  // landmarks. Until session 32 the area-preserving route refused every bear pair: its two
  // maps had stereographic poles at unrelated places (they disagreed by 0.37, median chord),
  // and the landmark steps were stopped by slivers of the centroid map. Now the target's pole
  // is the source's carried over (median error 0.0077 measured; the conformal route 0.0066).
  mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / "bear.off").string());
  ASSERT_TRUE(cm.valid());
  const registration::TruthPair p = registration::make_truth_pair(cm.mesh, registration::Deformation::kBend, 0.5, 1.0, 6);
  for (jobs::MapMethod method : {jobs::MapMethod::kAreaPreserving, jobs::MapMethod::kConformal}) {
    SCOPED_TRACE(jobs::map_method_name(method));
    jobs::RegisterRequest r;
    r.domain = jobs::Domain::kSphere;
    r.method = method;
    r.source_landmarks = p.source_landmarks;
    r.target_landmarks = p.target_landmarks;
    const jobs::RegisterOutcome out = jobs::run_register(mesh::clean(p.source), mesh::clean(p.target), "source", "target", r, 2);
    EXPECT_EQ(out.report["domain_folded_faces"], 0);
    EXPECT_LT(out.report["match"]["max_landmark_error"].get<double>(), 1e-9);
    EXPECT_LT(median_error(p, out), 0.012);
  }
}

TEST(RealRegister, CowOntoAStretchedRemeshedCopyByTheSpheresAreaPreservingRoute) {
  // cow's conformal sphere map crowds its legs, and until session 68 every pair of its
  // area-preserving domains was refused: a long thin centroid face between two landmarks was
  // squeezed flat by the landmark steps at any step length. The steps now let faces that become
  // slivers on the way turn, and mend them afterwards with the landmarks held (the match
  // reports both). Stretched by 20 % and remeshed, six landmarks: no fold, the landmarks hit,
  // and with the sphere's isometric refinement the OMT route errs far less than the conformal
  // route, whose maps differ where the stretch is not conformal (measured 0.0212 against
  // 0.0645, g alone 0.0386 against 0.0738, bench/RESULTS.md, session 68; after session 69's
  // faster fold repair 0.0234, g alone 0.0384). Since session 70 the centroid maps' local
  // moves no longer throw vertices across the sphere, and this pair's steps need no sliver
  // let turn (g alone 0.0360, 7 faces mended); DomainMatch.ASliverInTheDomainMeshDoesNotBlock
  // TheLandmarks covers that rule.
  mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / "cow.off").string());
  ASSERT_TRUE(cm.valid());
  const registration::TruthPair p = registration::make_truth_pair(cm.mesh, registration::Deformation::kStretch, 0.2, 1.0, 6);
  auto route_median = [&](jobs::MapMethod method, bool refined, nlohmann::json& report) {
    jobs::RegisterRequest r;
    r.domain = jobs::Domain::kSphere;
    r.method = method;
    r.source_landmarks = p.source_landmarks;
    r.target_landmarks = p.target_landmarks;
    r.isometric = refined;
    r.isometric_sphere = refined && method == jobs::MapMethod::kConformal;
    const jobs::RegisterOutcome out = jobs::run_register(mesh::clean(p.source), mesh::clean(p.target), "source", "target", r, 2);
    report = out.report;
    return median_error(p, out);
  };
  nlohmann::json g_alone, refined, conformal;
  const double omt_g = route_median(jobs::MapMethod::kAreaPreserving, false, g_alone);
  EXPECT_GT(g_alone["match"]["mended_faces"].get<int>(), 0);
  EXPECT_EQ(g_alone["domain_folded_faces"], 0);
  EXPECT_LT(g_alone["match"]["max_landmark_error"].get<double>(), 1e-9);
  EXPECT_LT(omt_g, 0.05);
  const double omt = route_median(jobs::MapMethod::kAreaPreserving, true, refined);
  EXPECT_EQ(refined["domain_folded_faces"], 0);
  EXPECT_LT(refined["isometric"]["energy_after"].get<double>(), refined["isometric"]["energy_before"].get<double>());
  EXPECT_LT(omt, 0.03) << "g alone " << omt_g;
  const double conf = route_median(jobs::MapMethod::kConformal, true, conformal);
  EXPECT_LT(omt, 0.6 * conf);
}

TEST(RealRegister, DinoOntoATwistedRemeshedCopyByTheSpheresAreaPreservingRoute) {
  // dino's OMT route was refused before session 69: the source's centroid map kept one fold
  // after its repair, and a registration takes no folded map. With the fold repair's rounds
  // stopping once the energy stalls (fold_repair.cpp) its maps come out bijective, and every
  // pair answers (bench/RESULTS.md, session 69). Twisted and remeshed, six landmarks: both
  // maps and g without a fold, the landmarks hit, and errors of the pair's order (measured
  // median 0.0357; the conformal route's is 0.0153: dino's legs crowd the centroid maps).
  mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / "dino.off").string());
  ASSERT_TRUE(cm.valid());
  const registration::TruthPair p = registration::make_truth_pair(cm.mesh, registration::Deformation::kTwist, 0.3, 1.0, 6);
  jobs::RegisterRequest r;
  r.domain = jobs::Domain::kSphere;
  r.method = jobs::MapMethod::kAreaPreserving;
  r.source_landmarks = p.source_landmarks;
  r.target_landmarks = p.target_landmarks;
  const jobs::RegisterOutcome out = jobs::run_register(mesh::clean(p.source), mesh::clean(p.target), "source", "target", r, 2);
  for (const char* side : {"source", "target"}) {
    EXPECT_EQ(out.report[side]["quality"]["flipped_faces"], 0) << side;
    EXPECT_GT(out.report[side]["omt"]["spreading_stages"].get<int>(), 0) << side << ": dino's legs are crowded";
  }
  EXPECT_EQ(out.report["domain_folded_faces"], 0);
  EXPECT_LT(out.report["match"]["max_landmark_error"].get<double>(), 1e-9);
  EXPECT_LT(median_error(p, out), 0.05);
}

TEST(RealRegister, LionHeadOntoATwistedRemeshedCopyIsRefinedTowardTheIsometry) {
  // Alg. 7 on the disk, conformal route, against ground truth: lion-head twisted by +-27
  // degrees at its ends and remeshed, six landmarks. g alone erred by 0.0215 (median,
  // geodesic over sqrt(area), session 24): the two conformal maps differ where the twist
  // stretches the flanks. The isometric refinement must lower the median below the issue's
  // 0.02 and clearly below g's own, turn no face over in the domain and hit the landmarks
  // (measured 0.0128 against 0.0215, bench/RESULTS.md, session 65).
  mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / "lion-head.off").string());
  ASSERT_TRUE(cm.valid());
  const registration::TruthPair p = registration::make_truth_pair(cm.mesh, registration::Deformation::kTwist, 0.3, 1.0, 6);
  double median[2] = {0, 0};
  for (bool isometric : {false, true}) {
    jobs::RegisterRequest r;
    r.method = jobs::MapMethod::kConformal;
    r.source_landmarks = p.source_landmarks;
    r.target_landmarks = p.target_landmarks;
    r.isometric = isometric;
    const jobs::RegisterOutcome out = jobs::run_register(mesh::clean(p.source), mesh::clean(p.target), "source", "target", r, 2);
    EXPECT_EQ(out.report["domain_folded_faces"], 0);
    EXPECT_LT(out.report["match"]["max_landmark_error"].get<double>(), 1e-9);
    EXPECT_EQ(out.report["isometric"]["applied"].get<bool>(), isometric);
    if (isometric) {
      EXPECT_LT(out.report["isometric"]["energy_after"].get<double>(), out.report["isometric"]["energy_before"].get<double>());
    }
    median[isometric] = median_error(p, out);
  }
  EXPECT_LT(median[1], 0.02) << "g alone: " << median[0];
  EXPECT_LT(median[1], 0.8 * median[0]);
}

TEST(RealDistance, EachDiskMeshIsNearestItsOwnBentRemeshedCopy) {
  // Issue 23's matrix property on the disk, in small: three real disk meshes and a bent,
  // independently remeshed copy of each (register/evaluation's ground-truth copies). Every
  // exact pair converges, and each mesh is nearer its own copy than any other mesh.
  const char* const names[] = {"lion-head.off", "mannequin-devil.off", "cylinder_locally_refined.off"};
  std::vector<distance::Shape> shapes, copies;
  for (const char* name : names) {
    mesh::CleanMesh cm = mesh::load_mesh((fs::path(BRENIER_TEST_DATA_DIR) / name).string());
    ASSERT_TRUE(cm.valid()) << name;
    const registration::TruthPair p = registration::make_truth_pair(cm.mesh, registration::Deformation::kBend, 0.5, 1.0, 4);
    for (auto [m, to] : {std::pair{&p.source, &shapes}, std::pair{&p.target, &copies}}) {
      const distance::ShapeInput in = jobs::shape_input(mesh::clean(*m), name, name, jobs::ShapeRequest{});
      to->push_back(distance::prepare_shape(in.mesh, in.name, in.options));
    }
  }
  distance::WassersteinOptions o;
  o.parallel_directions = true;
  auto exact = [&](const distance::Shape& a, const distance::Shape& b) {
    const distance::PairResult r = distance::wasserstein(a, b, o);
    EXPECT_TRUE(r.converged) << a.name << " x " << b.name;
    return r.distance;
  };
  for (size_t i = 0; i < shapes.size(); ++i) {
    const double own = exact(shapes[i], copies[i]);
    for (size_t j = 0; j < shapes.size(); ++j) {
      if (j != i) {
        EXPECT_LT(own, exact(shapes[i], shapes[j])) << names[i] << " and " << names[j];
      }
    }
    std::printf("%s x its copy: %.5f\n", names[i], own);
  }
}

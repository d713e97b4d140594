// brenier-compute omt-bench: the semi-discrete OT solver on synthetic problems (issue 4's
// benchmark): the uniform disk or square to N random sites, uniform in the domain, with
// equal masses or masses proportional to exp(-8 |p|^2) (ratio about 3000 on the disk).
// --start says where the Newton iterations start (OmtOptions::multilevel, multilevel_probe):
//   coarse (the default): the coarse-to-fine start wherever Alg. 2's Voronoi start leaves a
//     cell 10x off its target, as the area-preserving maps take it; so the benchmark times the
//     transport users get. Equal masses never trigger it (1M sites: one level, 6 iterations).
//   probe: that start only where the plain start's first Newton step is damped below 1/4,
//     as the distances take it;
//   plain: the seed's Alg. 2 alone (the default before session 79).
// --multilevel [--no-probe], the flags before --start, still mean probe [coarse].
// Gaussian masses, 2 cores (bench/RESULTS.md, session 79): 10K 0.19 -> 0.165 s, 100K 2.66 ->
// 2.25 s, the square's 100K 5.4 -> 2.9 s, plain against coarse. BENCH_TRACE=1 in the environment
// prints each Newton iteration's error and clock time to stderr (as bench_pair does).
#include <sys/resource.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <random>

#include "commands.hpp"
#include "request_flags.hpp"
#include "common/error.hpp"
#include "omt/omt.hpp"

namespace brenier::tools {
namespace {

struct BenchOptions {
  std::string domain = "disk";
  int sites = 10000;
  std::string masses = "gaussian";
  unsigned seed = 1;
  double tolerance = 1e-8;
  bool json = false;
  std::string start = "coarse";              // coarse, probe or plain; the older flags set it at parse time
  bool multilevel = false, no_probe = false;  // the flags before --start, read only by the callback
};

int run_bench(const BenchOptions& o) {
  const omt::Domain domain = o.domain == "disk" ? omt::Domain::unit_disk() : omt::Domain::square(1.0);
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  omt::Points y(o.sites, 2);
  for (int k = 0; k < o.sites;) {
    double a = U(rng), b = U(rng);
    if (domain.contains(a, b)) y.row(k++) << a, b;
  }
  Eigen::VectorXd nu(o.sites);
  for (int i = 0; i < o.sites; ++i) nu[i] = o.masses == "equal" ? 1.0 : std::exp(-8 * y.row(i).squaredNorm());
  omt::OmtOptions opt;
  opt.tolerance = o.tolerance;
  const std::string& start = o.start;
  opt.multilevel = start != "plain";
  opt.multilevel_probe = start == "probe";
  auto t0 = std::chrono::steady_clock::now();
  if (std::getenv("BENCH_TRACE"))
    opt.progress = [t0](int it, double e) {
      std::fprintf(stderr, "%9.3f s  iteration %3d  error %.3e\n",
                   std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), it, e);
      return true;
    };
  omt::OmtResult r = omt::solve_omt(domain, y, nu, opt);
  double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  struct rusage ru {};
  getrusage(RUSAGE_SELF, &ru);
  nlohmann::json j = {{"domain", o.domain},
                      {"sites", o.sites},
                      {"masses", o.masses},
                      {"seed", o.seed},
                      {"seconds", secs},
                      {"newton_iterations", r.iterations},
                      {"max_relative_area_error", r.max_relative_error},
                      {"converged", r.converged},
                      {"empty_cells", r.cells.empty_cells},
                      {"factorizations", r.factorizations},
                      {"start", start},
                      {"multilevel", opt.multilevel},
                      {"levels", r.levels},
                      {"linear_iterations", r.linear_iterations},
                      {"mass_ratio", r.target.maxCoeff() / r.target.minCoeff()},
                      {"peak_rss_mb", ru.ru_maxrss / 1024.0}};
  if (o.json)
    std::cout << j.dump(2) << std::endl;
  else
    std::printf("%s, %d sites, %s masses, %s start (%d levels): %.3f s, %d Newton iterations, "
                "max relative error %.2e, %d empty, %.0f MB\n",
                o.domain.c_str(), o.sites, o.masses.c_str(), start.c_str(), r.levels, secs, r.iterations,
                r.max_relative_error, r.cells.empty_cells, ru.ru_maxrss / 1024.0);
  return r.converged ? kExitOk : kExitNotConverged;
}

}  // namespace

void add_omt_bench(CLI::App& app, Action& action) {
  auto o = std::make_shared<BenchOptions>();
  CLI::App* cmd = app.add_subcommand("omt-bench", "time the OT solver on random sites (benchmark)");
  cmd->add_option("--domain", o->domain, "disk or square")->check(CLI::IsMember({"disk", "square"}));
  cmd->add_option("--sites", o->sites, "number of sites")->check(CLI::Range(1, 50000000));
  cmd->add_option("--masses", o->masses, "equal or gaussian (exp(-8|p|^2))")->check(CLI::IsMember({"equal", "gaussian"}));
  cmd->add_option("--seed", o->seed, "random seed");
  cmd->add_option("--tolerance", o->tolerance, "max relative cell-mass error")->check(options::positive_number());
  cmd->add_option("--start", o->start,
                  "coarse (coarse-to-fine where the Voronoi start is 10x off, as maps use; default), "
                  "probe (only where the plain start's first step is damped, as distances use) or plain (Alg. 2)")
      ->check(CLI::IsMember({"coarse", "probe", "plain"}));
  // The flags before --start: --multilevel is probe, with --no-probe coarse.
  auto* ml = cmd->add_flag("--multilevel", o->multilevel, "the same as --start probe")->group("Older flags");
  cmd->add_flag("--no-probe", o->no_probe, "with --multilevel: the same as --start coarse")
      ->group("Older flags")
      ->needs(ml);
  cmd->get_option("--start")->excludes(ml);
  cmd->add_flag("--json", o->json, "print one JSON object");
  cmd->callback([o, &action] {
    if (o->multilevel) o->start = o->no_probe ? "coarse" : "probe";
    action = [o] { return run_bench(*o); };
  });
}

}  // namespace brenier::tools

// brenier-compute omt-bench: the semi-discrete OT solver on synthetic problems (issue 4's
// benchmark): the uniform disk or square to N random sites, uniform in the domain, with
// equal masses or masses proportional to exp(-8 |p|^2) (ratio about 3000 on the disk).
// --multilevel times the coarse-to-fine start (with the plain start's probe, or without it:
// --no-probe) on the same problem. BENCH_TRACE=1 in the environment prints each Newton
// iteration's error and clock time to stderr (as bench_pair does).
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
  bool multilevel = false, probe = true;
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
  opt.multilevel = o.multilevel;
  opt.multilevel_probe = o.probe;
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
                     {"multilevel", o.multilevel},
                     {"levels", r.levels},
                      {"linear_iterations", r.linear_iterations},
                      {"mass_ratio", r.target.maxCoeff() / r.target.minCoeff()},
                      {"peak_rss_mb", ru.ru_maxrss / 1024.0}};
  if (o.json)
    std::cout << j.dump(2) << std::endl;
  else
    std::printf("%s, %d sites, %s masses: %.3f s, %d Newton iterations, max relative error %.2e, %d empty, %.0f MB\n",
                o.domain.c_str(), o.sites, o.masses.c_str(), secs, r.iterations, r.max_relative_error,
                r.cells.empty_cells, ru.ru_maxrss / 1024.0);
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
  cmd->add_flag("--multilevel", o->multilevel, "coarse-to-fine start (as the maps and distances use)");
  cmd->add_flag("--no-probe{false}", o->probe, "with --multilevel: take the coarse start without probing the plain one");
  cmd->add_flag("--json", o->json, "print one JSON object");
  cmd->callback([o, &action] { action = [o] { return run_bench(*o); }; });
}

}  // namespace brenier::tools

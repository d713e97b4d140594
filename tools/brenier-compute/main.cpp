// brenier-compute: the brenier engine on local files (see DESIGN.md, "Executables").
#include <cstdio>
#include <exception>
#include <iostream>
#include <new>
#include <string>

#include "commands.hpp"
#include "common/error.hpp"
#include "common/parallel.hpp"
#include "process.hpp"

namespace {

// The one place where errors become an exit code and one line on stderr.
int report(const char* kind, const std::string& message, int code) {
  std::string line = message;
  for (char& c : line)
    if (c == '\n' || c == '\r') c = ' ';
  std::fprintf(stderr, "brenier-compute: %s%s\n", kind, line.c_str());
  return code;
}

int exit_code_for(brenier::ErrorCode code) {
  using brenier::ErrorCode;
  switch (code) {
    case ErrorCode::kInvalidArgument:
    case ErrorCode::kNotFound:
    case ErrorCode::kResourceExhausted:
    case ErrorCode::kFailedPrecondition:
      return brenier::tools::kExitBadInput;
    case ErrorCode::kNotConverged:
      return brenier::tools::kExitNotConverged;
    default:
      return brenier::tools::kExitFailure;
  }
}

}  // namespace

int main(int argc, char** argv) {
  brenier::process::reexec_with_runtime_settings(argv);
  brenier::process::tune_allocator(brenier::process::Lifetime::kOneShot);
  CLI::App app{"brenier-compute: conformal and optimal-mass-transport maps of surfaces"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "brenier-compute 0.1.0");
  brenier::tools::Action action;
  brenier::tools::add_inspect(app, action);
  brenier::tools::add_map(app, action);
  brenier::tools::add_omt_bench(app, action);
  brenier::tools::add_distance(app, action);
  brenier::tools::add_render(app, action);
  brenier::tools::add_register(app, action);
  brenier::tools::add_omt_surface(app, action);
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    return report("usage: ", e.what(), brenier::tools::kExitBadInput);
  }
  try {
    return action ? action() : brenier::tools::kExitOk;
  } catch (const brenier::Error& e) {
    const char* kind = e.code() == brenier::ErrorCode::kInternal ? "internal error: " : "";
    return report(kind, brenier::name_options(e.what(), brenier::OptionStyle::kFlag), exit_code_for(e.code()));
  } catch (const std::bad_alloc&) {
    return report("", "out of memory", brenier::tools::kExitFailure);
  } catch (const std::exception& e) {
    return report("internal error: ", e.what(), brenier::tools::kExitFailure);
  }
}

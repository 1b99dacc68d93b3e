// `formloop regress [--parts DIR] [--goldens DIR] [--out DIR] [--only A,B] [--update]`: the reference parts
// through the pipeline with the virtual machine, compared with their goldens (app/regress.h). Prints a
// table on stderr and the JSON result on stdout; exit code 1 on any regression, or when fewer than 90 %
// of the parts end within tolerance after at most one compensation loop.

#include <iostream>
#include <memory>

#include <fmt/format.h>

#include "app/command.h"
#include "app/regress.h"
#include "core/log.h"
#include "retrieval/starter.h"

namespace formloop::app {
namespace {

std::string Number(const nlohmann::json& j, const char* format = "{:.3f}") {
  return j.is_number() ? fmt::format(fmt::runtime(format), j.get<double>()) : "-";
}

void PrintTable(const RegressResult& r) {
  std::cerr << fmt::format("{:<16} {:<11} {:>6} {:<9} {:<40} {:<24} {:>5}\n", "part", "status", "A", "route",
                           "form error per cycle (um)", "causes", "loops");
  for (const auto& row : r.table) {
    const nlohmann::json f = row.value("figures", nlohmann::json::object());
    std::string errors, causes;
    for (const auto& e : f.value("form_error_um", nlohmann::json::array()))
      errors += (errors.empty() ? "" : " -> ") + Number(e, "{:.1f}");
    for (const auto& c : f.value("causes", nlohmann::json::array()))
      causes += (causes.empty() ? "" : ",") + c.get<std::string>();
    std::cerr << fmt::format("{:<16} {:<11} {:>6} {:<9} {:<40} {:<24} {:>5}\n", row.value("part", "?"),
                             row.value("status", "?"), Number(f.value("similarity", nlohmann::json())),
                             f.value("route", "-"), errors, causes,
                             f.contains("loops_to_tolerance") && f["loops_to_tolerance"].is_number()
                                 ? std::to_string(f["loops_to_tolerance"].get<int>())
                                 : "-");
    if (row.contains("truth") && row["truth"].contains("true_effects")) {
      const nlohmann::json& t = row["truth"];
      auto names = [](const nlohmann::json& list) {
        std::string out;
        for (const auto& x : list) out += (out.empty() ? "" : ",") + (x.is_string() ? x.get<std::string>() : x.dump());
        return out.empty() ? std::string("-") : out;
      };
      std::cerr << fmt::format(
          "    truth: machine has {}; named not in it: {}; true effects not found: {}; named "
          "parameters outside their 95% interval: {}/{}\n",
          names(t["true_effects"]), names(t["named_not_in_profile"]), names(t["true_missed"]),
          t["parameters_outside"].size(), t["parameters"].get<int>());
    }
    for (const auto& d : row.value("differences", nlohmann::json::array())) {
      std::cerr << fmt::format("    {}: golden {} now {} (allowed {})\n", d["figure"].get<std::string>(),
                               d["golden"].dump(), d["value"].dump(), d["allowed"].get<std::string>());
    }
    for (const auto& d : row.value("changes", nlohmann::json::array())) {
      std::cerr << fmt::format("    updated {}: {} -> {}\n", d["figure"].get<std::string>(), d["golden"].dump(),
                               d["value"].dump());
    }
  }
  std::cerr << fmt::format("within tolerance after at most one compensation loop: {}/{}; regressions: {}\n",
                           r.within_one_loop, r.parts, r.regressions);
  std::cerr << fmt::format(
      "truth (against the machine profiles, not a golden): effects named that the machine lacks: "
      "{}; true effects neither named, in an alias group nor in the baseline: {}/{}; named "
      "parameters outside their 95% interval: {}/{}\n",
      r.named_not_in_profile, r.true_missed, r.true_effects, r.parameters_outside, r.parameters);
}

}  // namespace

void AddRegressCommand(CLI::App& root, CommandAction* action) {
  struct Args {
    std::string parts, goldens, out = "runs/regress";
    std::vector<std::string> only;
    bool update = false;
  };
  auto args = std::make_shared<Args>();
  CLI::App* cmd = root.add_subcommand(
      "regress",
      "Regression run: every reference part (data/regress/parts) through the pipeline with its virtual machine and "
      "one case library started from the starter library; key figures (A and route, fit, scallop, Moran z, causes, "
      "form error per cycle, loops to tolerance) compared with the goldens. Exit code 1 on a regression.");
  cmd->add_option("--parts", args->parts, "folder of reference parts (default data/regress/parts)");
  cmd->add_option("--goldens", args->goldens, "folder of goldens (default data/regress/goldens)");
  cmd->add_option("--out,-o", args->out, "folder for the run folders and the library (replaced)")
      ->capture_default_str();
  cmd->add_option("--only", args->only, "only these parts (names)")->delimiter(',');
  cmd->add_flag("--update", args->update, "rewrite the goldens with this run's figures and print what changed");
  cmd->callback([args, action] {
    *action = [args]() -> Status {
      const std::filesystem::path data = retrieval::DefaultDataDir();
      RegressOptions options;
      options.parts = args->parts.empty() ? data / "regress" / "parts" : std::filesystem::path(args->parts);
      options.goldens = args->goldens.empty() ? data / "regress" / "goldens" : std::filesystem::path(args->goldens);
      options.out = args->out;
      options.only = args->only;
      options.update = args->update;
      FL_ASSIGN_OR_RETURN(RegressResult result, RunRegress(options));
      PrintTable(result);
      std::cout << result.ToJson().dump(2) << std::endl;
      if (result.regressions > 0 && !args->update) {
        return Status::Failed(std::to_string(result.regressions) + " part(s) regressed (table above)");
      }
      if (result.parts > 0 && result.within_one_loop * 10 < result.parts * 9) {
        return Status::Failed(
            fmt::format("only {}/{} parts within tolerance after at most one compensation loop "
                        "(required: 90 %)",
                        result.within_one_loop, result.parts));
      }
      return Status::Ok();
    };
  });
}

}  // namespace formloop::app

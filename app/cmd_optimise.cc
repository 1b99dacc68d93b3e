// `formloop optimise cutting|feed|program`: thin CLI over app/optimise_jobs.h.

#include <iostream>
#include <memory>

#include "app/command.h"
#include "app/optimise_jobs.h"

namespace formloop::app {
namespace {

void AddOutput(CLI::App* cmd, OptimiseOutput* output, bool required) {
  CLI::Option* out = cmd->add_option("--out", output->out, "output folder (written whole or not at all)");
  if (required) out->required();
  cmd->add_flag("--force", output->force, "replace an earlier `formloop optimise` folder at --out");
}

template <typename Args, typename Run>
void SetAction(CLI::App* cmd, std::shared_ptr<Args> args, CommandAction* action, Run run) {
  cmd->callback([args, action, run] {
    *action = [args, run]() -> Status {
      FL_ASSIGN_OR_RETURN(const nlohmann::json out, run(*args));
      std::cout << out.dump(2) << std::endl;
      return Status::Ok();
    };
  });
}

}  // namespace

void AddOptimiseCommand(CLI::App& root, CommandAction* action) {
  CLI::App* optimise = root.add_subcommand(
      "optimise",
      "Process optimisation (spec/process-optimization.md): cutting parameters by the adaptive GA, fuzzy "
      "feed control on spindle current, NC blocks adjusted from inspection.");
  optimise->require_subcommand(1);

  auto cutting = std::make_shared<OptimiseCuttingArgs>();
  CLI::App* c = optimise->add_subcommand(
      "cutting",
      "Level 1: the metal-removal-rate optimum under tool-life (Taylor), speed, feed, force and power limits by the "
      "adaptive GA, fused with recommended cutting data. One cut (--a-p-mm, --a-e-mm): the GA next to the exact "
      "optimum and the Taylor tool lives. A program (--program with --engagement or --stock): the per-block "
      "depth-of-cut check (refused with the blocks named), then the optimum written into its F and S words.");
  c->add_option("--coefficients", cutting->coefficients,
                "COEFFS.json: tool, material, Taylor and force laws, machine "
                "(data/cutting/s1.json)")
      ->required();
  c->add_option("--a-p-mm", cutting->a_p_mm, "axial depth of cut of one cut");
  c->add_option("--a-e-mm", cutting->a_e_mm, "radial depth of cut of one cut");
  c->add_option("--program", cutting->program, "a program to re-optimise (formloop word-address)");
  c->add_option("--dialect", cutting->dialect, "its dialect")->default_val("linuxcnc");
  c->add_option("--engagement", cutting->engagement,
                "ENGAGEMENT.json: {\"blocks\": [{\"block\", \"a_p_mm\", "
                "\"a_e_mm\"}]} per cutting block");
  c->add_option("--stock", cutting->stock, "STOCK.json: the stock the program cuts (engagement by a Z-map)");
  c->add_option("--cutting-data", cutting->cutting_data, "recommended cutting data: JSON array of records");
  c->add_option("--library", cutting->library, "case library whose case --case keeps manufacturing.cutting_data");
  c->add_option("--case", cutting->case_uid, "uid of that case");
  c->add_option("--model-credibility", cutting->model_credibility,
                "c_model of the fusion (0.3 uncalibrated, 1 calibrated on Level-2 logs)")
      ->default_val(0.3)
      ->check(CLI::Range(0.0, 1.0));
  c->add_option("--seed", cutting->seed, "GA seed")->default_val(1);
  AddOutput(c, &cutting->output, false);
  SetAction(c, cutting, action, RunOptimiseCutting);

  auto feed = std::make_shared<OptimiseFeedArgs>();
  CLI::App* f = optimise->add_subcommand(
      "feed",
      "Level 2: fuzzy feed control (fuzzylite) in closed loop with the spindle-current plant along a program's "
      "engagement, next to the conservative constant feed; writes feed.csv, feed.png (current and feed over time), "
      "report.html and optimise.json.");
  f->add_option("--program", feed->program, "the program whose feed moves cut the stock");
  f->add_option("--dialect", feed->dialect, "its dialect")->default_val("linuxcnc");
  f->add_option("--stock", feed->stock, "STOCK.json: the stock it cuts");
  f->add_option("--scenario", feed->scenario, "wall-step: formloop's own raster over a stepped wall instead");
  f->add_option("--seed", feed->noise_seed, "current-measurement noise seed")->default_val(1);
  AddOutput(f, &feed->output, true);
  SetAction(f, feed, action, RunOptimiseFeed);

  auto program = std::make_shared<OptimiseProgramArgs>();
  CLI::App* p = optimise->add_subcommand(
      "program",
      "Level 3: map the out-of-tolerance regions of an inspection back to the NC blocks that cut them and adjust "
      "those blocks (normal offsets, or a feed reduction where the error follows the load); writes the adjusted "
      "program, adjustment.json and optimise.json and appends the inspection record to --log.");
  p->add_option("--run", program->run, "the `formloop run` folder that made the part (nominal Q, tool, tolerance)");
  p->add_option("--surface", program->surface, "without --run: the nominal surface Q.step");
  p->add_option("--ball-radius-mm", program->ball_radius_mm, "ball radius of the tool (default: the run's)");
  p->add_option("--dialect", program->dialect, "without --run: the program's dialect")->default_val("linuxcnc");
  p->add_option("--program", program->program, "the program that cut the part (default: the run's toolpath/program)");
  p->add_option("--inspection", program->inspection,
                "deviations.csv of the inspection (default: the run's loop-0/deviations.csv)");
  p->add_option("--load", program->load, "LOAD.json: load per block {\"N120\": ...}, e.g. from Level 2");
  p->add_option("--log", program->log, "inspection log (JSON Lines) to append the record to");
  p->add_option("--tolerance-mm", program->tolerance_mm, "profile tolerance t_p (default: the part's tolerance)");
  p->add_option("--inspection-id", program->inspection_id, "id of this inspection in the log");
  p->add_option("--part-id", program->part_id, "part id (default: the part's name)");
  p->add_option("--operation-id", program->operation_id, "operation id (default: the program's file name)");
  p->add_option("--probe-calibration-id", program->probe_calibration_id, "the probe calibration used");
  AddOutput(p, &program->output, true);
  SetAction(p, program, action, RunOptimiseProgram);
}

}  // namespace formloop::app

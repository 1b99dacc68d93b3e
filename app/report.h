#pragma once
// The per-run report: one self-contained report.html for a process engineer (issues 8, 27).
//
// Reads a run folder written by `formloop run` (and the optional files of `retrieve`, `diagnose`,
// simulation correction and retain), or a folder written by `formloop analyse` (analysis.json and
// deviations.csv: one cycle, drawn like a run's loop 0, without the run-only sections), and renders: the verdict,
// the part in 3-D coloured by deviation (three.js from Debian's libjs-three inlined, orbit/zoom/pan, probe values
// on hover, the tool path as an overlay; a static SVG projection for print), the loop history with what the next
// cycle cuts, deviation maps (the interpolated systematic field, one colour scale for every map and the 3-D view),
// the spatial analysis, the diagnosis (causes with share and interval, look-alikes, alias groups and what would
// separate them, the residual and the held-out gain), retrieval, plan, simulation correction and retain as
// labelled tables with units. Charts are inline SVG with real text (app/report_svg.h); CSS and scripts are inline;
// nothing is fetched from a network. A small script records in <body data-*> what rendered (charts, their
// rasters, the 3-D canvas, elements wider than the window, script errors) so a headless browser can check it.
//
// Run folder (extra keys are ignored):
//   summary.json                     required: part, surface, tolerance_um, loops[], verdict, route (optional)
//   retrieval.json, plan.json, sim_correction.json, retain.json      optional
//   loop-K/deviations.csv            per loop: the per-point table of metrology/probe_log_analysis.h
//                                    (x, y, z, deviation_um, systematic_um, random_um, lag_um, lisa_cluster
//                                    0..5; "lisa" in folders written before it)
//   loop-K/analysis.json             raw_moran {I, z_normality, ...}, chosen_model, decision
//   loop-K/machine.json              machine (a "virtual..." machine cuts every cycle from a new blank)
//   loop-0/diagnosis/diagnosis.json  optional: causes, confounded, unexplained, gain; alias_groups, implausible,
//                                    proposals and causes' interval_95 when the diagnosis writes them
//   loop-0/diagnosis/model.json      optional: the learned model (its alias_groups when diagnosis.json has none)
//   toolpath/toolpath.csv            optional: the cut moves for the 3-D overlay
// A missing or unreadable optional file leaves its section saying "not available" and why.
//
// The output is byte-deterministic: no timestamps, numbers formatted without the locale, JSON
// members in key order. Needs three.min.js and OrbitControls.js of libjs-three (NotFound naming the
// package when they are missing).

#include <filesystem>
#include <string>

#include "core/status.h"

namespace formloop::app {

// The report's HTML. BadInput naming summary.json when it is missing or malformed.
Result<std::string> RenderRunReport(const std::filesystem::path& run_dir);

// RenderRunReport written atomically to html_path; on error nothing is written.
Status WriteRunReport(const std::filesystem::path& run_dir, const std::filesystem::path& html_path);

// The plant overview of a folder of run folders (a batch run of `formloop run`, or `formloop regress`'s
// output): one table row per part (route, similarity, first-cycle and final form error, machined cycles,
// verdict, causes) linking <part>/report.html. Parts are the sub-folders holding summary.json, in name
// order, plus the failed parts batch_summary.json names. BadInput naming DIR when it holds none.
Result<std::string> RenderBatchOverview(const std::filesystem::path& dir);
Status WriteBatchOverview(const std::filesystem::path& dir, const std::filesystem::path& html_path);

}  // namespace formloop::app

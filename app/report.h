#pragma once
// The per-run report: one self-contained report.html for a process engineer (issue 8).
//
// Reads a run folder written by `formloop run` (and the optional files of `retrieve`, `diagnose`,
// simulation correction and retain), or a folder written by `formloop analyse` (analysis.json and
// deviations.csv: one cycle, drawn like a run's loop 0, without the run-only sections), and renders: the verdict,
// retrieval, plan, simulation correction, loop history, deviations before/after, spatial analysis, diagnosis and
// retain. Pictures are PNGs drawn by app/report_charts.h and embedded as data: URIs; CSS is inline; the only script is
// a few lines that record in <body data-images-loaded="loaded/total"> how many pictures decoded, so a
// headless browser can check the file. Nothing is fetched from a network.
//
// Run folder (extra keys are ignored):
//   summary.json                     required: part, surface, tolerance_um, loops[], verdict, route (optional)
//   retrieval.json, plan.json, sim_correction.json, retain.json      optional
//   loop-K/deviations.csv            per loop: the per-point table of metrology/probe_log_analysis.h
//                                    (x, y, deviation_um, systematic_um, random_um, lag_um, lisa_cluster
//                                    0..5; "lisa" in folders written before it)
//   loop-K/analysis.json             raw_moran {I, z_normality, ...}, chosen_model, decision
//   loop-0/diagnosis/diagnosis.json  optional: causes, unexplained, gain
// A missing or unreadable optional file leaves its section saying "not available".
//
// The output is byte-deterministic: no timestamps, numbers formatted without the locale, JSON
// members in key order.

#include <filesystem>
#include <string>

#include "core/status.h"

namespace formloop::app {

// The report's HTML. BadInput naming summary.json when it is missing or malformed.
Result<std::string> RenderRunReport(const std::filesystem::path& run_dir);

// RenderRunReport written atomically to html_path; on error nothing is written.
Status WriteRunReport(const std::filesystem::path& run_dir, const std::filesystem::path& html_path);

}  // namespace formloop::app

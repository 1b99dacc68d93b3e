#pragma once
// The sections of the run report (app/report.h) that live outside report.cc, each appending its
// <section> to `html`. Internal to app/report*.cc.

#include <string>

#include "app/report_html.h"
#include "core/status.h"

namespace formloop::app::report {

// report_tables.cc: the plan, the simulation correction, the retained case and the diagnosis as labelled
// tables with units.
void PlanSection(std::string& html, const RunData& run);
void SimCorrectionSection(std::string& html, const RunData& run);
void RetainSection(std::string& html, const RunData& run);
void DiagnosisSection(std::string& html, const RunData& run);

// report_3d.cc: the part in 3-D (three.js, inlined from Debian's libjs-three) coloured by deviation with
// the same scale as the maps, and a static SVG projection for print. max_abs_um: the report's scale.
Status View3dSection(std::string& html, const RunData& run, double max_abs_um);

// The systematic field of a loop when the analysis wrote it (systematic_um), else its deviations; and
// whether it is the systematic field.
struct MapField {
  std::vector<double> values;
  bool systematic = false;
};
MapField FieldOf(const LoopData& loop);

}  // namespace formloop::app::report

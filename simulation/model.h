#pragma once
// A model of the machine: a set of effects from the catalogue with parameter values, their
// standard errors and where they came from (spec/simulation.md §3). Models are data: JSON files
// (`formloop simulate --model`, `diagnose --baseline`, the extended model diagnose writes) and, once
// the case library stores them, rows of a case.
//
//   {"format": "formloop-model", "version": 1,
//    "effects": [{"name": "tool_wear", "parameters": {"k_w_um_per_m": 2.0},
//                 "std_errors": {"k_w_um_per_m": 0.1}}, ...],
//    "provenance": {...}}
//
// scallop is in every model (it is geometry) whether listed or not; noise is the one effect whose
// parameters are scatter, not a mean.
//
// Alias groups (issue 20): when the data that taught a model could not tell some effects apart, the
// model holds what the data do support — their combined prediction. Its effects then carry
// "alias_group": ID, and "alias_groups": [{"id": ID, "members": [...], "note": ...}] lists every
// effect of the group (also those with no entry, which the combined prediction stands for as well).
// Such an effect's parameters are one split of the combined prediction among its members, not an
// estimate of that effect: they predict like the group and are not named causes.

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "simulation/effects.h"

namespace formloop::sim {

struct EffectInstance {
  const Effect* effect = nullptr;
  std::vector<double> values;      // one per effect->parameters()
  std::vector<double> std_errors;  // same size; 0 = exact (injected or assumed)
  std::string alias_group;         // empty: a named effect; else the id of its alias group
};

struct ModelAliasGroup {
  std::string id;                    // "G1", unique in the model
  std::vector<std::string> members;  // every effect the group stands for ("setup_offset@B" for a part's own)
};

struct Model {
  std::vector<EffectInstance> effects;  // at most one instance per effect name
  std::vector<ModelAliasGroup> alias_groups;
  nlohmann::json provenance = nlohmann::json::object();

  bool Has(std::string_view name) const { return Find(name) != nullptr; }
  const EffectInstance* Find(std::string_view name) const;
  // Sets (or replaces) an effect's parameters; values must have the effect's parameter count.
  Status Set(std::string_view name, std::vector<double> values, std::vector<double> std_errors = {});
  // True when the model names the effect as a cause (it is in the model and in no alias group).
  bool Names(std::string_view name) const;
  // The mean measured normal deviation the model predicts at c (µm): scallop plus every surface and
  // measurement effect; noise adds nothing here.
  double DeviationUm(const PointContext& c) const;
  // Surface part only (what the machined surface carries, without the probe's effects), µm.
  double SurfaceDeviationUm(const PointContext& c) const;
  // Every effect but noise: the mean deviation a machine produces, what a prediction or a
  // pre-compensation works with.
  Model WithoutNoise() const;
  // noise σ's (0 when the model has no noise effect).
  double surface_sigma_um() const;
  double probe_sigma_um() const;

  nlohmann::json ToJson() const;
  // `source` names the file for messages.
  static Result<Model> FromJson(const nlohmann::json& json, const std::string& source);
};

Result<Model> ReadModel(const std::filesystem::path& path);
Status WriteModel(const std::filesystem::path& path, const Model& model);

}  // namespace formloop::sim

#include "simulation/experiment_design.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <map>

#include <fmt/format.h>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "simulation/diagnose_engine.h"
#include "simulation/virtual_machine.h"

namespace formloop::sim {
namespace {

using detail::Concat;
using detail::Problem;
using detail::Term;

// A member or other effect of the design: a term, or one column of it.
struct Block {
  Term term;
  int column = -1;  // −1: every column of the term
  std::string label;
  std::vector<int> drop;  // of another effect: the columns that are members of the group (left out)
};

// "effect", "effect@each part", "effect@PART", "effect(param)", "effect(param)@PART" → a block. A
// part-specific effect is always one block per part (so a new part gets its own parameters).
Result<Block> ParseLabel(const std::string& label, const std::vector<std::string>& parts) {
  const std::size_t at = label.find('@'), open = label.find('(');
  const std::string effect_name = label.substr(0, std::min(at, open));
  const Effect* e = FindEffect(effect_name);
  if (e == nullptr) return Status::Internal("experiment design: unknown effect in '" + label + "'");
  Block b{{e, e->part_specific() ? detail::kEachPart : detail::kShared}, -1, label};
  int part = 0;
  if (at != std::string::npos && label.substr(at + 1) != "each part") {
    const auto it = std::find(parts.begin(), parts.end(), label.substr(at + 1));
    if (it == parts.end()) return Status::Internal("experiment design: unknown part in '" + label + "'");
    part = static_cast<int>(it - parts.begin());
  }
  if (open != std::string::npos) {
    const std::string param = label.substr(open + 1, label.find(')') - open - 1);
    for (int j = 0; j < e->parameter_count(); ++j) {
      if (e->parameters()[j].name == param) b.column = (e->part_specific() ? part * e->parameter_count() : 0) + j;
    }
    if (b.column < 0) return Status::Internal("experiment design: unknown parameter in '" + label + "'");
  }
  return b;
}

// The group's design on a problem: member blocks and the others' columns, scaled by `scale` (per member
// column; computed on the first problem evaluated and reused for augmented ones).
struct GroupDesign {
  std::vector<Eigen::MatrixXd> members;
  Eigen::MatrixXd others;
  Eigen::VectorXd combined;  // the group's combined prediction, σ units
};

class Designer {
 public:
  // `taken`: readings already made (the diagnosis's own, ProposeExperiments), rows of every design before
  // the ones Evaluate is given: a change adds its information to what is measured already.
  Designer(const Diagnosis& diagnosis, const AliasGroup& group, double tau, std::vector<DirectMeasurement> taken = {})
      : d_(diagnosis), group_(group), tau_(tau), taken_(std::move(taken)) {}

  Status Init(const std::vector<std::string>& parts) {
    parts_ = parts;
    for (const auto& m : group_.members) {
      FL_ASSIGN_OR_RETURN(Block b, ParseLabel(m, parts));
      members_.push_back(b);
    }
    // Others: the extended model's effects beyond the baseline that are not members (a member column's
    // sibling columns stay among the others).
    auto add_other = [&](const Block& b) {
      for (const auto& o : others_) {
        if (o.term == b.term) return;
      }
      others_.push_back(b);
    };
    for (const Cause& c : d_.causes) {
      FL_ASSIGN_OR_RETURN(Block b, ParseLabel(c.effect, parts));
      add_other(b);
    }
    for (const auto& g : d_.alias_groups) {
      if (g.members == group_.members) continue;
      for (const auto& m : g.in_model) {
        FL_ASSIGN_OR_RETURN(Block b, ParseLabel(m, parts));
        b.column = -1;
        add_other(b);
      }
    }
    // A member term leaves the others; a member column leaves its term, whose other columns stay (a
    // named set-up whose tz alone is aliased keeps tx and ty among the others, not tz).
    for (const Block& m : members_) {
      for (auto it = others_.begin(); it != others_.end();) {
        if (!(it->term == m.term)) {
          ++it;
        } else if (m.column < 0) {
          it = others_.erase(it);
        } else {
          it->drop.push_back(m.column);
          ++it;
        }
      }
    }
    // In-model members' values (the combined prediction).
    for (const std::string& label : group_.in_model) {
      FL_ASSIGN_OR_RETURN(Block b, ParseLabel(label, parts));
      values_.push_back({b, ValuesOf(b.term)});
    }
    return Status::Ok();
  }

  // Pooled: the in-model members' values fitted on the current data beside the others, each part with its
  // own set-up. The extended model holds one instance per effect (the first part's set-up), which every
  // part would otherwise be given: the combined prediction, and so the proposal, would depend on the order
  // of the parts.
  Status FitValues(const Problem& now) {
    if (values_.empty()) return Status::Ok();
    FL_ASSIGN_OR_RETURN(const GroupDesign g, Evaluate(now));
    Eigen::MatrixXd a = g.others.topRows(now.n());
    std::vector<std::vector<Eigen::Index>> where(values_.size());
    for (std::size_t v = 0; v < values_.size(); ++v) {
      const Block& b = values_[v].first;
      const Eigen::MatrixXd c = Columns(now, b.term);
      const int p = b.term.effect->parameter_count();
      for (Eigen::Index k = 0; k < c.cols(); ++k) {
        const bool used = b.column >= 0 ? k == b.column : b.term.effect->parameters()[k % p].linear;
        if (!used) continue;
        where[v].push_back(k);
        a = Concat(a, c.col(k));
      }
    }
    const detail::Fit fit = detail::LeastSquares(a, now.r);
    if (fit.beta.size() != a.cols()) return Status::Ok();
    Eigen::Index next = g.others.cols();
    for (std::size_t v = 0; v < values_.size(); ++v) {
      std::vector<double>& own = values_[v].second;
      const Eigen::Index width = Columns(now, values_[v].first.term).cols();
      if (static_cast<Eigen::Index>(own.size()) < width) own.resize(static_cast<std::size_t>(width), 0.0);
      for (Eigen::Index k : where[v]) own[static_cast<std::size_t>(k)] = fit.beta[next++];
    }
    return Status::Ok();
  }

  // `proposed`: direct measurements appended as rows after the problem's and the readings made (weight
  // 1/σ; the combined prediction is 0 there, the rows being new observations).
  Result<GroupDesign> Evaluate(const Problem& prob, const std::vector<DirectMeasurement>& proposed = {}) {
    std::vector<DirectMeasurement> direct = taken_;
    direct.insert(direct.end(), proposed.begin(), proposed.end());
    GroupDesign out;
    const Eigen::Index rows = prob.n() + static_cast<Eigen::Index>(direct.size());
    out.others = Eigen::MatrixXd(rows, 0);
    for (const Block& o : others_) {
      FL_ASSIGN_OR_RETURN(Eigen::MatrixXd c, WithDirectRows(Columns(prob, o.term), o.term, direct));
      if (!o.drop.empty()) {
        // The member columns are taken out of their term; the rest stays.
        Eigen::MatrixXd rest(rows, 0);
        for (Eigen::Index k = 0; k < c.cols(); ++k) {
          if (std::find(o.drop.begin(), o.drop.end(), static_cast<int>(k)) == o.drop.end()) {
            rest = Concat(rest, c.col(k));
          }
        }
        c = rest;
      }
      out.others = Concat(out.others, c);
    }
    for (const Block& m : members_) {
      FL_ASSIGN_OR_RETURN(Eigen::MatrixXd c, WithDirectRows(Columns(prob, m.term), m.term, direct));
      if (m.column >= 0) c = Eigen::MatrixXd(c.col(m.column));
      out.members.push_back(c);
    }
    if (scales_.empty()) {
      for (const auto& m : out.members) {
        Eigen::VectorXd s(m.cols());
        for (Eigen::Index k = 0; k < m.cols(); ++k) s[k] = m.col(k).norm() > 0 ? 1.0 / m.col(k).norm() : 1.0;
        scales_.push_back(s);
      }
    }
    // The scales are the current data's; a design with more columns (a part-specific member on a part the
    // diagnosis did not see) repeats each parameter's scale, as the combined prediction repeats its value.
    for (std::size_t m = 0; m < out.members.size(); ++m) {
      const Eigen::VectorXd& own = scales_[m];
      Eigen::VectorXd s(out.members[m].cols());
      for (Eigen::Index k = 0; k < s.size(); ++k) s[k] = own[k % own.size()];
      out.members[m] *= s.asDiagonal();
    }
    out.combined = Eigen::VectorXd::Zero(rows);
    for (const auto& [b, own] : values_) {
      const Eigen::MatrixXd c = Columns(prob, b.term);
      // A part the diagnosis did not see (the next part) is given the first part's set-up as a stand-in.
      std::vector<double> v;
      for (Eigen::Index k = 0; k < c.cols(); ++k) v.push_back(own[static_cast<std::size_t>(k) % own.size()]);
      if (b.column >= 0) {
        out.combined.head(prob.n()) += c.col(b.column) * v[static_cast<std::size_t>(b.column)];
      } else {
        const int p = b.term.effect->parameter_count();
        for (Eigen::Index k = 0; k < c.cols(); ++k) {
          if (b.term.effect->parameters()[k % p].linear) {
            out.combined.head(prob.n()) += c.col(k) * v[static_cast<std::size_t>(k)];
          }
        }
      }
    }
    return out;
  }

 private:
  // A term's columns with one row per direct measurement below them: 1/σ at the measured parameter's
  // column (a set-up: the column of the reading's part, the first when it names none) when it is this
  // term's effect, else 0.
  Result<Eigen::MatrixXd> WithDirectRows(const Eigen::MatrixXd& c, const Term& t,
                                         const std::vector<DirectMeasurement>& direct) const {
    if (direct.empty()) return c;
    Eigen::MatrixXd out = Eigen::MatrixXd::Zero(c.rows() + static_cast<Eigen::Index>(direct.size()), c.cols());
    out.topRows(c.rows()) = c;
    const int p = t.effect->parameter_count();
    for (std::size_t k = 0; k < direct.size(); ++k) {
      if (direct[k].effect != t.effect->name()) continue;
      int part = 0;
      if (!direct[k].part.empty()) {
        const auto it = std::find(parts_.begin(), parts_.end(), direct[k].part);
        if (it == parts_.end()) {
          return Status::Internal("experiment design: a reading of part '" + direct[k].part + "', not one diagnosed");
        }
        part = static_cast<int>(it - parts_.begin());
      }
      const int first = t.part == detail::kEachPart ? part * p : 0;
      for (int j = 0; j < p; ++j) {
        if (t.effect->parameters()[j].name == direct[k].parameter && first + j < c.cols()) {
          out(c.rows() + static_cast<Eigen::Index>(k), first + j) = 1.0 / direct[k].sigma;
        }
      }
    }
    return out;
  }
  Eigen::MatrixXd Columns(const Problem& prob, const Term& t) const {
    if (t.effect->linear()) return prob.Columns(t, {});
    std::vector<double> theta(static_cast<std::size_t>(t.effect->parameter_count()), 1.0);
    for (int j = 0; j < t.effect->parameter_count(); ++j) {
      if (!t.effect->parameters()[j].linear) theta[static_cast<std::size_t>(j)] = tau_;
    }
    return prob.Columns(t, theta);
  }
  // The values of a model effect, one per column (a part-specific effect: the first part's values, the
  // only ones the extended model holds, repeated; they scale the combined prediction only).
  std::vector<double> ValuesOf(const Term& t) const {
    const EffectInstance* e = d_.extended.Find(t.effect->name());
    std::vector<double> v;
    const int copies = t.part == detail::kEachPart ? std::max<int>(1, static_cast<int>(d_.parts.size())) : 1;
    for (int c = 0; c < copies; ++c) {
      for (int j = 0; j < t.effect->parameter_count(); ++j) v.push_back(e != nullptr ? e->values[j] : 0.0);
    }
    return v;
  }

  const Diagnosis& d_;
  const AliasGroup& group_;
  double tau_;
  std::vector<DirectMeasurement> taken_;
  std::vector<std::string> parts_;
  std::vector<Block> members_, others_;
  std::vector<std::pair<Block, std::vector<double>>> values_;
  std::vector<Eigen::VectorXd> scales_;
};

// log det of the members' information with the others profiled out (Ds-optimality), floored.
double LogDetInformation(const GroupDesign& g) {
  Eigen::MatrixXd members(g.others.rows(), 0);
  for (const auto& m : g.members) members = Concat(members, m);
  Eigen::MatrixXd projected = members;
  if (g.others.cols() > 0) {
    const Eigen::MatrixXd q = Eigen::HouseholderQR<Eigen::MatrixXd>(g.others).householderQ() *
                              Eigen::MatrixXd::Identity(g.others.rows(), g.others.cols());
    projected -= q * (q.transpose() * members);
  }
  const Eigen::VectorXd ev =
      Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(projected.transpose() * projected).eigenvalues();
  double sum = 0;
  for (Eigen::Index k = 0; k < ev.size(); ++k) sum += std::log(std::max(ev[k], 1e-12));
  return sum;
}

// min over members of λ_m (see the header), on the rows of `g`, θ_m fitted on the first `fit_rows`.
constexpr double kMinorShare = 0.1;
double Separation(const GroupDesign& g, Eigen::Index fit_rows) {
  const double total = g.combined.head(fit_rows).squaredNorm();
  if (!(total > 0)) return 0;
  double worst = std::numeric_limits<double>::infinity();
  for (std::size_t m = 0; m < g.members.size(); ++m) {
    const Eigen::MatrixXd a = Concat(g.others, g.members[m]);
    const detail::Fit fit = detail::LeastSquares(a.topRows(fit_rows), g.combined.head(fit_rows));
    if (fit.beta.size() == 0) continue;
    Eigen::VectorXd h = g.members[m] * fit.beta.tail(g.members[m].cols());
    // A member that cannot stand for the group alone may still carry a part of it (a probe radius beside
    // a set-up shift): it must be told from the others at a tenth of the group's size, else it stays
    // grouped with its look-alike after the change.
    const double own = h.head(fit_rows).squaredNorm();
    if (!(own > 0)) continue;
    if (own < kMinorShare * total) h *= std::sqrt(kMinorShare * total / own);
    Eigen::MatrixXd rest = g.others;
    for (std::size_t o = 0; o < g.members.size(); ++o) {
      if (o != m) rest = Concat(rest, g.members[o]);
    }
    const double lambda = detail::LeastSquares(rest, h).rss;
    if (std::getenv("FL_DEBUG_EXPERIMENT")) std::fprintf(stderr, "    member %zu: lambda %.2f\n", m, lambda);
    worst = std::min(worst, lambda);
  }
  return std::isfinite(worst) ? worst : 0.0;
}

}  // namespace

std::vector<DirectKind> DefaultDirectKinds() {
  return {{"tool_setter",
           "tool setter",
           "tool_radius",
           {"delta_r_um"},
           1.0,
           60,
           "measure the cutting tool's radius on the machine's tool setter"},
          {"reference_sphere",
           "reference sphere",
           "probe_radius",
           {"delta_r_eff_um"},
           0.5,
           120,
           "calibrate the probe's effective radius on the reference sphere"},
          {"datum",
           "datum faces",
           "setup_offset",
           {"tx_um", "ty_um", "tz_um"},
           1.0,
           90,
           "probe the fixture's datum faces (x, y and z) to measure where the part sits"},
          {"datum_rotation",
           "datum plane and edge",
           "setup_rotation",
           {"wx_urad", "wy_urad", "wz_urad"},
           5.0,
           120,
           "probe the fixture's datum plane at three points and its edge at two, far apart, to measure how the "
           "part is turned"},
          {"step_gauge_x",
           "step gauge along X",
           "axis_scale_x",
           {"e_x_um_per_m"},
           1.0,
           600,
           "clamp a calibrated step gauge (or length bar, ~500 mm) along X and probe its faces to measure the X "
           "scale"},
          {"step_gauge_y",
           "step gauge along Y",
           "axis_scale_y",
           {"e_y_um_per_m"},
           1.0,
           600,
           "clamp a calibrated step gauge (or length bar, ~500 mm) along Y and probe its faces to measure the Y "
           "scale"},
          {"step_gauge_z",
           "step gauge along Z",
           "axis_scale_z",
           {"e_z_um_per_m"},
           2.5,
           600,
           "stand a calibrated step gauge (or length bar, ~200 mm) along Z and probe its faces to measure the Z "
           "scale"},
          {"ball_bar_xy",
           "ball bar in XY",
           "squareness_xy",
           {"S_xy_urad"},
           5.0,
           900,
           "run a ball-bar circle in the XY plane (ISO 230-4, both directions) to measure the squareness of X and "
           "Y"},
          {"ball_bar_yz",
           "ball bar in YZ",
           "squareness_yz",
           {"S_yz_urad"},
           5.0,
           900,
           "run a ball-bar arc in the YZ plane (ISO 230-4, both directions) to measure the squareness of Y and Z"},
          {"ball_bar_zx",
           "ball bar in ZX",
           "squareness_zx",
           {"S_zx_urad"},
           5.0,
           900,
           "run a ball-bar arc in the ZX plane (ISO 230-4, both directions) to measure the squareness of Z and X"},
          {"deflection_test_cut",
           "test cut at two engagements",
           "tool_deflection",
           {"k_d_um"},
           1.0,
           600,
           "cut a vertical wall in a spare block with the finishing tool at two radial engagements (0.05 r and "
           "0.2 r) and probe both walls: their offset is the deflection"},
          {"sphere_directions",
           "reference sphere, many directions",
           "probe_lobing",
           {"c3_um", "s3_um"},
           0.3,
           180,
           "probe the reference sphere in 12 or more directions around its equator to measure the probe's "
           "lobing"},
          {"tool_setter_before_after",
           "tool setter before and after the cut",
           "tool_wear",
           {"k_w_um_per_m"},
           1.4,
           120,
           "measure the cutting tool's radius on the tool setter before and after cutting the part: the loss over "
           "the part's path length is the wear rate",
           true}};
}

Status ExperimentOptions::Validate() const {
  if (!(tilt_deg > 0 && tilt_deg < 75)) return Status::BadInput(Where{.field = "tilt_deg"}, "must be in (0, 75)");
  if (candidate_grid < 4) return Status::BadInput(Where{.field = "candidate_grid"}, "must be >= 4");
  if (!(probe_seconds_per_point > 0)) return Status::BadInput(Where{.field = "probe_seconds_per_point"}, "must be > 0");
  for (int k : reprobe_counts) {
    if (k < 1) return Status::BadInput(Where{.field = "reprobe_counts"}, "must be >= 1");
  }
  for (double f : feed_scales) {
    if (!(f > 0)) return Status::BadInput(Where{.field = "feed_scales"}, "must be > 0");
  }
  for (const DirectKind& k : direct_kinds) {
    for (const std::string& parameter : k.parameters) {
      const DirectMeasurement d{k.effect, parameter, 0.0, k.sigma, "", k.instrument};
      FL_RETURN_IF_ERROR(d.Validate());
    }
    if (!(k.cost_s > 0)) return Status::BadInput(Where{.field = "direct_kinds.cost_s"}, "must be > 0");
  }
  return Status::Ok();
}

nlohmann::json ExperimentProposal::ToJson() const {
  nlohmann::json j = {{"alias_group", members},
                      {"kind", kind},
                      {"change", change},
                      {"cost_s", cost_s},
                      {"design_correlation_before", correlation_before},
                      {"design_correlation_predicted", correlation_after},
                      {"log_det_information_gain", log_det_gain},
                      {"separation_predicted", separation},
                      {"predicted_to_split", predicted_to_split}};
  if (!direct.empty()) {
    nlohmann::json measure = nlohmann::json::array();
    for (const DirectMeasurement& d : direct) {
      measure.push_back({{"effect", d.effect}, {"parameter", d.parameter}, {"sigma", d.sigma}, {"by", d.by}});
    }
    j["measure"] = measure;
  } else if (kind == "reprobe") {
    nlohmann::json points = nlohmann::json::array();
    for (std::size_t i = 0; i < plan.points.size(); ++i) {
      const auto& p = plan.points[i];
      points.push_back({{"id", p.id},
                        {"u", p.u},
                        {"v", p.v},
                        {"point_mm", {p.point.x(), p.point.y(), p.point.z()}},
                        {"normal", {p.normal.x(), p.normal.y(), p.normal.z()}},
                        {"approach", {approaches[i].x(), approaches[i].y(), approaches[i].z()}}});
    }
    j["points"] = points;
  } else {
    j["raster_turn_deg"] = raster_turn_deg;
    j["feed_scale"] = feed_scale;
  }
  return j;
}

namespace {

struct PartData {
  std::vector<ProbeResidualData> data;
  std::vector<double> sigma;
  std::vector<std::string> labels;
};

// The parts' residuals (in the diagnosis's order) with each part's σ and label.
Result<PartData> PartDataOf(std::vector<ProbeResidualData> residuals, const Diagnosis& diagnosis) {
  PartData out;
  std::size_t row = 0;
  for (auto& data : residuals) {
    // σ of the part: the RMS of the diagnosis' residual after its model over the part's rows.
    double sum = 0;
    const std::size_t m = data.contexts.size();
    if (row + m > diagnosis.residual_after_um.size()) {
      return Status::Internal("experiment design: the diagnosis was made from other data");
    }
    for (std::size_t i = 0; i < m; ++i)
      sum += diagnosis.residual_after_um[row + i] * diagnosis.residual_after_um[row + i];
    row += m;
    out.sigma.push_back(std::max(1e-3, std::sqrt(sum / static_cast<double>(m))));
    out.data.push_back(std::move(data));
  }
  const std::size_t parts = out.data.size();
  out.labels = diagnosis.parts.size() == parts && parts > 1 ? diagnosis.parts : std::vector<std::string>(parts, "");
  if (parts > 1 && diagnosis.parts.size() != parts) {
    for (std::size_t p = 0; p < parts; ++p) out.labels[p] = std::to_string(p + 1);
  }
  return out;
}

Result<PartData> ReadParts(const std::vector<ProbeDataInput>& parts, const Diagnosis& diagnosis,
                           const Model& baseline) {
  std::vector<ProbeResidualData> residuals;
  for (const auto& in : parts) {
    FL_ASSIGN_OR_RETURN(ProbeResidualData data, ProbeResiduals(in, baseline));
    residuals.push_back(std::move(data));
  }
  return PartDataOf(std::move(residuals), diagnosis);
}

double TauOf(const Diagnosis& d, const Problem& prob, const PlausibleRanges& plausible) {
  if (const EffectInstance* t = d.extended.Find("thermal_drift_z")) return t->values[1];
  double lo = prob.time_scale_s / 100, hi = prob.time_scale_s * 100;
  if (const ParameterRange* r = plausible.Find(*FindEffect("thermal_drift_z"), 1)) {
    lo = r->min;
    hi = r->max;
  }
  const auto f =
      detail::FitTerm(prob, {FindEffect("thermal_drift_z"), detail::kShared}, Eigen::MatrixXd(prob.n(), 0), lo, hi);
  return f.theta[1];
}

// Re-probe candidates on the first part: a grid of locations × (−n and four tilted approaches).
Result<std::pair<metrology::ProbingPlan, std::vector<Eigen::Vector3d>>> Candidates(const ProbeDataInput& part,
                                                                                   const ExperimentOptions& o) {
  FL_ASSIGN_OR_RETURN(const metrology::ProbingPlan grid,
                      metrology::PlanProbingGrid(*part.surface, o.candidate_grid, o.candidate_grid, 0.05));
  std::int64_t next_id = 0;
  for (const auto& p : part.plan->points) next_id = std::max(next_id, p.id);
  metrology::ProbingPlan plan;
  std::vector<Eigen::Vector3d> approaches;
  const double tilt = o.tilt_deg * M_PI / 180;
  for (const auto& p : grid.points) {
    Eigen::Vector3d t1 = p.normal.cross(Eigen::Vector3d::UnitX());
    if (t1.norm() < 0.1) t1 = p.normal.cross(Eigen::Vector3d::UnitY());
    t1.normalize();
    const Eigen::Vector3d t2 = p.normal.cross(t1);
    for (int a = 0; a < 5; ++a) {
      metrology::ProbePoint q = p;
      q.id = ++next_id;
      Eigen::Vector3d dir = -p.normal;
      if (a > 0) {
        const double phi = (a - 1) * M_PI / 2;
        dir = -(std::cos(tilt) * p.normal + std::sin(tilt) * (std::cos(phi) * t1 + std::sin(phi) * t2));
      }
      plan.points.push_back(q);
      approaches.push_back(dir.normalized());
    }
  }
  return std::make_pair(plan, approaches);
}

}  // namespace

namespace {

Result<Problem> ProblemOf(const PartData& pd) {
  std::vector<detail::PartRows> rows;
  for (std::size_t p = 0; p < pd.data.size(); ++p) {
    rows.push_back(
        {&pd.data[p].contexts, &pd.data[p].residual_um, &pd.data[p].sensitivity, static_cast<int>(p), pd.sigma[p]});
  }
  return detail::BuildProbeProblem(rows, pd.labels, 8);
}

}  // namespace

Result<double> GroupCorrelation(const std::vector<ProbeDataInput>& parts, const Diagnosis& diagnosis,
                                const Model& baseline, const std::vector<std::string>& members,
                                const std::vector<DirectMeasurement>& direct) {
  FL_ASSIGN_OR_RETURN(const PartData pd, ReadParts(parts, diagnosis, baseline));
  FL_ASSIGN_OR_RETURN(const Problem prob, ProblemOf(pd));
  AliasGroup group;
  group.members = members;
  Designer designer(diagnosis, group, TauOf(diagnosis, prob, PlausibleRanges{}));
  FL_RETURN_IF_ERROR(designer.Init(pd.labels));
  FL_ASSIGN_OR_RETURN(const GroupDesign g, designer.Evaluate(prob, direct));
  return detail::GroupDesignCorrelation(g.members, g.others);
}

Result<double> GroupSeparation(const std::vector<ProbeDataInput>& parts, const Diagnosis& diagnosis,
                               const Model& baseline, const std::vector<std::string>& members,
                               const std::vector<DirectMeasurement>& direct) {
  const auto group = std::find_if(diagnosis.alias_groups.begin(), diagnosis.alias_groups.end(),
                                  [&](const AliasGroup& g) { return g.members == members; });
  if (group == diagnosis.alias_groups.end()) {
    return Status::BadInput(Where{.field = "members"}, "not an alias group of the diagnosis");
  }
  FL_ASSIGN_OR_RETURN(const PartData pd, ReadParts(parts, diagnosis, baseline));
  FL_ASSIGN_OR_RETURN(const Problem prob, ProblemOf(pd));
  Designer designer(diagnosis, *group, TauOf(diagnosis, prob, PlausibleRanges{}), diagnosis.direct);
  FL_RETURN_IF_ERROR(designer.Init(pd.labels));
  if (pd.data.size() > 1) FL_RETURN_IF_ERROR(designer.FitValues(prob));
  FL_ASSIGN_OR_RETURN(const GroupDesign g, designer.Evaluate(prob, direct));
  return Separation(g, prob.n());
}

namespace {

// ProposeExperiments on the parts' residuals `pd`; `first` is the part a re-probe or the next part's plan
// refer to (its residuals are pd's first).
Result<std::vector<ExperimentProposal>> Propose(const ProbeDataInput& first, const PartData& pd,
                                                const Diagnosis& diagnosis, const ExperimentOptions& options) {
  std::vector<ExperimentProposal> out;
  std::vector<detail::PartRows> current;
  for (std::size_t p = 0; p < pd.data.size(); ++p) {
    current.push_back(
        {&pd.data[p].contexts, &pd.data[p].residual_um, &pd.data[p].sensitivity, static_cast<int>(p), pd.sigma[p]});
  }
  FL_ASSIGN_OR_RETURN(const Problem now, detail::BuildProbeProblem(current, pd.labels, 8));
  const Eigen::Index n_now = now.n();
  // Re-probe candidates with their contexts (the first part's path).
  FL_ASSIGN_OR_RETURN(const auto candidates, Candidates(first, options));
  FL_ASSIGN_OR_RETURN(const std::vector<PointContext> candidate_contexts,
                      AssociateWithToolpath(*first.cutter_locations, first.tool_radius_mm,
                                            MeasuredPointsOf(candidates.first, candidates.second)));
  const Eigen::VectorXd candidate_zero = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(candidate_contexts.size()));
  // Next parts: the first part's plan on a re-planned path.
  struct NextPart {
    double turn = 0, feed = 1, cut_time_s = 0;
    std::vector<PointContext> contexts;
  };
  std::vector<NextPart> next_parts;
  if (options.replan) {
    std::vector<std::pair<double, double>> changes;
    for (double turn : options.raster_turns_deg) changes.push_back({turn, 1.0});
    for (double feed : options.feed_scales) changes.push_back({0.0, feed});
    for (const auto& [turn, feed] : changes) {
      FL_ASSIGN_OR_RETURN(const std::vector<CutterLocation> cls, options.replan(turn, feed));
      if (cls.empty()) continue;
      NextPart np{turn, feed, cls.back().time_s, {}};
      FL_ASSIGN_OR_RETURN(np.contexts, AssociateWithToolpath(cls, first.tool_radius_mm, MeasuredPointsOf(*first.plan)));
      next_parts.push_back(std::move(np));
    }
  }
  const double path_length_m =
      first.cutter_locations->empty() ? 0.0 : first.cutter_locations->back().path_length_mm * 1e-3;
  const Eigen::VectorXd next_zero = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(first.plan->points.size()));
  std::vector<std::string> labels_plus = pd.labels;
  if (labels_plus.size() == 1) labels_plus = {"1"};
  labels_plus.push_back("next");

  for (const AliasGroup& group : diagnosis.alias_groups) {
    if (std::getenv("FL_DEBUG_EXPERIMENT")) {
      std::string names;
      for (const auto& m : group.members) names += m + " ";
      std::fprintf(stderr, "group: %s\n", names.c_str());
    }
    Designer designer(diagnosis, group, TauOf(diagnosis, now, options.plausible), diagnosis.direct);
    FL_RETURN_IF_ERROR(designer.Init(pd.labels));
    if (pd.data.size() > 1) FL_RETURN_IF_ERROR(designer.FitValues(now));
    FL_ASSIGN_OR_RETURN(const GroupDesign base, designer.Evaluate(now));
    const double rho0 = detail::GroupDesignCorrelation(base.members, base.others);
    const double logdet0 = LogDetInformation(base);
    std::vector<ExperimentProposal> options_for_group;
    auto assess = [&](const Problem& augmented, ExperimentProposal p) -> Status {
      FL_ASSIGN_OR_RETURN(const GroupDesign g, designer.Evaluate(augmented, p.direct));
      p.members = group.members;
      p.correlation_before = rho0;
      p.correlation_after = detail::GroupDesignCorrelation(g.members, g.others);
      p.log_det_gain = LogDetInformation(g) - logdet0;
      p.separation = Separation(g, n_now);
      p.predicted_to_split = p.separation >= options.required_noncentrality;
      if (std::getenv("FL_DEBUG_EXPERIMENT")) {
        std::fprintf(stderr, "  %s cost %.0f: corr %.4f -> %.4f, separation %.2f, combined |.|^2 %.2f\n",
                     p.kind.c_str(), p.cost_s, rho0, p.correlation_after, p.separation,
                     g.combined.head(n_now).squaredNorm());
      }
      options_for_group.push_back(std::move(p));
      return Status::Ok();
    };
    // Re-probe: sequential Ds-optimal choice among the candidates. Adding a row x to the information
    // M of all parameters changes log det M − log det M_OO by log(1 + xᵀM⁻¹x) − log(1 + x_Oᵀ M_OO⁻¹ x_O)
    // (matrix determinant lemma); M is kept regularised (aliased columns make it singular).
    {
      std::vector<detail::PartRows> rows = current;
      rows.push_back({&candidate_contexts, &candidate_zero, nullptr, 0, pd.sigma[0]});
      FL_ASSIGN_OR_RETURN(const Problem all, detail::BuildProbeProblem(rows, pd.labels, 8));
      FL_ASSIGN_OR_RETURN(const GroupDesign g, designer.Evaluate(all));
      Eigen::MatrixXd x = g.others;
      for (const auto& m : g.members) x = Concat(x, m);
      const Eigen::Index k_o = g.others.cols(), k = x.cols();
      // The information of the data (the first n_now rows) and of the readings already made (the last).
      const Eigen::Index made = static_cast<Eigen::Index>(diagnosis.direct.size());
      Eigen::MatrixXd info =
          x.topRows(n_now).transpose() * x.topRows(n_now) + x.bottomRows(made).transpose() * x.bottomRows(made);
      const double ridge = 1e-8 * std::max(1.0, info.trace() / std::max<Eigen::Index>(1, k));
      info += ridge * Eigen::MatrixXd::Identity(k, k);
      Eigen::MatrixXd inv = info.inverse();
      Eigen::MatrixXd inv_o = k_o > 0 ? Eigen::MatrixXd(info.topLeftCorner(k_o, k_o).inverse()) : Eigen::MatrixXd();
      std::vector<bool> taken(static_cast<std::size_t>(all.n() - n_now), false);
      std::vector<int> order;
      const int max_count = *std::max_element(options.reprobe_counts.begin(), options.reprobe_counts.end());
      for (int step = 0; step < max_count && step < static_cast<int>(taken.size()); ++step) {
        double best = -1;
        int pick = -1;
        for (Eigen::Index c = 0; c < static_cast<Eigen::Index>(taken.size()); ++c) {
          if (taken[static_cast<std::size_t>(c)]) continue;
          const Eigen::VectorXd row = x.row(n_now + c).transpose();
          double gain = std::log1p(row.dot(inv * row));
          if (k_o > 0) gain -= std::log1p(row.head(k_o).dot(inv_o * row.head(k_o)));
          if (gain > best) {
            best = gain;
            pick = static_cast<int>(c);
          }
        }
        if (pick < 0) break;
        taken[static_cast<std::size_t>(pick)] = true;
        order.push_back(pick);
        const Eigen::VectorXd row = x.row(n_now + pick).transpose();
        const Eigen::VectorXd u = inv * row;
        inv -= u * u.transpose() / (1.0 + row.dot(u));
        if (k_o > 0) {
          const Eigen::VectorXd uo = inv_o * row.head(k_o);
          inv_o -= uo * uo.transpose() / (1.0 + row.head(k_o).dot(uo));
        }
      }
      for (int count : options.reprobe_counts) {
        if (count > static_cast<int>(order.size())) continue;
        std::vector<PointContext> chosen;
        ExperimentProposal p;
        p.kind = "reprobe";
        for (int i = 0; i < count; ++i) {
          chosen.push_back(candidate_contexts[static_cast<std::size_t>(order[static_cast<std::size_t>(i)])]);
          p.plan.points.push_back(
              candidates.first.points[static_cast<std::size_t>(order[static_cast<std::size_t>(i)])]);
          p.approaches.push_back(candidates.second[static_cast<std::size_t>(order[static_cast<std::size_t>(i)])]);
        }
        int tilted = 0;
        for (std::size_t i = 0; i < p.plan.points.size(); ++i) {
          tilted += -p.approaches[i].dot(p.plan.points[i].normal) < 0.999;
        }
        p.change = fmt::format(
            "re-probe {} more points of this part ({} of them with the approach tilted {:g} deg "
            "from the normal), chosen for the information they add on this group",
            count, tilted, options.tilt_deg);
        p.cost_s = count * options.probe_seconds_per_point;
        const Eigen::VectorXd zero = Eigen::VectorXd::Zero(count);
        std::vector<detail::PartRows> aug = current;
        aug.push_back({&chosen, &zero, nullptr, 0, pd.sigma[0]});
        FL_ASSIGN_OR_RETURN(const Problem augmented, detail::BuildProbeProblem(aug, pd.labels, 8));
        FL_RETURN_IF_ERROR(assess(augmented, std::move(p)));
      }
    }
    // The next part cut another way, probed with this part's plan.
    for (const NextPart& np : next_parts) {
      std::vector<detail::PartRows> aug = current;
      aug.push_back({&np.contexts, &next_zero, nullptr, static_cast<int>(pd.data.size()), pd.sigma[0]});
      FL_ASSIGN_OR_RETURN(const Problem augmented, detail::BuildProbeProblem(aug, labels_plus, 8));
      ExperimentProposal p;
      p.kind = np.feed != 1.0 ? "feed" : "raster_turn";
      p.raster_turn_deg = np.turn;
      p.feed_scale = np.feed;
      p.change = np.feed != 1.0 ? fmt::format(
                                      "cut the next part with the feed scaled by {:g}, probe it with this plan "
                                      "and diagnose the two parts together",
                                      np.feed)
                                : fmt::format(
                                      "cut the next part with the raster turned by {:g} deg{}, probe it with "
                                      "this plan and diagnose the two parts together",
                                      np.turn, np.turn == 180 ? " (the cutting order reversed)" : "");
      p.cost_s = np.cut_time_s + static_cast<double>(np.contexts.size()) * options.probe_seconds_per_point;
      FL_RETURN_IF_ERROR(assess(augmented, std::move(p)));
    }
    // Direct measurements of the group's members: every combination of the kinds that measure one when
    // there are at most kExhaustiveKinds of them, else a greedy forward choice (each step adds the kind
    // that separates most, until the set is predicted to split or every kind is in).
    {
      std::vector<const DirectKind*> relevant;
      for (const DirectKind& k : options.direct_kinds) {
        for (const std::string& m : group.members) {
          if (m.substr(0, std::min(m.find('@'), m.find('('))) == k.effect) {
            relevant.push_back(&k);
            break;
          }
        }
      }
      auto assess_set = [&](const std::vector<std::size_t>& picks) -> Result<const ExperimentProposal*> {
        ExperimentProposal p;
        std::string actions;
        for (std::size_t k : picks) {
          const DirectKind& dk = *relevant[k];
          p.kind += (p.kind.empty() ? "" : "+") + dk.kind;
          actions += (actions.empty() ? "" : "; ") + dk.action;
          // A reading the diagnosis has already (of the first part's set-up when it is one): the proposal
          // is to read it again, which the design counts as a further, independent reading.
          std::vector<const DirectMeasurement*> made;
          for (const std::string& prm : dk.parameters) {
            for (const DirectMeasurement& m : diagnosis.direct) {
              if (m.effect == dk.effect && m.parameter == prm && (m.part.empty() || m.part == pd.labels.front())) {
                made.push_back(&m);
                break;
              }
            }
          }
          if (!made.empty() && made.size() == dk.parameters.size()) {
            actions += fmt::format(" again (already read{}, sigma {:g}; the new reading counted as independent of it)",
                                   made.front()->by.empty() ? "" : " by the " + made.front()->by, made.front()->sigma);
          }
          p.cost_s += dk.cost_s;
          const double sigma = dk.per_path_length ? dk.sigma / std::max(1e-3, path_length_m) : dk.sigma;
          for (const std::string& parameter : dk.parameters) {
            p.direct.push_back({dk.effect, parameter, 0.0, sigma, "", dk.instrument});
          }
        }
        p.change = actions + ", and diagnose again with the measured values (formloop diagnose --direct)";
        FL_RETURN_IF_ERROR(assess(now, std::move(p)));
        return &options_for_group.back();
      };
      constexpr std::size_t kExhaustiveKinds = 6;
      if (relevant.size() <= kExhaustiveKinds) {
        for (unsigned mask = 1; mask < (1u << relevant.size()); ++mask) {
          std::vector<std::size_t> picks;
          for (std::size_t k = 0; k < relevant.size(); ++k) {
            if (mask & (1u << k)) picks.push_back(k);
          }
          FL_RETURN_IF_ERROR(assess_set(picks).status());
        }
      } else {
        std::vector<std::size_t> picks;
        std::vector<bool> in(relevant.size(), false);
        while (picks.size() < relevant.size()) {
          double best_separation = -1, best_cost = 0;
          std::size_t best_k = relevant.size();
          bool split = false;
          for (std::size_t k = 0; k < relevant.size(); ++k) {
            if (in[k]) continue;
            std::vector<std::size_t> trial = picks;
            trial.push_back(k);
            FL_ASSIGN_OR_RETURN(const ExperimentProposal* p, assess_set(trial));
            if (p->separation > best_separation || (p->separation == best_separation && p->cost_s < best_cost)) {
              best_separation = p->separation;
              best_cost = p->cost_s;
              best_k = k;
              split = p->predicted_to_split;
            }
          }
          in[best_k] = true;
          picks.push_back(best_k);
          if (split) break;
        }
      }
    }
    if (options_for_group.empty()) continue;
    // The cheapest change predicted to split the group; else the one that separates most (the cheapest of
    // equals): a change that decides nothing is not worth its time however cheap it is. Over the suite's
    // aliased scenarios this measured better than the most separation per second (groups split after
    // the change 300 against 293 of 315; proposals predicted below 1, 27 of 28 split against 20), at 37 %
    // more measuring time in all.
    auto best = options_for_group.begin();
    for (auto it = options_for_group.begin(); it != options_for_group.end(); ++it) {
      const bool better =
          it->predicted_to_split
              ? (!best->predicted_to_split || it->cost_s < best->cost_s ||
                 (it->cost_s == best->cost_s && it->log_det_gain > best->log_det_gain))
              : (!best->predicted_to_split && (it->separation > best->separation ||
                                               (it->separation == best->separation && it->cost_s < best->cost_s)));
      if (better) best = it;
    }
    out.push_back(*best);
  }
  return out;
}

}  // namespace

Result<std::vector<ExperimentProposal>> ProposeExperiments(const ProbeDataInput& part,
                                                           const std::vector<ProbeResidualData>& residuals,
                                                           const Diagnosis& diagnosis,
                                                           const ExperimentOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  if (diagnosis.alias_groups.empty()) return std::vector<ExperimentProposal>{};
  if (part.surface == nullptr || part.plan == nullptr || part.cutter_locations == nullptr) {
    return Status::Internal("ProposeExperiments: the first part needs its surface, plan and path");
  }
  FL_ASSIGN_OR_RETURN(const PartData pd, PartDataOf(residuals, diagnosis));
  return Propose(part, pd, diagnosis, options);
}

Result<std::vector<ExperimentProposal>> ProposeExperiments(const std::vector<ProbeDataInput>& parts,
                                                           const Diagnosis& diagnosis, const Model& baseline,
                                                           const ExperimentOptions& options) {
  if (diagnosis.alias_groups.empty()) return std::vector<ExperimentProposal>{};
  if (parts.empty()) return Status::Internal("ProposeExperiments: no part");
  std::vector<ProbeResidualData> residuals;
  for (const auto& in : parts) {
    FL_ASSIGN_OR_RETURN(ProbeResidualData data, ProbeResiduals(in, baseline));
    residuals.push_back(std::move(data));
  }
  return ProposeExperiments(parts.front(), residuals, diagnosis, options);
}

}  // namespace formloop::sim

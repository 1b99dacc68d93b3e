#include "cnc/controller.h"

#include <cmath>
#include <limits>
#include <sstream>

#include "core/atomic_file.h"
#include "core/point_io.h"

namespace formloop::cnc {

double LatencyModel::Draw(Rng& rng) const {
  const double u = rng.Uniform();
  const double z = rng.Normal();
  const double spike = rng.Uniform();
  double t = base_s;
  if (distribution == Distribution::kUniform) {
    t += jitter_s * u;
  } else if (jitter_s > 0) {
    t += jitter_s * std::exp(0.5 * z);
  }
  if (spike < spike_rate) t += spike_s;
  return t;
}

Status LatencyModel::Validate() const {
  if (!(base_s >= 0 && jitter_s >= 0 && spike_s >= 0 && base_s + jitter_s + spike_s <= 60)) {
    return Status::BadInput("latency: base, jitter and spike must be ≥ 0 s and add up to at most 60 s");
  }
  if (!(spike_rate >= 0 && spike_rate <= 1)) return Status::BadInput("latency: spike rate must be in [0, 1]");
  return Status::Ok();
}

Status ControllerFaults::Validate() const {
  for (const auto& [name, rate] : {std::pair<const char*, double>{"api_error_rate", api_error_rate},
                                   {"dropped_write_rate", dropped_write_rate},
                                   {"connection_drop_rate", connection_drop_rate},
                                   {"half_open_rate", half_open_rate},
                                   {"reorder_rate", reorder_rate},
                                   {"repeat_rate", repeat_rate},
                                   {"skip_rate", skip_rate}}) {
    if (!(rate >= 0 && rate <= 0.5))
      return Status::BadInput(std::string("fault rate ") + name + " must be in [0, 0.5]");
  }
  if (!(visibility_max_s >= 0 && visibility_max_s <= 10))
    return Status::BadInput("visibility_max_s must be in [0, 10] s");
  for (const auto& d : deviations) {
    if (d.axis < 0 || d.axis > 2) return Status::BadInput("a deviation fault names axis 0..2");
  }
  return Status::Ok();
}

Status ControllerOptions::Validate() const {
  if (points < 1 || points > kMaxPointId) {
    return Status::BadInput("points must be 1.." + std::to_string(kMaxPointId) + " per run (12-bit ids)");
  }
  if (runs < 1 || runs > 100000) return Status::BadInput("runs must be 1..100000");
  if (!(measure_time_s >= 0 && run_gap_s >= 0 && restart_delay_s >= 0 && start_delay_s >= 0)) {
    return Status::BadInput("measure, gap, restart and start times must be ≥ 0 s");
  }
  FL_RETURN_IF_ERROR(latency.Validate());
  FL_RETURN_IF_ERROR(faults.Validate());
  MachineProgramOptions p = program;
  p.dialect = dialect;
  return p.Validate();
}

metrology::ProbingPlan SyntheticPlan(int count) {
  metrology::ProbingPlan plan;
  const int columns = std::max(1, static_cast<int>(std::ceil(std::sqrt(count * 1.25))));
  for (int k = 0; k < count; ++k) {
    const double x = -100 + 2.0 * (k % columns), y = -80 + 2.0 * (k / columns);
    metrology::ProbePoint p;
    p.id = k + 1;
    p.point = Eigen::Vector3d(x, y, 0.5 * std::sin(x / 13) * std::cos(y / 17));
    const double zx = 0.5 / 13 * std::cos(x / 13) * std::cos(y / 17),
                 zy = -0.5 / 17 * std::sin(x / 13) * std::sin(y / 17);
    p.normal = Eigen::Vector3d(-zx, -zy, 1).normalized();
    p.u = x;
    p.v = y;
    plan.points.push_back(p);
  }
  return plan;
}

namespace {

// A probe end point as an integer key at 0.1 µm. Both sides key the value the program states: the
// controller formats and parses the planned end point as the program text does.
// The mixing wraps modulo 2^64 (unsigned arithmetic: a signed overflow is undefined; UBSan found it in
// CollectorTest.EveryDialectAndLayoutDeliversEveryPointExactly). The same bits as before on every build.
std::int64_t EndKey(const std::array<double, 3>& p) {
  std::uint64_t key = 0;
  for (double v : p) key = key * 10'000'019u + static_cast<std::uint64_t>(std::llround(v * 10000.0));
  return static_cast<std::int64_t>(key);
}

std::array<double, 3> AsWritten(const std::array<double, 3>& p, int decimals) {
  std::array<double, 3> out{};
  for (int a = 0; a < 3; ++a) ParseDouble(FormatFixed(p[a], decimals), &out[a]);
  return out;
}

}  // namespace

Controller::Controller(const ControllerOptions& options, EventScheduler* scheduler)
    : options_(options), scheduler_(scheduler), rng_(options.seed) {}

Result<std::unique_ptr<Controller>> Controller::Create(const ControllerOptions& options, EventScheduler* scheduler) {
  FL_RETURN_IF_ERROR(options.Validate());
  std::unique_ptr<Controller> c(new Controller(options, scheduler));
  FL_RETURN_IF_ERROR(c->Setup());
  return c;
}

Status Controller::Setup() {
  options_.program.dialect = options_.dialect;
  plan_ = SyntheticPlan(options_.points);
  FL_ASSIGN_OR_RETURN(program_, WriteMachineProgram(plan_, options_.program));
  MacroLimits limits;
  limits.sinumerik_r_last = options_.program.probe.sinumerik_r_last;
  limits.linuxcnc_ports = 64;
  FL_ASSIGN_OR_RETURN(code_, ReadMacroProgram(options_.dialect, program_.files, limits));
  block_ = program_.block;
  for (const auto& p : plan_.points) {
    const ProbePath path = ProbePathOf(p, options_.program.probe);
    if (!probe_index_
             .emplace(EndKey(AsWritten(path.end, options_.program.probe.post.decimals)), static_cast<int>(p.id - 1))
             .second) {
      return Status::Internal("two probe points of the synthetic plan end at the same position");
    }
  }
  // The default offset table: wear ±1 mm for tools 1..20, work offsets ±1000 mm for G54..G59.
  for (int t = 1; t <= 20; ++t) {
    offsets_["T" + std::to_string(t) + ".radius_wear"] = OffsetEntry{};
    offsets_["T" + std::to_string(t) + ".length_wear"] = OffsetEntry{};
  }
  for (int g = 54; g <= 59; ++g) {
    for (const char* axis : {"X", "Y", "Z"})
      offsets_["G" + std::to_string(g) + "." + axis] = OffsetEntry{0, -1000, 1000, 0.001};
  }
  for (const auto& [name, entry] : options_.offsets) {
    FL_RETURN_IF_ERROR(ParseOffsetAddress(name).status());
    offsets_[name] = entry;
  }
  if (options_.volatile_ranges.empty() && options_.dialect == Dialect::kFanuc) options_.volatile_ranges = {{100, 199}};
  for (const auto& [address, value] : options_.initial_values) memory_[address] = Store(value);
  interpreter_ = std::make_unique<MacroInterpreter>(&code_, this);
  scheduler_->After(options_.start_delay_s, [this] { StartRun(); });
  return Status::Ok();
}

bool Controller::Draw(double rate) { return rng_.Uniform() < rate; }

double Controller::Store(double value) const {
  if (options_.precision != Precision::kDigits8 || value == 0 || !std::isfinite(value)) return value;
  const int exponent = static_cast<int>(std::floor(std::log10(std::fabs(value))));
  const double scale = std::pow(10.0, 7 - exponent);
  return std::round(value * scale) / scale;
}

double Controller::ApiPath(double value) const {
  if (!options_.faults.api_mantissa32 || value == 0 || !std::isfinite(value)) return value;
  // FOCAS ODBM: value = mcr_val / 10^dec_val with a 32-bit mcr_val; the largest dec_val that fits.
  for (int dec = 9; dec >= -9; --dec) {
    const double scaled = std::round(value * std::pow(10.0, dec));
    if (std::fabs(scaled) <= 2147483647.0) return scaled / std::pow(10.0, dec);
  }
  return value;
}

MacroValue Controller::Peek(int address) const {
  const auto it = memory_.find(address);
  if (it == memory_.end()) return std::nullopt;
  return it->second;
}

Result<double> Controller::PeekOffset(const std::string& name) const {
  const auto it = offsets_.find(name);
  if (it == offsets_.end()) return Status::NotFound("offset " + name + " is not in the controller's table");
  return it->second.value_mm;
}

std::vector<std::array<double, 3>> Controller::GenerateTruth(int run) const {
  // Deviations v·1e-4 + u·0.3e-4 mm with v uniform in −900..900 and |u| ≤ 1: never at a rounding tie,
  // so the quantised value is v exactly. One seeded stream per run; fault overrides replace axes.
  Rng rng(options_.seed * 1'000'003ULL + static_cast<std::uint64_t>(run));
  std::vector<std::array<double, 3>> t;
  for (int k = 1; k <= options_.points; ++k) {
    std::array<double, 3> d{};
    for (int a = 0; a < 3; ++a) {
      const double v = static_cast<double>(static_cast<int>(rng.UniformIndex(1801)) - 900);
      const double u = rng.Uniform(-1, 1);
      d[a] = v * 1e-4 + u * 0.3e-4;
    }
    t.push_back(d);
  }
  for (const auto& dev : options_.faults.deviations) {
    if (dev.at.run == run && dev.at.point >= 1 && dev.at.point <= options_.points)
      t[dev.at.point - 1][dev.axis] = dev.value_mm;
  }
  return t;
}

std::array<double, 3> Controller::Truth(int run, int id) const { return GenerateTruth(run).at(id - 1); }

void Controller::StartRun() {
  ++runs_started_;
  running_ = true;
  current_point_ = 0;
  pending_repeat_ = pending_skip_ = 0;
  if (static_cast<int>(truth_.size()) < runs_started_) truth_.push_back(GenerateTruth(runs_started_));
  interpreter_->Restart();
  const std::uint64_t gen = generation_;
  scheduler_->After(0, [this, gen] {
    if (gen == generation_) Step();
  });
}

void Controller::Step() {
  if (!running_) return;
  const MacroInterpreter::Step step = interpreter_->Run();
  const std::uint64_t gen = generation_;
  switch (step.state) {
    case MacroInterpreter::State::kRunning:
      scheduler_->After(step.wait_s, [this, gen] {
        if (gen == generation_) Step();
      });
      return;
    case MacroInterpreter::State::kStopped:
      Reset();
      return;
    case MacroInterpreter::State::kEnded:
      running_ = false;
      ++runs_completed_;
      if (runs_completed_ >= options_.runs) {
        done_ = true;
      } else {
        scheduler_->After(options_.run_gap_s, [this, gen] {
          if (gen == generation_) StartRun();
        });
      }
      return;
    case MacroInterpreter::State::kAlarm:
      running_ = false;
      alarms_.push_back(AlarmRecord{runs_started_, interpreter_->alarm_number(), interpreter_->alarm_text(),
                                    interpreter_->Where(), scheduler_->now_s()});
      done_ = true;
      return;
  }
}

void Controller::Reset() {
  ++fault_counts_["reset"];
  running_ = false;
  ++generation_;
  // A reset discards what the program had not made visible yet and clears the volatile variables.
  pending_.clear();
  for (auto it = memory_.begin(); it != memory_.end();) {
    bool cleared = false;
    for (const auto& [lo, hi] : options_.volatile_ranges) cleared = cleared || (it->first >= lo && it->first <= hi);
    it = cleared ? memory_.erase(it) : std::next(it);
  }
  const std::uint64_t gen = generation_;
  scheduler_->After(options_.restart_delay_s, [this, gen] {
    if (gen == generation_) StartRun();
  });
}

MacroValue Controller::ReadVariable(int number) {
  for (auto it = pending_.rbegin(); it != pending_.rend(); ++it) {
    if (it->address == number) return it->value;
  }
  return Peek(number);
}

void Controller::Commit(int address, double value) { memory_[address] = Store(value); }

void Controller::WriteVariable(int number, MacroValue value) {
  double v = value.value_or(0.0);
  const bool is_control = number == block_.control();
  const bool is_data = number >= block_.data() && number < block_.data() + block_.data_count();
  std::optional<ControlWord> word;
  if (is_data) {
    if (number == block_.data()) {
      last_corrupted_ = false;
      for (const auto& at : options_.faults.corrupt_data) {
        if (at.run == runs_started_ && at.point == current_point_) {
          v += 0.5;
          last_corrupted_ = true;
          ++fault_counts_["corrupt_data"];
        }
      }
    }
    last_data_[number - block_.data()] = v;
  }
  bool reorder = false;
  if (is_control) {
    ControlWord w;
    if (ClassifyControlValue(v, &w) == WordKind::kPointReady) {
      word = w;
      HandoverRecord rec;
      rec.run = runs_started_;
      rec.q = ReadVariable(block_.run_counter()).value_or(0.0);
      rec.id = w.point;
      rec.data = last_data_;
      rec.truth_mm = last_truth_;
      rec.t_s = scheduler_->now_s();
      rec.corrupted = last_corrupted_;
      record_.push_back(rec);
      // One draw per fault kind per handover, in a fixed order.
      reorder = Draw(options_.faults.reorder_rate) && options_.faults.visibility_max_s > 0;
      const bool repeat = Draw(options_.faults.repeat_rate);
      const bool skip = Draw(options_.faults.skip_rate);
      if (w.point < options_.points) {
        if (repeat) {
          pending_repeat_ = w.point;
          ++fault_counts_["repeat_id"];
        } else if (skip && w.point + 1 < options_.points) {
          pending_skip_ = w.point;
          ++fault_counts_["skip_id"];
        }
      }
    }
  }
  // Visibility: the delay is drawn for the block's addresses (what the API side watches); the
  // program's scratch variables are committed in order with them.
  const bool in_block = number >= block_.base && number < block_.base + block_.size();
  const double delay =
      in_block && options_.faults.visibility_max_s > 0 ? rng_.Uniform(0, options_.faults.visibility_max_s) : 0.0;
  double t_visible = scheduler_->now_s() + delay;
  if (reorder) {
    ++fault_counts_["reorder"];
    t_visible = scheduler_->now_s();  // the control word overtakes the data still pending
  } else {
    if (t_visible < last_visible_t_) t_visible = last_visible_t_;
    last_visible_t_ = t_visible;
  }
  if (!value.has_value()) {
    memory_.erase(number);
  } else if (t_visible <= scheduler_->now_s() && (reorder || pending_.empty())) {
    Commit(number, v);
  } else {
    const std::uint64_t seq = pending_seq_++;
    pending_.push_back(Pending{seq, number, v});
    const std::uint64_t gen = generation_;
    scheduler_->At(t_visible, [this, seq, gen] {
      if (gen != generation_) return;
      for (auto it = pending_.begin(); it != pending_.end(); ++it) {
        if (it->seq == seq) {
          Commit(it->address, it->value);
          pending_.erase(it);
          return;
        }
      }
    });
  }
  // A third party writes into the block while the collector holds the token.
  if (word) {
    for (const auto& tp : options_.faults.third_party) {
      if (tp.at.run == runs_started_ && tp.at.point == word->point) {
        ++fault_counts_["third_party_write"];
        const int address = block_.base + tp.offset;
        const double value3 = tp.value;
        scheduler_->At(t_visible + 1e-6, [this, address, value3] { Commit(address, value3); });
      }
    }
  }
}

ProbeOutcome Controller::Probe(const std::array<double, 3>& from, const std::array<double, 3>& to, double feed) {
  ProbeOutcome out;
  out.duration_s = options_.measure_time_s;
  const auto it = probe_index_.find(EndKey(to));
  if (it == probe_index_.end()) {
    out.position = to;
    return out;  // nothing there: the probe never triggers
  }
  const ProbePath path = ProbePathOf(plan_.points[it->second], options_.program.probe);
  const auto& truth = truth_[runs_started_ - 1][it->second];
  for (int a = 0; a < 3; ++a) out.position[a] = path.reference[a] + truth[a];
  last_truth_ = truth;
  out.tripped = true;
  return out;
}

void Controller::Message(const std::string& text) { messages_.push_back(text); }

MachineEnvironment::MarkAction Controller::OnPointMark(int id) {
  MarkAction action;
  for (const auto& at : options_.faults.resets) {
    if (at.run == runs_started_ && at.point == id) {
      action.kind = MarkAction::Kind::kStop;
      return action;
    }
  }
  if (pending_repeat_ > 0 && id == pending_repeat_ + 1) {
    action.kind = MarkAction::Kind::kJump;
    action.target = pending_repeat_;
    pending_repeat_ = 0;
  } else if (pending_skip_ > 0 && id == pending_skip_ + 1) {
    action.kind = MarkAction::Kind::kJump;
    action.target = pending_skip_ + 2;
    pending_skip_ = 0;
  }
  current_point_ = action.kind == MarkAction::Kind::kJump ? action.target : id;
  return action;
}

void Controller::Submit(const ApiRequest& request, std::function<void(const ApiResponse&, Disposition)> done) {
  // Draws in a fixed order for every call.
  const double latency = options_.latency.Draw(rng_);
  const bool error = Draw(options_.faults.api_error_rate);
  const bool drop = Draw(options_.faults.connection_drop_rate);
  const bool half_open = Draw(options_.faults.half_open_rate);
  const bool drop_write = Draw(options_.faults.dropped_write_rate);
  const bool applied_anyway = Draw(0.5);
  const double now = scheduler_->now_s();
  Disposition disposition = Disposition::kAnswer;
  if (drop) {
    disposition = Disposition::kDropConnection;
    ++fault_counts_["connection_drop"];
  } else if (half_open) {
    disposition = Disposition::kHalfOpen;
    ++fault_counts_["half_open"];
  }
  const bool apply = !error && (disposition == Disposition::kAnswer || applied_anyway);
  if (error) ++fault_counts_["api_error"];
  auto response = std::make_shared<ApiResponse>();
  if (error) {
    response->ok = false;
    response->error = "EW_BUSY: the controller refused the call (injected API error)";
  }
  const bool is_write = request.op == ApiRequest::Op::kWriteRange;
  if (apply && request.op == ApiRequest::Op::kReadRange) {
    response->values.assign(request.count, std::nullopt);
    const int n = request.count;
    for (int k = 0; k < n; ++k) {
      // Torn: address k is read at its own moment across the call, the machine running in between.
      const double t = options_.faults.torn_range_reads ? now + latency * (k + 1) / (n + 1) : now + latency / 2;
      scheduler_->At(t, [this, response, request, k] {
        const MacroValue v = Peek(request.start + k);
        response->values[k] = v ? MacroValue(ApiPath(*v)) : std::nullopt;
      });
    }
    if (options_.faults.torn_range_reads && n > 1) ++fault_counts_["torn_read"];
  } else if (apply && is_write) {
    if (drop_write) {
      ++fault_counts_["dropped_write"];
    } else {
      scheduler_->At(now + latency / 2, [this, request] {
        for (std::size_t k = 0; k < request.values.size(); ++k)
          Commit(request.start + static_cast<int>(k), ApiPath(request.values[k]));
      });
    }
  } else if (apply) {
    scheduler_->At(now + latency / 2, [this, request, response] {
      const auto it = offsets_.find(request.offset);
      if (it == offsets_.end()) {
        response->ok = false;
        response->error = "EW_NUMBER: offset " + request.offset + " is not in the controller's table";
        return;
      }
      OffsetEntry& entry = it->second;
      if (request.op == ApiRequest::Op::kReadOffset) {
        response->value = entry.value_mm;
        return;
      }
      if (options_.faults.offset_reject.count(request.offset) != 0) {
        ++fault_counts_["offset_reject"];
        response->ok = false;
        response->error = "EW_PROT: writing " + request.offset + " is refused (injected)";
        return;
      }
      if (!(request.value >= entry.min_mm && request.value <= entry.max_mm)) {
        response->ok = false;
        response->error = "EW_DATA: " + request.offset + " = " + FormatExact(request.value) +
                          " is outside the controller's range [" + FormatExact(entry.min_mm) + ", " +
                          FormatExact(entry.max_mm) + "]";
        return;
      }
      // The controller keeps whole resolution steps (0.001 mm steps: integer µm), read back as the
      // double nearest to that decimal.
      const double steps_per_mm = std::round(1.0 / entry.resolution_mm);
      double stored = std::fabs(steps_per_mm * entry.resolution_mm - 1.0) < 1e-12
                          ? std::round(request.value * steps_per_mm) / steps_per_mm
                          : std::round(request.value / entry.resolution_mm) * entry.resolution_mm;
      const auto mismatch = options_.faults.offset_mismatch.find(request.offset);
      if (mismatch != options_.faults.offset_mismatch.end() && mismatch_used_.insert(request.offset).second) {
        stored = std::round((stored + mismatch->second) * steps_per_mm) / steps_per_mm;
        ++fault_counts_["offset_mismatch"];
      }
      entry.value_mm = stored;
    });
  }
  scheduler_->At(now + latency, [response, done, disposition] { done(*response, disposition); });
}

Status Controller::WriteRecord(const std::filesystem::path& path) const {
  std::ostringstream out;
  out << "# formloop link emulate: every point the measuring program handed over\n";
  out << "run,q,id,data0,data1,data2,dx_mm,dy_mm,dz_mm,t_s,corrupted\n";
  for (const auto& r : record_) {
    out << r.run << "," << FormatExact(r.q) << "," << r.id << "," << FormatExact(r.data[0]) << ","
        << FormatExact(r.data[1]) << "," << FormatExact(r.data[2]) << "," << FormatExact(r.truth_mm[0]) << ","
        << FormatExact(r.truth_mm[1]) << "," << FormatExact(r.truth_mm[2]) << "," << FormatExact(r.t_s) << ","
        << (r.corrupted ? 1 : 0) << "\n";
  }
  return WriteFileAtomic(path, out.str());
}

}  // namespace formloop::cnc

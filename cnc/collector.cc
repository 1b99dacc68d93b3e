#include "cnc/collector.h"

#include <cmath>
#include <limits>
#include <optional>
#include <set>
#include <sstream>

#include "core/atomic_file.h"
#include "core/log.h"
#include "core/point_io.h"
#include "core/progress.h"

namespace formloop::cnc {

Status CollectorOptions::Validate() const {
  if (block.base < 0) return Status::BadInput("the block base address must be ≥ 0");
  if (expect_points < 0 || expect_points > kMaxPointId) return Status::BadInput("expect_points must be 0..2000");
  if (runs < 1) return Status::BadInput("runs must be ≥ 1");
  if (!(poll_s > 0 && poll_slow_s >= poll_s && slow_after_s >= 0))
    return Status::BadInput("poll intervals must be > 0 (slow ≥ fast)");
  if (!(visibility_timeout_s > 0)) return Status::BadInput("visibility_timeout_s must be > 0");
  if (!(reconnect_min_s > 0 && reconnect_max_s >= reconnect_min_s))
    return Status::BadInput("reconnect backoff must be > 0 (max ≥ min)");
  if (!(idle_timeout_s >= 0)) return Status::BadInput("idle_timeout_s must be ≥ 0");
  if (max_data_resets < 1) return Status::BadInput("max_data_resets must be ≥ 1");
  if (journal.empty()) return Status::BadInput("the collector needs a journal file");
  return Status::Ok();
}

nlohmann::json CollectorCounters::ToJson() const {
  return {{"reads", reads},
          {"writes", writes},
          {"api_errors", api_errors},
          {"connection_errors", connection_errors},
          {"reconnects", reconnects},
          {"points_stored", points_stored},
          {"duplicates", duplicates},
          {"resumed_after_restart", resumed},
          {"lost_writes_repeated", lost_writes},
          {"visibility_waits", visibility_waits},
          {"arms", arms}};
}

long CollectorReport::points_total() const {
  long n = 0;
  for (const auto& s : sessions) n += static_cast<long>(s.points.size());
  return n;
}

namespace {

// Messages for the points of a session whose values are out of range.
std::vector<std::string> PointErrors(const Session& s) {
  std::vector<std::string> out;
  for (const auto& p : s.points) {
    for (int a = 0; a < 3; ++a) {
      if (p.decoded.flags[a] == AxisFlag::kOverflow) {
        out.push_back("OVERFLOW: point " + std::to_string(p.id) + ", axis " + AxisName(a) + ", |deviation| >= 0.1 mm");
      } else if (p.decoded.flags[a] == AxisFlag::kRangeError) {
        out.push_back("RANGE_ERROR: point " + std::to_string(p.id) + ", axis " + AxisName(a) +
                      ": the value is malformed (not a whole number, or 1000..2047 without the OVERFLOW sentinel)");
      }
    }
  }
  return out;
}

}  // namespace

nlohmann::json CollectorReport::ToJson() const {
  nlohmann::json sessions_json = nlohmann::json::array();
  for (const auto& s : sessions) {
    nlohmann::json j = {{"q", s.q},
                        {"status", SessionStatusName(s.status)},
                        {"points", s.points.size()},
                        {"last_id", s.last_id()},
                        {"finished_count", s.finished_count},
                        {"errors", s.errors},
                        {"warnings", s.warnings},
                        {"point_errors", PointErrors(s)}};
    if (!s.abort_reason.empty()) j["abort_reason"] = s.abort_reason;
    sessions_json.push_back(j);
  }
  return {{"ok", ok},
          {"fatal", fatal},
          {"sessions", sessions_json},
          {"points_received", points_total()},
          {"counters", counters.ToJson()},
          {"elapsed_s", elapsed_s},
          {"points_per_s", points_per_s()}};
}

namespace {

struct Observation {
  MacroValue c;
  std::array<MacroValue, 3> data{};
  MacroValue q, a;
  WordKind kind = WordKind::kIllegal;
  ControlWord word;
  bool data_empty = true;
  double qv() const { return q.value_or(0.0); }
  bool Same(const Observation& o) const { return c == o.c && data == o.data && q == o.q && a == o.a; }
  std::array<double, 3> DataValues() const {
    return {data[0].value_or(std::nan("")), data[1].value_or(0.0), data[2].value_or(0.0)};
  }
};

std::string Text(const MacroValue& v) { return v ? FormatExact(*v) : std::string("vacant"); }

// Thrown nowhere: the outcome of one decision.
enum class Outcome { kWait, kAgain, kFatal };

class Collector {
 public:
  Collector(MacroTransport& transport, Clock& clock, const CollectorOptions& options, const CollectorHook& hook)
      : t_(transport), clock_(clock), o_(options), hook_(hook), block_(options.block) {}

  Result<CollectorReport> Run() {
    FL_RETURN_IF_ERROR(o_.Validate());
    FL_ASSIGN_OR_RETURN(journal_, Journal::Open(o_.journal, o_.fsync));
    const double start = clock_.NowS();
    double last_change = start;
    std::optional<Observation> last;
    std::unique_ptr<Progress> progress;
    if (o_.progress && o_.expect_points > 0) {
      progress = std::make_unique<Progress>("collecting points", static_cast<std::size_t>(o_.expect_points) * o_.runs);
      progress->Advance(static_cast<std::size_t>(StoredPoints()));
    }
    progress_ = progress.get();
    for (;;) {
      if (o_.idle_timeout_s > 0 && clock_.NowS() - last_change > o_.idle_timeout_s) {
        Fatal("IDLE_TIMEOUT",
              "the block did not change for " + FormatFixed(o_.idle_timeout_s, 1) +
                  " s; the measuring program is not running or stopped in an alarm (the journal is kept: "
                  "run the collector again to resume)");
        break;
      }
      if (!EnsureConnected()) continue;
      const auto obs = Read();
      if (!obs) continue;
      Hook(CollectorStep::kAfterRead);
      if (!last || !last->Same(*obs)) {
        last = obs;
        last_change = clock_.NowS();
      }
      if (Done(*obs)) break;
      const Outcome outcome = Decide(*obs);
      if (outcome == Outcome::kFatal) break;
      if (outcome == Outcome::kWait) {
        clock_.SleepS(clock_.NowS() - last_change > o_.slow_after_s ? o_.poll_slow_s : o_.poll_s);
      }
    }
    if (progress) progress->Finish();
    if (!journal_status_.ok()) return journal_status_;
    report_.sessions = journal_.sessions();
    report_.elapsed_s = clock_.NowS() - start;
    report_.points_stored_rate_ = report_.elapsed_s > 0 ? report_.counters.points_stored / report_.elapsed_s : 0;
    return report_;
  }

 private:
  void Hook(CollectorStep step) {
    if (hook_) hook_(step);
  }

  long StoredPoints() const {
    long n = 0;
    for (const auto& s : journal_.sessions()) n += static_cast<long>(s.points.size());
    return n;
  }
  int FinishedRuns() const {
    int n = 0;
    for (const auto& s : journal_.sessions()) {
      n += (s.status == SessionStatus::kComplete || s.status == SessionStatus::kIncomplete) ? 1 : 0;
    }
    return n;
  }
  bool Done(const Observation& o) const {
    if (FinishedRuns() < o_.runs) return false;
    // Wait until the FINISHED word of the last run has been answered with IDLE.
    return o.kind != WordKind::kFinished;
  }

  bool EnsureConnected() {
    if (connected_) return true;
    const Status s = t_.Connect();
    if (s.ok()) {
      connected_ = true;
      if (had_connection_) ++report_.counters.reconnects;
      had_connection_ = true;
      backoff_s_ = o_.reconnect_min_s;
      return true;
    }
    log::Warn("link: cannot connect to {}: {}; next try in {:.1f} s", t_.Describe(), s.message(), backoff_s_);
    clock_.SleepS(backoff_s_);
    backoff_s_ = std::min(o_.reconnect_max_s, backoff_s_ * 2);
    return false;
  }

  // A failed call: connection gone → reconnect; refused → a short pause before the next read.
  void CallFailed(const Status& s, const char* what) {
    if (s.code() == StatusCode::kIoError) {
      ++report_.counters.connection_errors;
      connected_ = false;
      t_.Disconnect();
      log::Debug("link: {} failed, connection lost: {}", what, s.message());
    } else {
      ++report_.counters.api_errors;
      log::Debug("link: {} refused: {}", what, s.message());
      clock_.SleepS(o_.poll_s);
    }
  }

  std::optional<Observation> Read() {
    ++report_.counters.reads;
    auto values = t_.ReadRange(block_.base, block_.size());
    if (!values.ok()) {
      CallFailed(values.status(), "read");
      return std::nullopt;
    }
    if (static_cast<int>(values->size()) != block_.size()) {
      CallFailed(Status::IoError("the controller answered with the wrong number of values"), "read");
      return std::nullopt;
    }
    Observation o;
    const auto& v = *values;
    o.c = v[0];
    for (int k = 0; k < block_.data_count(); ++k) o.data[k] = v[1 + k];
    o.q = v[block_.run_counter() - block_.base];
    o.a = v[block_.alarm() - block_.base];
    o.kind = o.c ? ClassifyControlValue(*o.c, &o.word) : WordKind::kIdle;
    if (block_.layout == Layout::kPacked) {
      o.data_empty = !o.data[0] || *o.data[0] == kEmptyData;
    } else {
      o.data_empty = false;
      for (int k = 0; k < 3; ++k) o.data_empty = o.data_empty || !o.data[k] || *o.data[k] == kSplitEmpty;
    }
    return o;
  }

  // A write the controller refused (an error code) was not applied and is made again at once, up to
  // kRefusedRetries times; a write whose outcome is unknown (connection lost) is not repeated: the
  // caller reads the block and decides afresh.
  static constexpr int kRefusedRetries = 20;
  bool Write(int address, const std::vector<double>& values, const char* what) {
    for (int attempt = 0;; ++attempt) {
      ++report_.counters.writes;
      const Status s = t_.WriteRange(address, values);
      if (s.ok()) return true;
      CallFailed(s, what);
      if (s.code() == StatusCode::kIoError || attempt >= kRefusedRetries) return false;
    }
  }
  bool WriteEmpty() {
    if (block_.layout == Layout::kPacked) return Write(block_.data(), {kEmptyData}, "data reset");
    return Write(block_.data(), {kSplitEmpty, kSplitEmpty, kSplitEmpty}, "data reset");
  }
  bool WriteControl(const ControlWord& w) { return Write(block_.control(), {EncodeControl(w)}, "control write"); }

  bool JournalOk(const Status& s) {
    if (s.ok()) return true;
    journal_status_ = s;
    return false;
  }

  Outcome Fatal(const std::string& code, const std::string& text) {
    report_.ok = false;
    report_.fatal = code + ": " + text;
    log::Error("link: {}", report_.fatal);
    if (journal_.open() != nullptr) JournalOk(journal_.AddError(code, text));
    return Outcome::kFatal;
  }

  bool CloseAborted(const std::string& reason) {
    log::Warn("link: session of run Q={} closed as ABORTED: {}", FormatExact(journal_.open()->q), reason);
    return JournalOk(journal_.Abort(reason));
  }

  Outcome Arm() {
    if (!WriteEmpty()) return Outcome::kAgain;
    if (!WriteControl(MeasuringWord(0))) return Outcome::kAgain;
    ++report_.counters.arms;
    Hook(CollectorStep::kAfterArm);
    log::Info("link: block armed, waiting for the measuring program");
    return Outcome::kAgain;
  }

  bool WantArm(const Observation& o) const {
    if (FinishedRuns() >= o_.runs) return false;
    const auto& sessions = journal_.sessions();
    return sessions.empty() || o.qv() != sessions.back().q;
  }

  Outcome Decide(const Observation& o) {
    const Session* s = journal_.open();
    switch (o.kind) {
      case WordKind::kIdle:
        if (s != nullptr) {
          if (!CloseAborted("the block was reset to IDLE during the run")) return Outcome::kFatal;
        }
        return WantArm(o) ? Arm() : Outcome::kWait;
      case WordKind::kMeasuring:
        return OnMeasuring(o, s);
      case WordKind::kPointReady:
        return OnReady(o, s);
      case WordKind::kFinished:
        return OnFinished(o, s);
      case WordKind::kAbort:
        if (s != nullptr && !CloseAborted("the block shows ABORT")) return Outcome::kFatal;
        return Fatal("ABORTED",
                     "the measuring run was stopped with ABORT (stop_on_range); reset the alarm on the machine");
      case WordKind::kIllegal:
        break;
    }
    return Fatal("PROTOCOL_ERROR", "the control word is " + Text(o.c) +
                                       ", which is none of the legal words; the session is invalid and someone has to "
                                       "reset the block (C = 0) on the controller by hand");
  }

  Outcome OnMeasuring(const Observation& o, const Session* s) {
    const int p = o.word.point;
    if (p == 0) {
      if (s != nullptr && o.qv() != s->q) {
        if (!CloseAborted("the run was restarted (Q " + FormatExact(s->q) + " -> " + FormatExact(o.qv()) + ")"))
          return Outcome::kFatal;
      } else if (s != nullptr && s->last_id() > 0) {
        return Fatal("PROTOCOL_ERROR", "the block was re-armed during run Q=" + FormatExact(s->q) + " after point " +
                                           std::to_string(s->last_id()));
      }
      return Outcome::kWait;
    }
    if (s != nullptr) {
      if (o.qv() != s->q) {
        if (!CloseAborted("the run was restarted (Q " + FormatExact(s->q) + " -> " + FormatExact(o.qv()) + ")"))
          return Outcome::kFatal;
        return WantArm(o) ? Arm() : Outcome::kWait;
      }
      if (s->last_id() != p) {
        return Fatal("LOST_POINTS", "the block shows point " + std::to_string(p) +
                                        " acknowledged but the journal ends at " + std::to_string(s->last_id()));
      }
      return Outcome::kWait;
    }
    const auto& sessions = journal_.sessions();
    if (!sessions.empty() && o.qv() != sessions.back().q) return WantArm(o) ? Arm() : Outcome::kWait;
    if (!sessions.empty()) return Outcome::kWait;  // our last acknowledgement of a closed session
    return Fatal("LOST_POINTS",
                 "the block shows point " + std::to_string(p) + " of run Q=" + FormatExact(o.qv()) +
                     " acknowledged but the journal " + journal_.path().string() +
                     " has no session: the points were collected elsewhere or the journal was lost; reset "
                     "the block (C = 0) to start over");
  }

  Outcome OnReady(const Observation& o, const Session* s) {
    const int i = o.word.point;
    if (s != nullptr && o.qv() != s->q) {
      if (!CloseAborted("the run was restarted (Q " + FormatExact(s->q) + " -> " + FormatExact(o.qv()) + ")"))
        return Outcome::kFatal;
      s = nullptr;
    }
    if (s == nullptr) {
      const auto& sessions = journal_.sessions();
      if (!sessions.empty() && sessions.back().q == o.qv() && sessions.back().status == SessionStatus::kAborted &&
          i == sessions.back().last_id() && o_.stop_on_range) {
        return Acknowledge(o, i, true);  // killed between journaling the abort and writing ABORT
      }
      if (o.data_empty) return WaitVisible(o, i);
      if (!JournalOk(journal_.OpenSession(o.qv(), clock_.NowS()))) return Outcome::kFatal;
      log::Info("link: run Q={} started", FormatExact(o.qv()));
      s = journal_.open();
      if (i > 1 && !JournalOk(journal_.AddError(
                       "GAP", "points 1.." + std::to_string(i - 1) + " of this run were never received"))) {
        return Outcome::kFatal;
      }
    }
    const int last = s->last_id();
    if (i < last) {
      return Fatal("PROTOCOL_ERROR", "point " + std::to_string(i) + " arrived after point " + std::to_string(last) +
                                         " in the same run Q=" + FormatExact(s->q));
    }
    if (i == last) return AcknowledgeStored(o, *s, i);
    if (o.data_empty) return WaitVisible(o, i);
    if (i > last + 1) {
      const std::string missing =
          i == last + 2 ? std::to_string(last + 1) : std::to_string(last + 1) + ".." + std::to_string(i - 1);
      log::Error("link: GAP: point {} arrived after {}; missing {}", i, last, missing);
      if (!JournalOk(journal_.AddError("GAP", "points " + missing + " were never received (point " + std::to_string(i) +
                                                  " followed " + std::to_string(last) + ")"))) {
        return Outcome::kFatal;
      }
    }
    JournalPoint point;
    point.id = i;
    point.data = o.DataValues();
    point.t_s = clock_.NowS();
    Result<DecodedPoint> decoded =
        block_.layout == Layout::kPacked ? UnpackData(*o.data[0]) : DecodeSplit({*o.data[0], *o.data[1], *o.data[2]});
    if (decoded.ok()) {
      point.decoded = *decoded;
    } else {
      point.decoded.flags = {AxisFlag::kRangeError, AxisFlag::kRangeError, AxisFlag::kRangeError};
    }
    for (int a = 0; a < 3; ++a) {
      if (point.decoded.flags[a] == AxisFlag::kOverflow) {
        log::Error("link: point {}, axis {}: |deviation| >= 0.1 mm (OVERFLOW); the collection goes on", i, AxisName(a));
      } else if (point.decoded.flags[a] == AxisFlag::kRangeError) {
        log::Error("link: point {}, axis {}: malformed value (RANGE_ERROR, data {}); the collection goes on", i,
                   AxisName(a), Text(o.data[block_.layout == Layout::kPacked ? 0 : a]));
      }
    }
    if (!JournalOk(journal_.AddPoint(point))) return Outcome::kFatal;
    stored_here_.insert(std::make_pair(o.qv(), i));
    ++report_.counters.points_stored;
    if (progress_ != nullptr) progress_->Advance();
    Hook(CollectorStep::kAfterPersist);
    const bool abort = o_.stop_on_range && !point.decoded.ok();
    if (abort && !CloseAborted("stop_on_range: point " + std::to_string(i) + " is out of range"))
      return Outcome::kFatal;
    return Acknowledge(o, i, abort);
  }

  Outcome WaitVisible(const Observation& o, int i) {
    ++report_.counters.visibility_waits;
    if (vis_q_ != o.qv() || vis_id_ != i) {
      vis_q_ = o.qv();
      vis_id_ = i;
      vis_since_ = clock_.NowS();
      vis_reported_ = false;
    } else if (!vis_reported_ && clock_.NowS() - vis_since_ > o_.visibility_timeout_s) {
      vis_reported_ = true;
      const std::string text =
          "point " + std::to_string(i) + ": POINT_READY but the data word stayed EMPTY for more than " +
          FormatFixed(o_.visibility_timeout_s, 1) + " s (the machine's write is not visible); still waiting";
      log::Error("link: VISIBILITY_TIMEOUT: {}", text);
      if (journal_.open() != nullptr && !JournalOk(journal_.AddWarning("VISIBILITY_TIMEOUT", text)))
        return Outcome::kFatal;
    }
    return Outcome::kWait;
  }

  // POINT_READY for the point stored last. With the data word not EMPTY: the machine sent it again
  // (a DUPLICATE) or a kill came before the data reset; either way reset the data and hand back. With
  // the data EMPTY the word cannot tell a hand-back that never landed (or a kill after the data reset)
  // from a repeat whose data write is not visible yet; handing back at once would leave that data
  // write to land later, where the next point could be read with it. So the collector waits T_vis
  // for the data to appear, and only then hands back again.
  Outcome AcknowledgeStored(const Observation& o, const Session& s, int i) {
    const auto key = std::make_pair(s.q, i);
    // Stored by this process and never handed back: the machine cannot have seen an acknowledgement
    // of i, so it cannot be repeating it; hand back at once.
    const bool unambiguous = stored_here_.count(key) != 0 && hand_back_sent_.count(key) == 0;
    if (o.data_empty && !unambiguous) {
      if (settle_q_ != s.q || settle_id_ != i || settle_generation_ != acks_) {
        settle_q_ = s.q;
        settle_id_ = i;
        settle_generation_ = acks_;
        settle_since_ = clock_.NowS();
        return Outcome::kWait;
      }
      if (clock_.NowS() - settle_since_ < o_.visibility_timeout_s) return Outcome::kWait;
    }
    if (acked_.count(key) != 0) {
      if (o.data_empty) {
        ++report_.counters.lost_writes;  // our hand-back did not land
      } else {
        ++report_.counters.duplicates;
        const bool same = o.DataValues() == s.points.back().data;
        const std::string text = "point " + std::to_string(i) + " was sent again" +
                                 (same ? "" : " with different data") + "; the first copy is kept";
        log::Warn("link: DUPLICATE: {}", text);
        if (!JournalOk(journal_.AddWarning("DUPLICATE", text))) return Outcome::kFatal;
      }
    } else {
      ++report_.counters.resumed;
    }
    return Acknowledge(o, i, o_.stop_on_range && !s.points.back().decoded.ok());
  }

  // data := EMPTY until the read-back shows it, then the hand-back.
  Outcome Acknowledge(const Observation& o, int i, bool abort) {
    if (!o.data_empty) {
      bool empty = false;
      for (int attempt = 0; attempt < o_.max_data_resets && !empty; ++attempt) {
        if (!WriteEmpty()) return Outcome::kAgain;
        Hook(CollectorStep::kAfterDataReset);
        const auto v = Read();
        if (!v) return Outcome::kAgain;
        if (v->kind != WordKind::kPointReady || v->word.point != i || v->qv() != o.qv()) return Outcome::kAgain;
        empty = v->data_empty;
        if (!empty) ++report_.counters.lost_writes;
      }
      if (!empty) {
        return Fatal("WRITE_FAILED", "the data word could not be reset to EMPTY in " +
                                         std::to_string(o_.max_data_resets) + " attempts at point " +
                                         std::to_string(i));
      }
    }
    hand_back_sent_.insert(std::make_pair(o.qv(), i));  // from here on it may have landed
    if (!WriteControl(abort ? AbortWord() : MeasuringWord(i))) return Outcome::kAgain;
    acked_.insert(std::make_pair(o.qv(), i));
    ++acks_;
    Hook(CollectorStep::kAfterAck);
    return Outcome::kAgain;  // the next read is the control word's read-back
  }

  Outcome OnFinished(const Observation& o, const Session* s) {
    const int n = o.word.point;
    if (s != nullptr && o.qv() != s->q) {
      if (!CloseAborted("the run was restarted (Q " + FormatExact(s->q) + " -> " + FormatExact(o.qv()) + ")"))
        return Outcome::kFatal;
      s = nullptr;
    }
    if (s != nullptr) {
      if (n != s->last_id()) {
        if (!JournalOk(journal_.AddError("COUNT_MISMATCH", "the program finished with N = " + std::to_string(n) +
                                                               " but the last point received is " +
                                                               std::to_string(s->last_id())))) {
          return Outcome::kFatal;
        }
      }
      if (o_.expect_points > 0 && n != o_.expect_points) {
        if (!JournalOk(journal_.AddError("COUNT_MISMATCH", "the program finished with N = " + std::to_string(n) +
                                                               " but " + std::to_string(o_.expect_points) +
                                                               " points were expected"))) {
          return Outcome::kFatal;
        }
      }
      const Session& now = *journal_.open();
      const SessionStatus status = now.errors.empty() ? SessionStatus::kComplete : SessionStatus::kIncomplete;
      if (!JournalOk(journal_.End(n, status))) return Outcome::kFatal;
      log::Info("link: run Q={} finished: {} points, {}", FormatExact(now.q), now.points.size(),
                SessionStatusName(status));
      Hook(CollectorStep::kAfterEnd);
    } else {
      const auto& sessions = journal_.sessions();
      const bool ended_here =
          !sessions.empty() && sessions.back().q == o.qv() &&
          (sessions.back().status == SessionStatus::kComplete || sessions.back().status == SessionStatus::kIncomplete);
      if (!ended_here) {
        return Fatal("LOST_POINTS", "the block shows run Q=" + FormatExact(o.qv()) + " FINISHED with " +
                                        std::to_string(n) + " points, but the journal has no such session");
      }
    }
    if (!WriteControl(IdleWord())) return Outcome::kAgain;
    return Outcome::kAgain;
  }

  MacroTransport& t_;
  Clock& clock_;
  CollectorOptions o_;
  const CollectorHook& hook_;
  BlockLayout block_;
  Journal journal_;
  Status journal_status_;
  CollectorReport report_;
  Progress* progress_ = nullptr;
  bool connected_ = false, had_connection_ = false;
  double backoff_s_ = 0.5;
  std::set<std::pair<double, int>> acked_;
  std::set<std::pair<double, int>> stored_here_, hand_back_sent_;
  long acks_ = 0;
  double settle_q_ = std::numeric_limits<double>::quiet_NaN();
  int settle_id_ = -1;
  long settle_generation_ = -1;
  double settle_since_ = 0;
  double vis_q_ = std::numeric_limits<double>::quiet_NaN();
  int vis_id_ = -1;
  double vis_since_ = 0;
  bool vis_reported_ = false;
};

}  // namespace

Result<CollectorReport> Collect(MacroTransport& transport, Clock& clock, const CollectorOptions& options,
                                const CollectorHook& hook) {
  Collector collector(transport, clock, options, hook);
  return collector.Run();
}

Result<SelfTestReport> RunSelfTest(MacroTransport& transport, const BlockLayout& block) {
  FL_RETURN_IF_ERROR(transport.Connect());
  FL_ASSIGN_OR_RETURN(const auto values, transport.ReadRange(block.base, 1));
  if (values.size() != 1) return Status::IoError("the controller answered with the wrong number of values");
  if (values[0] && *values[0] != 0) {
    return Status::Failed("the block's control word is " + FormatExact(*values[0]) +
                          ", not IDLE: the self-test runs only while no measurement is open");
  }
  SelfTestReport report;
  report.passed = true;
  for (const double value : {static_cast<double>(kMaxDataWord), 2078508007.0}) {
    FL_RETURN_IF_ERROR(transport.Write(block.data(), value));
    FL_ASSIGN_OR_RETURN(const auto back, transport.ReadRange(block.data(), 1));
    const double read = back.empty() || !back[0] ? std::nan("") : *back[0];
    report.written_read.emplace_back(value, read);
    if (read != value) report.passed = false;
  }
  FL_RETURN_IF_ERROR(transport.Write(block.data(), kEmptyData));
  report.message =
      report.passed
          ? "both data words read back exactly: the PACKED layout is safe on this controller and API path"
          : "a data word came back changed: the controller or the API keeps too few digits; configure the SPLIT layout";
  return report;
}

Status WriteCollection(const std::filesystem::path& path, const std::vector<Session>& sessions) {
  std::ostringstream out;
  out << "# formloop link collect: every point collected, per session\n";
  out << "session,q,status,id,data0,data1,data2,vx,vy,vz,dx_mm,dy_mm,dz_mm,flags,t_s\n";
  for (std::size_t k = 0; k < sessions.size(); ++k) {
    const Session& s = sessions[k];
    for (const auto& p : s.points) {
      out << (k + 1) << "," << FormatExact(s.q) << "," << SessionStatusName(s.status) << "," << p.id;
      for (double d : p.data) out << "," << FormatExact(d);
      for (int v : p.decoded.v) out << "," << v;
      std::string flags;
      for (int a = 0; a < 3; ++a) {
        out << ","
            << (p.decoded.flags[a] == AxisFlag::kOk ? FormatFixed(p.decoded.v[a] * kValueUnitMm, 4) : std::string());
        if (p.decoded.flags[a] != AxisFlag::kOk)
          flags += std::string(flags.empty() ? "" : " ") + AxisName(a) + ":" + AxisFlagName(p.decoded.flags[a]);
      }
      out << "," << (flags.empty() ? "OK" : flags) << "," << FormatExact(p.t_s) << "\n";
    }
  }
  return WriteFileAtomic(path, out.str());
}

}  // namespace formloop::cnc

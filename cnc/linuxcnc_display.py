#!/usr/bin/python3
# formloop LinuxCNC configuration: the DISPLAY program.
#
# formloop's DISPLAY program for LinuxCNC (cnc/linuxcnc_display.py, written into every configuration by
# `formloop machine linuxcnc config`). LinuxCNC starts it as `DISPLAY -ini INI` once the controller is up
# and shuts the controller down when it exits (the exit code becomes `linuxcnc`'s own).
#
# It runs one program and says what happened, in a JSON file:
#   1. LinuxCNC's own interpreter (the `gcode` module the AXIS preview uses) reads the whole program
#      without moving anything; an error there is reported with its line and the machine never starts.
#   2. estop reset -> machine on -> home all -> auto -> open -> run -> wait until the interpreter is idle,
#      collecting the error channel; an error aborts the program and is reported with its line: the one
#      the message names, else the task's current line (the motion and read lines are kept beside it).
#   3. abort, machine off, estop, and the result file.
#
# Inputs (environment, set by formloop): FORMLOOP_PROGRAM (absolute path of the program),
# FORMLOOP_RESULT (where the JSON goes), FORMLOOP_TIMEOUT_S (the program's time limit, s).
# Exit code: 0 the program ran to its end without an error, 1 otherwise.
#
# Result file (written atomically: temporary file + rename):
#   {"format": "formloop linuxcnc result", "version": 1, "program": ..., "ok": true|false,
#    "stage": "preview|reset|on|home|auto|open|run|done", "errors": [{"stage", "text", "line", ...}],
#    "messages": [texts the program printed], "seconds": {"preview": .., "start": .., "run": ..}}
import json
import os
import re
import sys
import time

import gcode
import linuxcnc


class PreviewCanon:
    """The canonical-command sink for gcode.parse: it only has to answer the interpreter's questions."""

    def __init__(self, parameter_file):
        self.parameter_file = parameter_file

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return lambda *args, **kwargs: None

    def get_external_length_units(self):
        return 1.0 / 25.4  # the configuration is in mm

    def get_external_angular_units(self):
        return 1.0

    def get_axis_mask(self):
        return 7  # X, Y, Z

    def get_tool(self, pocket):
        return (-1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0)

    def get_block_delete(self):
        return False

    def check_abort(self):
        return False

    def change_tool(self, pocket):
        pass

    def next_line(self, state):
        pass


def preview(program, scratch_dir):
    """None, or the error of LinuxCNC's interpreter reading the program: (line, text, block)."""
    os.makedirs(scratch_dir, exist_ok=True)
    here = os.getcwd()
    os.chdir(scratch_dir)  # the interpreter writes its parameter file into the current folder
    try:
        code, sequence = gcode.parse(program, PreviewCanon(os.path.join(scratch_dir, "preview.var")), "G21", "")
    finally:
        os.chdir(here)
    if code <= gcode.MIN_ERROR:
        return None
    # gcode.parse returns the sequence number one past the offending line (LinuxCNC 2.9; checked by
    # tests/linuxcnc: an error on line k gives k + 1).
    line = max(1, sequence - 1)
    with open(program, encoding="utf-8", errors="replace") as f:
        lines = f.read().splitlines()
    block = lines[line - 1].strip() if line <= len(lines) else ""
    return line, gcode.strerror(code), block


def intended_abort(program, text):
    """True when `text` is one of the program's own (abort, TEXT) alarms: the preview reaches one when the
    program waits on inputs (M66) that only the running controller gives it."""
    with open(program, encoding="utf-8", errors="replace") as f:
        alarms = set(re.findall(r"\(\s*abort\s*,([^)]*)\)", f.read(), flags=re.IGNORECASE))
    return text.strip() in {a.strip() for a in alarms}


class Machine:
    def __init__(self, result):
        self.stat = linuxcnc.stat()
        self.command = linuxcnc.command()
        self.errors = linuxcnc.error_channel()
        self.result = result

    def drain(self, stage):
        """Moves everything on the error channel into the result; True if any of it was an error."""
        failed = False
        while True:
            message = self.errors.poll()
            if not message:
                return failed
            kind, text = message
            if kind in (linuxcnc.NML_ERROR, linuxcnc.OPERATOR_ERROR):
                self.stat.poll()
                # The interpreter reads ahead of motion, so an error it raises while motion is still on an
                # earlier line names its own line in the text ("Linear move on line 3 would exceed X's
                # positive limit"). Otherwise the task's current line is the one that failed (a G38.2
                # without contact, or one that starts with the probe tripped, while motion_line still
                # names the move before it).
                named = re.search(r"\bline (\d+)\b", text)
                if named:
                    line = int(named.group(1))
                else:
                    line = self.stat.current_line if self.stat.current_line > 0 else self.stat.motion_line
                self.result["errors"].append({"stage": stage, "text": text.strip(), "line": line,
                                              "motion_line": self.stat.motion_line,
                                              "current_line": self.stat.current_line,
                                              "read_line": self.stat.read_line})
                failed = True
            else:
                self.result["messages"].append(text.strip())

    def wait(self, stage, done, timeout_s):
        """Polls until done(stat) or an error or the time limit; True when done."""
        self.result["stage"] = stage
        end = time.monotonic() + timeout_s
        while True:
            self.stat.poll()
            if done(self.stat):
                return not self.drain(stage)
            if self.drain(stage):
                return False
            if time.monotonic() > end:
                self.result["errors"].append({"stage": stage, "text": "no answer within %g s" % timeout_s,
                                              "line": self.stat.current_line})
                return False
            time.sleep(0.005)

    def start(self):
        c, s = self.command, linuxcnc
        c.state(s.STATE_ESTOP_RESET)
        if not self.wait("reset", lambda st: st.task_state == s.STATE_ESTOP_RESET, 10):
            return False
        c.state(s.STATE_ON)
        if not self.wait("on", lambda st: st.task_state == s.STATE_ON, 10):
            return False
        c.home(-1)
        if not self.wait("home", lambda st: all(st.homed[j] for j in range(st.joints)), 30):
            return False
        c.mode(s.MODE_AUTO)
        return self.wait("auto", lambda st: st.task_mode == s.MODE_AUTO, 10)

    def run(self, program, timeout_s):
        c, s = self.command, linuxcnc
        c.program_open(program)
        if not self.wait("open", lambda st: st.file == program, 10):
            return False
        c.auto(s.AUTO_RUN, 0)
        # The task has taken the command once it echoes its serial number; from then on an idle
        # interpreter means the program has ended (a short one may already be done).
        serial = c.serial
        if not self.wait("run", lambda st: st.echo_serial_number >= serial, 10):
            return False
        if not self.wait("run", lambda st: st.interp_state == s.INTERP_IDLE, timeout_s):
            if not self.result["errors"] or self.result["errors"][-1]["text"].startswith("no answer"):
                st = self.stat
                text = "the program did not end within %g s" % timeout_s
                line = st.current_line or st.motion_line
                if not line and st.read_line:  # e.g. in a dwell: only how far the interpreter has read is known
                    text += " (the interpreter had read up to line %d)" % st.read_line
                self.result["errors"][-1:] = [{"stage": "run", "text": text, "line": line,
                                               "current_line": st.current_line, "motion_line": st.motion_line,
                                               "read_line": st.read_line}]
            return False
        return True

    def stop(self):
        """Abort, machine off, estop; messages after this are not the program's."""
        c, s = self.command, linuxcnc
        c.abort()
        c.wait_complete(5)
        c.state(s.STATE_OFF)
        c.state(s.STATE_ESTOP)
        c.wait_complete(5)


def write_result(path, result):
    temporary = "%s.tmp-%d" % (path, os.getpid())
    with open(temporary, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=2, sort_keys=True)
        f.write("\n")
    os.replace(temporary, path)


def main():
    program = os.path.abspath(os.environ["FORMLOOP_PROGRAM"])
    result_path = os.environ["FORMLOOP_RESULT"]
    timeout_s = float(os.environ.get("FORMLOOP_TIMEOUT_S", "600"))
    result = {"format": "formloop linuxcnc result", "version": 1, "program": program, "ok": False,
              "stage": "preview", "errors": [], "messages": [], "seconds": {}}
    t0 = time.monotonic()
    try:
        # The controller's status first: its first poll maps LinuxCNC's tool data, which the interpreter
        # reads for T words (without it gcode.parse crashes on the first T).
        machine = Machine(result)
        machine.stat.poll()
        failure = preview(program, os.path.join(os.path.dirname(result_path), "preview"))
        result["seconds"]["preview"] = round(time.monotonic() - t0, 3)
        if failure and intended_abort(program, failure[1]):
            result["messages"].append("preview: reading stopped at line %d, the program's own alarm (%s), which "
                                      "depends on inputs only the running controller gives" % (failure[0],
                                                                                             failure[1].strip()))
        elif failure:
            line, text, block = failure
            result["errors"].append({"stage": "preview", "line": line, "text": text, "block": block})
            return 1
        t1 = time.monotonic()
        started = machine.start()
        result["seconds"]["start"] = round(time.monotonic() - t1, 3)
        if started:
            t2 = time.monotonic()
            result["ok"] = machine.run(program, timeout_s)
            result["seconds"]["run"] = round(time.monotonic() - t2, 3)
            if result["ok"]:
                result["stage"] = "done"
        machine.stop()
        result["ok"] = result["ok"] and not result["errors"]
        return 0 if result["ok"] else 1
    except Exception as e:  # anything unexpected still ends in a result file and a controller shutdown
        result["errors"].append({"stage": result["stage"], "line": 0, "text": "display program: %r" % (e,)})
        return 1
    finally:
        write_result(result_path, result)


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/python3
# formloop LinuxCNC configuration: the link component.
#
# The handshake's variable block (spec/tuning-and-link.md §7.2) on LinuxCNC (cnc/linuxcnc_link.h). The
# machine-side program (cnc/machine_program.h, dialect linuxcnc) writes block address k with
# M68 E<k> Q<value> (motion.analog-out-k) and commits the write by toggling motion.digital-out-k (M64/M65
# P<k>; the configuration wires it back to motion.digital-in-k, where the program reads its level); it
# reads address k with M66 E<k> L0 (motion.analog-in-k into #5399). formloop's collector reads and writes
# the same addresses through this component's socket. The component keeps one register per address, the
# last value written by either side, and drives motion.analog-in-k with it, so both sides see one shared
# variable, as a macro variable is on other controllers:
#
#   a machine write is the commit bit of its address changing level: the register takes the machine's
#   output then (M68 reaches motion before the M64/M65 after it), so every write arrives, a value equal
#   to the last one included;
#   a collector write replaces the register at once.
# The component knows nothing of the protocol: what the words mean is the collector's (cnc/collector.h).
#
# Argument: PORTS (e.g. 4: addresses 0..3).
# The socket: FORMLOOP_LINK_SOCKET (set by formloop's run); without it the registers still join the two
# sides of each address. Protocol, one line each way per request (values in Python's repr, exact):
#   R <start> <count>            ->  OK <v> ...
#   W <start> <v> [<v> ...]      ->  OK
#   anything else                ->  ERR <why>
import os
import select
import signal
import socket
import sys

import hal

POLL_S = 0.0005  # the machine side is looked at every 0.5 ms (a servo period is 1 ms)


class Link:
    def __init__(self, ports):
        self.ports = ports
        self.hal = hal.component("formloop-link")
        for k in range(ports):
            self.hal.newpin("machine-%d" % k, hal.HAL_FLOAT, hal.HAL_IN)
            self.hal.newpin("commit-%d" % k, hal.HAL_BIT, hal.HAL_IN)
            self.hal.newpin("block-%d" % k, hal.HAL_FLOAT, hal.HAL_OUT)
        self.registers = [0.0] * ports
        self.commits = [False] * ports
        self.hal.ready()

    def watch_machine(self):
        # The commit bits first, then the values: a value is set before its commit.
        commits = [bool(self.hal["commit-%d" % k]) for k in range(self.ports)]
        for k in range(self.ports):
            if commits[k] != self.commits[k]:
                self.registers[k] = self.hal["machine-%d" % k]
        self.commits = commits
        self.publish()

    def publish(self):
        for k in range(self.ports):
            self.hal["block-%d" % k] = self.registers[k]

    def answer(self, line):
        words = line.split()
        try:
            if len(words) == 3 and words[0] == "R":
                start, count = int(words[1]), int(words[2])
                if start < 0 or count < 1 or start + count > self.ports:
                    return "ERR addresses %d..%d are not all in 0..%d" % (start, start + count - 1, self.ports - 1)
                self.watch_machine()
                return "OK " + " ".join(repr(v) for v in self.registers[start:start + count])
            if len(words) >= 3 and words[0] == "W":
                start, values = int(words[1]), [float(v) for v in words[2:]]
                if start < 0 or start + len(values) > self.ports:
                    return "ERR addresses %d..%d are not all in 0..%d" % (start, start + len(values) - 1,
                                                                         self.ports - 1)
                self.watch_machine()
                self.registers[start:start + len(values)] = values
                self.publish()
                return "OK"
        except ValueError as e:
            return "ERR %s" % e
        return "ERR expected 'R start count' or 'W start value...'"


def serve(link, path):
    server = None
    if path:
        if os.path.exists(path):
            os.unlink(path)
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        server.bind(path)
        server.listen(1)
    clients, buffers = [], {}
    while True:
        link.watch_machine()
        readable = select.select(([server] if server else []) + clients, [], [], POLL_S)[0]
        for s in readable:
            if s is server:
                client, _ = server.accept()
                clients.append(client)
                buffers[client] = b""
                continue
            chunk = s.recv(65536)
            if not chunk:
                clients.remove(s)
                del buffers[s]
                s.close()
                continue
            buffers[s] += chunk
            while b"\n" in buffers[s]:
                line, buffers[s] = buffers[s].split(b"\n", 1)
                s.sendall((link.answer(line.decode("ascii", "replace")) + "\n").encode("ascii"))


def main():
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # LinuxCNC's shutdown: leave HAL cleanly
    link = Link(int(sys.argv[1]) if len(sys.argv) > 1 else 4)
    try:
        serve(link, os.environ.get("FORMLOOP_LINK_SOCKET", ""))
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()

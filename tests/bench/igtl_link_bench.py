#!/usr/bin/env python3
"""The live link's cost to a run (docs/benchmarks.md "Live link"): the same headless scripted run
of heartsim, alone and with `--igtl` and a client connected, `--repeats` times each, alternating;
the minimum wall time of each (the run's own "ran N steps … ms wall" line) and the minimum
processor time heartsim took (user + system, all its threads: the link's own cost, which the
load of a shared machine does not change as it changes the wall time). The client reads every
message (the OpenIGTLink header's body size) and throws the bodies away, counting each type, as a
Slicer that keeps up would.

    python3 tests/bench/igtl_link_bench.py build/release/runtime/heartsim pat0.h5 gesture.csv --seconds 0.3
"""
import argparse
import re
import resource
import socket
import struct
import subprocess
import threading
import time


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def client(port, counts):
    """Connects (retrying while heartsim starts) and reads to the end: {type: messages}."""
    for _ in range(600):
        try:
            s = socket.create_connection(("127.0.0.1", port))
            break
        except OSError:
            time.sleep(0.1)
    else:
        return
    buffer = bytearray(1 << 20)
    with s:
        while True:
            header = b""
            while len(header) < 58:
                chunk = s.recv(58 - len(header))
                if not chunk:
                    return
                header += chunk
            kind = header[2:14].rstrip(b"\0").decode()
            counts[kind] = counts.get(kind, 0) + 1
            left = struct.unpack(">Q", header[42:50])[0]
            while left:
                n = s.recv_into(buffer, min(left, len(buffer)))
                if not n:
                    return
                left -= n


def run(heartsim, args, linked):
    counts = {}
    cmd = [heartsim, "run"] + args
    thread = None
    if linked:
        port = free_port()
        cmd += ["--igtl", str(port), "--igtl-wait", "60"]
        thread = threading.Thread(target=client, args=(port, counts))
        thread.start()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, check=True).stdout
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_ms = 1e3 * (after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    if thread:
        thread.join()
    m = re.search(r"ran (\d+) steps .*?([0-9.e+]+) ms simulated in ([0-9.e+]+) ms wall", out)
    return int(m.group(1)), float(m.group(2)), float(m.group(3)), counts, cpu_ms


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("heartsim")
    p.add_argument("scenario")
    p.add_argument("trajectory")
    p.add_argument("--seconds", default="0.3", help="simulated seconds of each run")
    p.add_argument("--backend", default="cpu")
    p.add_argument("--repeats", type=int, default=5)
    a = p.parse_args()
    args = [a.scenario, "--headless", "--backend", a.backend, "--real-time", "off", "--trajectory", a.trajectory, "--seconds", a.seconds]
    best = {False: None, True: None}
    cpu = {False: None, True: None}
    for i in range(a.repeats):
        for linked in (False, True):
            steps, simulated, wall, counts, cpu_ms = run(a.heartsim, args, linked)
            print(f"run {i + 1} {'with a client' if linked else 'alone'}: {steps} steps, {simulated:.4g} ms simulated in {wall:.5g} ms wall "
                  f"(real-time factor {simulated / wall:.3g}), heartsim's processor time {cpu_ms:.5g} ms"
                  f"{'; received ' + str(counts) if linked else ''}", flush=True)
            if best[linked] is None or wall < best[linked][2]:
                best[linked] = (steps, simulated, wall, counts)
            cpu[linked] = cpu_ms if cpu[linked] is None else min(cpu[linked], cpu_ms)
    alone, linked = best[False], best[True]
    print(f"\nminimum of {a.repeats}: alone {alone[2]:.5g} ms wall (real-time factor {alone[1] / alone[2]:.3g}), with a client "
          f"{linked[2]:.5g} ms (real-time factor {linked[1] / linked[2]:.3g}): the link costs {100 * (linked[2] / alone[2] - 1):.1f} % of the "
          f"wall time; processor time {cpu[False]:.5g} ms alone, {cpu[True]:.5g} ms with a client: {100 * (cpu[True] / cpu[False] - 1):.1f} %; "
          f"received {linked[3]}")


if __name__ == "__main__":
    main()

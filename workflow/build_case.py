"""One case's build for workflow/Snakefile: runs `heartprep build`, its output into the case's log,
and writes the case's build record, OUT/logs/<case>.build.json, the same record `heartprep batch`
writes for its own builds (tools/heartprep/command_batch.cpp): who built the scenario (the
workflow, and which run of it), how long the build took, when it ended, or why it failed. The
summary (`heartprep batch --no-build`) reads it, so it reports the case as `built by the workflow`
with this build's time.

    python3 build_case.py --record R --run-file F --case ID --key KEY --log LOG -- heartprep build ...

Exits with the build's status (128 + N for a build ended by signal N). The record says `running`
while the build runs, so a job the cluster kills outright (out of time or memory) leaves a record
that the summary reports as failed.
"""
import argparse
import datetime
import json
import os
import signal
import subprocess
import sys
import time


def write_record(path, fields):
    """Writes the record atomically: a summary never reads half of one."""
    temporary = "%s.%d.tmp" % (path, os.getpid())
    with open(temporary, "w", encoding="utf-8") as out:
        json.dump(fields, out, indent=2)
        out.write("\n")
    os.replace(temporary, path)


def last_error(log):
    """The last `heartprep: error: ` line of the log, without the prefix ("" when there is none)."""
    message = ""
    try:
        with open(log, encoding="utf-8", errors="replace") as lines:
            for line in lines:
                if line.startswith("heartprep: error: "):
                    message = line[len("heartprep: error: "):].rstrip("\n")
    except OSError:
        pass
    return message


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--record", required=True, help="the build record to write, OUT/logs/<case>.build.json")
    parser.add_argument("--run-file", required=True, help="OUT/logs/workflow-run: the run this job belongs to")
    parser.add_argument("--case", required=True)
    parser.add_argument("--key", required=True, help="the case's content key (heartprep batch --plan)")
    parser.add_argument("--log", required=True, help="the case's log: the build's stdout and stderr")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- heartprep build ...")
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("no build command after --")
    try:
        with open(args.run_file, encoding="utf-8") as run_file:
            run = run_file.read().strip()
    except OSError:
        run = ""  # a job run outside a workflow run (snakemake --no-hooks): its builds are reused
    record = {"case_id": args.case, "key": args.key, "built_by": "workflow", "run": run, "status": "running",
              "seconds": None, "finished": "", "message": ""}
    os.makedirs(os.path.dirname(os.path.abspath(args.record)), exist_ok=True)
    write_record(args.record, record)

    # The cluster stops a job with SIGTERM (its time limit, scancel): stop the build and say so.
    stopped = []

    def on_stop(number, _frame):
        stopped.append(number)
        if build.poll() is None:
            build.send_signal(signal.SIGTERM)

    start = time.monotonic()
    with open(args.log, "wb") as log:
        build = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        for number in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
            signal.signal(number, on_stop)
        status = build.wait()
    seconds = time.monotonic() - start
    record["seconds"] = round(seconds, 3)
    record["finished"] = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    if status == 0 and not stopped and os.path.exists(command_output(command)):
        record["status"] = "built"
        record["scenario_bytes"] = os.path.getsize(command_output(command))
    else:
        record["status"] = "failed"
        message = last_error(args.log)
        if stopped:
            message = "stopped by %s (the cluster's time limit, scancel or Ctrl-C)%s" % (
                signal.Signals(stopped[0]).name, ": " + message if message else "")
        elif status < 0:
            name = signal.Signals(-status).name
            message = message or "killed by %s%s (see %s)" % (
                name, " (out of memory?)" if name == "SIGKILL" else "", args.log)
        elif not message:
            message = "exit status %d (see %s)" % (status, args.log)
        record["message"] = message
    write_record(args.record, record)
    if status < 0:
        return 128 - status
    return status if status != 0 else (1 if stopped else 0)


def command_output(command):
    """The scenario a `heartprep build ... -o OUT` command writes."""
    for i, word in enumerate(command[:-1]):
        if word in ("-o", "--output"):
            return command[i + 1]
    return ""


if __name__ == "__main__":
    sys.exit(main())

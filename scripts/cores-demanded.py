#!/usr/bin/env python3
"""Cores a command asks for, independent of other load on the machine (issue 37, item 3).

Runs the command and samples /proc/PID/task/*/schedstat once a second: per interval, the sum
over the process's threads of (time on a CPU + time waiting in a run queue) / interval is the
cores it wanted (runnable threads), and time on a CPU / interval the cores it got. On a shared
machine the second falls with the load, the first does not: a bake whose units keep both
rayon threads busy reads ≈ 2 (≈ 1 with RAYON_NUM_THREADS=1).

    scripts/cores-demanded.py --out rows.json -- bake scene.eco -o P.bake --no-cache --json

The command's stdout goes to OUT.stdout (the build report with --json); rows.json holds
[t, demanded, got] per interval. With --report, the mean demanded and got cores over each
stage's span in that report (stages[].start_seconds, wall_seconds) are printed.
"""
import argparse, json, os, subprocess, sys, time


def threads_time(pid):
    run = wait = 0
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return None
    for t in tasks:
        try:
            a = open(f"/proc/{pid}/task/{t}/schedstat").read().split()
        except OSError:
            continue
        run += int(a[0])
        wait += int(a[1])
    return run, wait


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="cores.json")
    ap.add_argument("--interval", type=float, default=1.0)
    ap.add_argument("--report", action="store_true", help="per-stage means from the --json report")
    ap.add_argument("command", nargs=argparse.REMAINDER)
    a = ap.parse_args()
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    with open(a.out + ".stdout", "w") as out:
        p = subprocess.Popen(cmd, stdout=out)
        t0 = time.time()
        prev = (t0, *(threads_time(p.pid) or (0, 0)))
        rows = []
        while p.poll() is None:
            time.sleep(a.interval)
            s = threads_time(p.pid)
            if s is None:
                break
            now = (time.time(), *s)
            dt = now[0] - prev[0]
            if now[1] >= prev[1]:
                rows.append([round(now[0] - t0, 2),
                             (now[1] - prev[1] + now[2] - prev[2]) / 1e9 / dt,
                             (now[1] - prev[1]) / 1e9 / dt])
            prev = now
        rc = p.wait()
    json.dump(rows, open(a.out, "w"))
    if rows:
        print("whole: demanded %.2f, got %.2f cores (%d intervals)" % (
            sum(r[1] for r in rows) / len(rows), sum(r[2] for r in rows) / len(rows), len(rows)))
    if a.report and rows:
        rep = json.load(open(a.out + ".stdout"))
        spans = {}
        for s in rep["stages"]:
            b, e = spans.get(s["stage"], (1e18, 0))
            spans[s["stage"]] = (min(b, s["start_seconds"]), max(e, s["start_seconds"] + s["wall_seconds"]))
        for st, (b, e) in spans.items():
            sel = [r for r in rows if b + a.interval <= r[0] <= e]
            if sel:
                print("%-9s %7.1f..%7.1f s: demanded %.2f (min %.2f), got %.2f" % (
                    st, b, e, sum(r[1] for r in sel) / len(sel), min(r[1] for r in sel),
                    sum(r[2] for r in sel) / len(sel)))
    sys.exit(rc)


if __name__ == "__main__":
    main()

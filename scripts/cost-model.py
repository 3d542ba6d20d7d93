#!/usr/bin/env python3
"""Cost model of a `bake plan --emit ninja` build from its `.ninja_log` (issue 17, item 5).

Usage: scripts/cost-model.py BUILD_DIR [--workers 1,4,16,64] [--json]

Reads BUILD_DIR/build.ninja (the edges: outputs and inputs of each action) and
BUILD_DIR/.ninja_log (each action's start and end in ms, of the last run of each output), and
prints per action its time, the serial sum, the critical path (the longest chain of dependent
actions, by measured time) and the predicted wall time on N identical workers: a list schedule
that always starts the ready action with the longest remaining path (never below the critical
path nor below serial/N). Times are those of the run that wrote the log; run `ninja -j1` for
per-action times of one whole machine per action.
"""
import json
import sys
from pathlib import Path


def parse_ninja(text):
    edges = []  # (outputs, inputs, desc)
    cur = None
    for line in text.splitlines():
        if line.startswith("build "):
            head = line[len("build "):]
            # unescape "$ " and "$:" enough to split on the first unescaped ':'
            i = 0
            while True:
                j = head.index(":", i)
                if j > 0 and head[j - 1] == "$":
                    i = j + 1
                    continue
                break
            outs = head[:j].split()
            rest = head[j + 1:].split()
            rule, deps = rest[0], rest[1:]
            if rule == "plan":  # the generator edge that remakes build.ninja: not an action
                cur = None
                continue
            ins = []
            mode = "explicit"
            for d in deps:
                if d == "|":
                    mode = "implicit"
                elif d == "||":
                    mode = "order"
                elif mode != "implicit":
                    ins.append(d)
            cur = {"outs": outs, "ins": ins, "desc": outs[0]}
            edges.append(cur)
        elif cur is not None and line.startswith("  desc = "):
            cur["desc"] = line[len("  desc = "):].strip()
    return edges


def parse_log(text):
    times = {}
    for line in text.splitlines():
        if line.startswith("#"):
            continue
        f = line.split("\t")
        if len(f) < 4:
            continue
        start, end, out = int(f[0]), int(f[1]), f[3]
        times[out] = (start, end)
    return times


def main():
    args = sys.argv[1:]
    if not args:
        print(__doc__)
        sys.exit(2)
    d = Path(args[0])
    workers = [1, 4, 16, 64]
    as_json = "--json" in args
    if "--workers" in args:
        workers = [int(w) for w in args[args.index("--workers") + 1].split(",")]
    edges = parse_ninja((d / "build.ninja").read_text())
    log = parse_log((d / ".ninja_log").read_text())
    made = {}
    for k, e in enumerate(edges):
        for o in e["outs"]:
            made[o] = k
        t = [log[o] for o in e["outs"] if o in log]
        if not t:
            sys.exit(f"{e['desc']}: no time in .ninja_log (build the plan first)")
        e["ms"] = max(b for _, b in t) - min(a for a, _ in t)
    preds = [sorted({made[i] for i in e["ins"] if i in made}) for e in edges]
    succs = [[] for _ in edges]
    for k, p in enumerate(preds):
        for j in p:
            succs[j].append(k)
    # Longest path from each action to the end (inclusive), in topological order reversed.
    order = []
    seen = [0] * len(edges)

    def visit(k):
        if seen[k] == 2:
            return
        seen[k] = 1
        for j in preds[k]:
            visit(j)
        seen[k] = 2
        order.append(k)

    for k in range(len(edges)):
        visit(k)
    tail = [0] * len(edges)
    for k in reversed(order):
        tail[k] = edges[k]["ms"] + max((tail[s] for s in succs[k]), default=0)
    serial = sum(e["ms"] for e in edges)
    critical = max(tail) if tail else 0
    # The critical chain itself.
    chain = []
    starts = [k for k in range(len(edges)) if not preds[k]]
    k = max(starts, key=lambda s: tail[s]) if starts else None
    while k is not None:
        chain.append(edges[k]["desc"])
        nxt = [s for s in succs[k]]
        k = max(nxt, key=lambda s: tail[s]) if nxt else None

    def schedule(n):
        import heapq
        left = [len(p) for p in preds]
        ready = [(-tail[k], k) for k in range(len(edges)) if left[k] == 0]
        heapq.heapify(ready)
        running = []  # (end, k)
        now = 0
        free = n
        done = 0
        while done < len(edges):
            while ready and free > 0:
                _, k = heapq.heappop(ready)
                heapq.heappush(running, (now + edges[k]["ms"], k))
                free -= 1
            end, k = heapq.heappop(running)
            now = end
            free += 1
            done += 1
            for s in succs[k]:
                left[s] -= 1
                if left[s] == 0:
                    heapq.heappush(ready, (-tail[s], s))
        return now

    predicted = {n: schedule(n) for n in workers}
    result = {
        "actions": len(edges),
        "serial_s": serial / 1000,
        "critical_path_s": critical / 1000,
        "ratio": (serial / critical) if critical else None,
        "critical_chain": chain,
        "predicted_wall_s": {str(n): predicted[n] / 1000 for n in workers},
        "longest": sorted(((e["ms"] / 1000, e["desc"]) for e in edges), reverse=True)[:10],
    }
    if as_json:
        print(json.dumps(result, indent=2))
        return
    print(f"{len(edges)} actions; serial sum {serial/1000:.1f} s; critical path {critical/1000:.1f} s "
          f"(serial / critical = {result['ratio']:.1f})")
    print("critical chain: " + " -> ".join(chain))
    for n in workers:
        print(f"  {n:>3} workers: {predicted[n]/1000:.1f} s")
    print("longest actions:")
    for s, desc in result["longest"]:
        print(f"  {s:8.1f} s  {desc}")


if __name__ == "__main__":
    main()

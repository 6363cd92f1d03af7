#!/usr/bin/env python3
"""The center's memory under its heaviest requests (issue 36, docs/fleet.md).

Runs against a fleet daemon already serving a loaded center (see
docs/fleet.md "Memory at the center"): for each request, the peak resident
set of the daemon's process during it minus its resident set before it
(`/proc/PID/clear_refs` 5 resets the peak, `VmHWM` reads it); then 24
parallel slow downloads of one large recording, and a 200-way burst of SPC
queries (statuses, median time, peak). Standard library only.

    deploy/measure-center-memory.py --pid PID --base http://127.0.0.1:8799 \
        --recipe spider-80-1 --parameter keff_n_per_m --measurement ID
"""
import argparse
import json
import statistics
import threading
import time
import urllib.error
import urllib.request


def rss_kb(pid, key):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    raise RuntimeError(key)


def reset_peak(pid):
    with open(f"/proc/{pid}/clear_refs", "w") as f:
        f.write("5")


def fetch(url, slow_bytes_per_s=None, chunk=1 << 16):
    t0 = time.monotonic()
    try:
        with urllib.request.urlopen(url, timeout=600) as r:
            n = 0
            while True:
                b = r.read(chunk)
                if not b:
                    break
                n += len(b)
                if slow_bytes_per_s:
                    # a slow client: the server must not buffer what it
                    # has not sent yet
                    want = n / slow_bytes_per_s
                    dt = time.monotonic() - t0
                    if want > dt:
                        time.sleep(want - dt)
            return r.status, n, time.monotonic() - t0
    except urllib.error.HTTPError as e:
        body = e.read()
        return e.code, len(body), time.monotonic() - t0


def one(pid, base, path):
    time.sleep(0.5)
    before = rss_kb(pid, "VmRSS")
    reset_peak(pid)
    status, n, dt = fetch(base + path)
    peak = rss_kb(pid, "VmHWM")
    return {
        "path": path,
        "status": status,
        "bytes": n,
        "ms": round(dt * 1000),
        "rss_before_mb": round(before / 1024, 1),
        "peak_mb": round(peak / 1024, 1),
        "rise_mb": round((peak - before) / 1024, 1),
    }


def parallel(pid, base, paths, slow=None):
    time.sleep(0.5)
    before = rss_kb(pid, "VmRSS")
    reset_peak(pid)
    out = [None] * len(paths)
    peak = [before]
    done = threading.Event()

    def watch():
        while not done.is_set():
            peak[0] = max(peak[0], rss_kb(pid, "VmRSS"))
            time.sleep(0.05)

    def run(i, p):
        out[i] = fetch(base + p, slow)

    w = threading.Thread(target=watch)
    w.start()
    t0 = time.monotonic()
    ts = [threading.Thread(target=run, args=(i, p)) for i, p in enumerate(paths)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    wall = time.monotonic() - t0
    done.set()
    w.join()
    hwm = rss_kb(pid, "VmHWM")
    statuses = {}
    for s, _, _ in out:
        statuses[s] = statuses.get(s, 0) + 1
    ok = [dt for s, _, dt in out if s == 200]
    return {
        "requests": len(paths),
        "statuses": statuses,
        "bytes_each": sorted({n for s, n, _ in out if s == 200}),
        "median_ok_s": round(statistics.median(ok), 2) if ok else None,
        "wall_s": round(wall, 1),
        "rss_before_mb": round(before / 1024, 1),
        "peak_mb": round(max(hwm, peak[0]) / 1024, 1),
        "rise_mb": round((max(hwm, peak[0]) - before) / 1024, 1),
    }


def main():
    a = argparse.ArgumentParser()
    a.add_argument("--pid", type=int, required=True)
    a.add_argument("--base", required=True)
    a.add_argument("--recipe", required=True)
    a.add_argument("--parameter", required=True)
    a.add_argument("--measurement", required=True)
    a.add_argument("--part", required=True)
    a.add_argument("--station", required=True)
    a.add_argument("--downloads", type=int, default=24)
    a.add_argument("--burst", type=int, default=200)
    args = a.parse_args()
    r, p = args.recipe, args.parameter
    singles = [
        f"/api/v1/fleet/stations",
        f"/api/v1/fleet/recipes/{r}/verdicts?last=1000000",
        f"/api/v1/fleet/recipes/{r}/verdicts?last=10000",
        f"/api/v1/fleet/recipes/{r}/verdicts?since=2000-01-01T00:00:00Z&limit=10000",
        f"/api/v1/fleet/recipes/{r}/spc?parameter={p}&last=100000",
        f"/api/v1/fleet/recipes/{r}/yield?since=2000-01-01T00:00:00Z",
        f"/api/v1/recipes/{r}/spc?parameter={p}&last=10000",
        f"/api/v1/fleet/parts?limit=500",
        f"/api/v1/fleet/measurements?station={args.station}&limit=500",
        f"/api/v1/parts?limit=500",
        f"/api/v1/measurements?limit=500",
        f"/api/v1/parts/{args.part}/measurements",
        f"/api/v1/fleet/audit?limit=500",
        f"/api/v1/fleet/recipe-proposals?limit=500",
        f"/api/v1/measurements/{args.measurement}/recordings/main.wav",
    ]
    res = {"singles": [one(args.pid, args.base, s) for s in singles]}
    for s in res["singles"]:
        print(json.dumps(s), flush=True)
    rec = f"/api/v1/measurements/{args.measurement}/recordings/main.wav"
    res["downloads"] = parallel(
        args.pid, args.base, [rec] * args.downloads, slow=8 << 20
    )
    print(json.dumps({"downloads": res["downloads"]}), flush=True)
    spc = f"/api/v1/fleet/recipes/{r}/spc?parameter={p}&last=100000"
    res["spc_burst"] = parallel(args.pid, args.base, [spc] * args.burst)
    print(json.dumps({"spc_burst": res["spc_burst"]}), flush=True)


if __name__ == "__main__":
    main()

#!/usr/bin/python3
"""Seed 000 Tables 1–2 in shape: frames per second of the browser viewer (cli/view/bench.js)
in headless Chromium on SwiftShader (CPU), by technique × distance × view angle, and for the
hybrid + adaptive renderer by box size. Absolute figures depend on the GPU (here: none), so
docs/viewer.md compares ratios: hybrid + adaptive over relief mapping everywhere.
Usage: bench/view-fps.py BUILD_DIR COPY_DIR [--size WxH] [--secs S] [--rounds R] [--cells 5,10,20,50,100]
Each figure is the best of R interleaved rounds (the least disturbed on a shared machine)."""
import argparse, os, subprocess, sys, time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "view"))
import cdp

SEED_T1 = {  # Hz: RM, Hybrid, Hybrid + adaptive (GeForce 7900GTX), ranges as midpoints
    ("near", "grazing"): (36, 40.5, 46.5), ("near", "front"): (32, 43.5, 64),
    ("in shot", "grazing"): (100, 61, 330), ("in shot", "front"): (74, 60, 350),
    ("far", "grazing"): (365, 82, 650), ("far", "front"): (192.5, 80, 1250),
}
SEED_T2 = {5: (305, 142, 18), 10: (300, 185, 38), 20: (330, 250, 75), 50: (240, 175, 145), 100: (135, 130, 125)}


def serve(impasto, copy, cell):
    args = [impasto, "view", copy, "--port", "0", "--no-cache"] + (["--cell", str(cell)] if cell else [])
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    line = p.stdout.readline()
    if "http://" not in line:
        p.kill()
        sys.exit("impasto view printed no URL: %r" % line)
    return p, line[line.index("http://"):].split()[0]


def run_page(browser, url, query, timeout):
    browser.goto(url + "bench.html?" + query)
    deadline, seen = time.time() + timeout, 0
    while not browser.eval("window.bench && (window.bench.done || window.bench.error)"):
        if time.time() > deadline:
            sys.exit("bench page: not done after %g s" % timeout)
        rows = browser.eval("window.bench ? window.bench.rows : []") or []
        for r in rows[seen:]:
            print("  %s" % r, file=sys.stderr, flush=True)
        seen = len(rows)
        time.sleep(1)
    err = browser.eval("window.bench.error")
    if err:
        sys.exit("bench page: " + err)
    return browser.eval("window.bench.rows")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("build")
    ap.add_argument("copy")
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--secs", type=float, default=1.0)
    ap.add_argument("--cells", default="5,10,20,50,100")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    impasto = os.path.join(a.build, "cli", "impasto")
    browser = cdp.Browser()
    try:
        p, url = serve(impasto, a.copy, 0)
        try:
            rows = run_page(browser, url, "table=1&size=%s&secs=%g&rounds=%d" % (a.size, a.secs, a.rounds), 3600)
        finally:
            p.terminate()
            p.wait()
        fps = {(r["distance"], r["angle"], r["mode"]): r for r in rows}
        print("Table 1 (%s, %s px, fps; ratio = hybrid+adaptive / relief-only)\n" % (a.copy, a.size))
        print("| distance | angle | bump only | relief only | hybrid | hybrid + adaptive (boxes drawn) | ratio | seed ratio |")
        print("|---|---|---|---|---|---|---|---|")
        for (d, an), seed in SEED_T1.items():
            f = lambda m: fps[(d, an, m)]["fps"]
            ad = fps[(d, an, "adaptive")]
            print("| %s | %s | %.1f | %.1f | %.1f | %.1f (%d/%d) | %.2f | %.2f |" % (
                d, an, f("bump"), f("rm"), f("relief"), f("adaptive"), ad["drawn"], ad["boxes"],
                f("adaptive") / f("rm"), seed[2] / seed[0]))
        print("\nTable 2 (hybrid + adaptive, in shot, fps; ratio to 20×20 boxes)\n")
        print("| box size | boxes | front | intermediate | grazing | seed front | seed intermediate | seed grazing |")
        print("|---|---|---|---|---|---|---|---|")
        t2 = {}
        for cell in [int(c) for c in a.cells.split(",")]:
            p, url = serve(impasto, a.copy, cell)
            try:
                t2[cell] = {r["angle"]: r for r in run_page(browser, url, "table=2&size=%s&secs=%g&rounds=%d" % (a.size, a.secs, a.rounds), 1800)}
            finally:
                p.terminate()
                p.wait()
        ref = t2.get(20)
        for cell, r in t2.items():
            s = SEED_T2.get(cell)
            rel = lambda an: r[an]["fps"] / ref[an]["fps"] if ref else float("nan")
            srel = lambda k: s[k] / SEED_T2[20][k] if s else float("nan")
            print("| %d×%d | %d | %.1f (%.2f) | %.1f (%.2f) | %.1f (%.2f) | %s | %s | %s |" % (
                cell, cell, r["front"]["boxes"], r["front"]["fps"], rel("front"), r["intermediate"]["fps"],
                rel("intermediate"), r["grazing"]["fps"], rel("grazing"),
                "%.2f" % srel(0), "%.2f" % srel(1), "%.2f" % srel(2)))
    finally:
        browser.close()


if __name__ == "__main__":
    main()

#!/usr/bin/python3
"""`impasto view` in a real browser (headless Chromium on SwiftShader, DevTools protocol):
 1. the page renders the copy under the same view and light as `impasto render` (the CPU
    renderer): RMSE <= 2 % of white over the painting (the pixels either image lights), in
    the hybrid + adaptive mode and with every box relief-mapped;
 2. the ruler, dragged between the centres of two known texels in a top-down view, reads
    their distance within one texel pitch;
 3. a corrupt copy: `impasto view` names the file on stderr and the page is the error page;
 4. only the server's own files are served: traversal attempts get 404 and no file bytes.
Usage: test-view-browser.py BUILD_DIR COPY_DIR. Exit 77 only when chromium is absent."""
import json, math, os, shutil, socket, subprocess, sys, tempfile, time, urllib.request

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cdp

RMSE_MAX = 0.02          # of white, over the painting
W, H = 320, 240
fails = []
T0 = time.time()


def check(ok, what):
    print("%5.1f s %s%s" % (time.time() - T0, "ok   " if ok else "FAIL ", what), flush=True)
    if not ok:
        fails.append(what)


def start_view(impasto, copy, log):
    p = subprocess.Popen([impasto, "view", copy, "--port", "0", "--no-cache"], stdout=subprocess.PIPE,
                         stderr=open(log, "w"), text=True)
    line = p.stdout.readline()
    if "http://" not in line:
        p.kill()
        raise RuntimeError("impasto view printed no URL: %r (stderr: %s)" % (line, open(log).read()))
    return p, line[line.index("http://"):].split()[0]


def stop(p):
    p.terminate()
    try:
        return p.wait(10)
    except subprocess.TimeoutExpired:
        p.kill()
        return p.wait()


def rmse(a, b):
    """RMSE of two decoded PNGs (RGB of each), over the pixels either lights; [0, 1]."""
    (wa, ha, ca, ra), (wb, hb, cb, rb) = a, b
    assert (wa, ha) == (wb, hb), "sizes differ: %dx%d, %dx%d" % (wa, ha, wb, hb)
    s, n = 0.0, 0
    for y in range(ha):
        for x in range(wa):
            pa = ra[y][x * ca:x * ca + 3]
            pb = rb[y][x * cb:x * cb + 3]
            if max(pa) == 0 and max(pb) == 0:
                continue
            s += sum((pa[k] - pb[k]) ** 2 for k in range(3))
            n += 3
    return math.sqrt(s / max(n, 1)) / 255, n // 3


def compare_render(impasto, copy, browser, url, tmp, view, light, fov, mode):
    cpu = os.path.join(tmp, "cpu-%s.png" % mode)
    subprocess.run([impasto, "render", copy, "--view", view, "--light", light, "--fov", str(fov), "--mode", mode,
                    "--size", "%dx%d" % (W, H), "--out", cpu], check=True, stdout=subprocess.DEVNULL)
    browser.goto("%s?bare=1&size=%dx%d&view=%s&light=%s&fov=%g&mode=%s" % (url, W, H, view, light, fov, mode))
    browser.wait_for("window.impasto && (window.impasto.ready || window.impasto.error)")
    err = browser.eval("window.impasto.error")
    check(err is None, "the page loaded the copy (error: %s)" % err)
    shot = browser.screenshot(W, H)
    open(os.path.join(tmp, "gpu-%s.png" % mode), "wb").write(shot)
    e, n = rmse(cdp.png_decode(open(cpu, "rb").read()), cdp.png_decode(shot))
    check(n > W * H // 10 and e <= RMSE_MAX,
          "%s: the browser's frame matches `impasto render`: RMSE %.4f of white over %d pixels (bound %.2f)"
          % (mode, e, n, RMSE_MAX))
    return browser.eval("window.impasto.stats")


def ruler(browser, url, meta):
    """Top-down view; drag between the centres of texels A and B; expect their distance."""
    p, plane = meta["pitch_mm"], meta["plane_mm"]
    cx, cy = 0.5 * (meta["nx"] - 1) * p, 0.5 * (meta["ny"] - 1) * p
    fov, Z = 40.0, plane + 0.75 * meta["nx"] * p / math.tan(math.radians(20))
    browser.goto("%s?bare=1&size=%dx%d&view=%r,%r,%r,%r,%r,%r&fov=%g&tool=ruler&light=%r,%r,%r"
                 % (url, W, H, cx, cy, Z, cx, cy, plane, fov, cx, cy, plane + 300))
    browser.wait_for("window.impasto && (window.impasto.ready || window.impasto.error)")
    fx = 0.5 * W / math.tan(math.radians(0.5 * fov))

    def pix(i, j):   # the pinhole of `impasto render`: image x = canvas x, image y = −canvas y
        return (0.5 * W + fx * (i * p - cx) / (Z - plane), 0.5 * H - fx * (j * p - cy) / (Z - plane))
    A, B = (int(meta["nx"] * 0.2), int(meta["ny"] * 0.3)), (int(meta["nx"] * 0.8), int(meta["ny"] * 0.7))
    pa, pb = pix(*A), pix(*B)
    browser.mouse("mousePressed", *pa)
    for k in range(1, 5):
        browser.mouse("mouseMoved", pa[0] + k / 4 * (pb[0] - pa[0]), pa[1] + k / 4 * (pb[1] - pa[1]))
    browser.mouse("mouseReleased", *pb)
    got = browser.eval("window.impasto.ruler && window.impasto.ruler.mm")
    want = p * math.hypot(B[0] - A[0], B[1] - A[1])
    check(got is not None and abs(got - want) <= p,
          "ruler from texel %s to %s reads %s mm, expected %.4f mm within one texel (%.4f mm)" % (A, B, got, want, p))
    text = browser.eval("document.getElementById('ruler-readout').textContent")
    check(got is not None and ("%.3f mm" % got) in text, "the ruler's readout shows it: %r" % text)


def raw_get(url, path):
    host, port = url.split("//")[1].rstrip("/").split(":")
    s = socket.create_connection((host, int(port)), timeout=10)
    s.sendall(("GET %s HTTP/1.0\r\nHost: x\r\n\r\n" % path).encode())
    data = b""
    while True:
        b = s.recv(65536)
        if not b:
            break
        data += b
    s.close()
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split()[1]), body


def traversal(url, copy):
    secret = open(os.path.join(copy, "boxes.json"), "rb").read()[:40]
    for path in ("/../boxes.json", "/copy/../../boxes.json", "/copy/boxes.json", "/%2e%2e/%2e%2e/etc/passwd",
                 "/copy/..%2fboxes.json", "/copy/heightfield.exr", "/..%2f..%2f..%2fetc%2fpasswd", "/error.html",
                 "/copy/%2e%2e/boxes.json"):
        status, body = raw_get(url, path)
        check(status in (400, 404) and secret not in body and b"root:" not in body,
              "GET %s → %d, none of the copy's or the system's files" % (path, status))
    status, body = raw_get(url, "/copy/meta.json")
    check(status == 200 and b'"impasto-view"' in body, "GET /copy/meta.json → %d" % status)


def corrupt(impasto, copy, browser, tmp):
    bad = os.path.join(tmp, "corrupt-copy")
    shutil.copytree(copy, bad)
    with open(os.path.join(bad, "heightfield.exr"), "r+b") as f:
        f.truncate(100)
    log = os.path.join(tmp, "corrupt.log")
    p, url = start_view(impasto, bad, log)
    try:
        browser.goto(url)
        title = browser.wait_for("document.getElementById('impasto-error') && document.getElementById('message').textContent", 20)
        check("heightfield.exr" in title, "the error page names the broken file: %r" % title[:200])
        status, _ = raw_get(url, "/")
        check(status == 500, "the error page is served with status 500 (got %d)" % status)
    finally:
        rc = stop(p)
    err = open(log).read()
    check("heightfield.exr" in err and "not a readable digital copy" in err, "stderr names the file: %r" % err.strip()[:300])
    check(rc == 3, "impasto view on a corrupt copy exits 3 when stopped (got %d)" % rc)


def main():
    build, copy = sys.argv[1], sys.argv[2]
    impasto = os.path.join(build, "cli", "impasto")
    if not cdp.find_chromium():
        print("skip: chromium is not installed (apt-get install chromium)")
        return 77
    if not os.path.exists(os.path.join(copy, "rho_d.exr")):
        print("FAIL: %s is not a copy (the appearance_copy fixture makes it)" % copy)
        return 1
    tmp = tempfile.mkdtemp(prefix="impasto-view-test.")
    t0 = time.time()
    browser = cdp.Browser()
    p, url = start_view(impasto, copy, os.path.join(tmp, "view.log"))
    try:
        browser.viewport(W, H)
        meta = json.load(urllib.request.urlopen(url + "copy/meta.json", timeout=10))
        p_mm = meta["pitch_mm"]
        cx, cy = 0.5 * (meta["nx"] - 1) * p_mm, 0.5 * (meta["ny"] - 1) * p_mm
        # oblique view from the -y side, raking light from the upper left
        view = "%.4f,%.4f,%.4f" % (cx, cy - 60, 110)
        light = "%.4f,%.4f,%.4f" % (cx - 80, cy + 40, 60)
        st = compare_render(impasto, copy, browser, url, tmp, view, light, 9, "adaptive")
        check(st and st["drawn"] > 0 and st["blended"] + st["drawn"] < 2 * st["boxes"],
              "adaptive mode relief-maps some boxes and not others: %s" % st)
        compare_render(impasto, copy, browser, url, tmp, view, light, 9, "relief")
        compare_render(impasto, copy, browser, url, tmp, view, light, 9, "bump")
        ruler(browser, url, meta)
        traversal(url, copy)
        corrupt(impasto, copy, browser, tmp)
    finally:
        stop(p)
        browser.close()
    print("%.1f s" % (time.time() - t0))
    if fails:
        print("images kept in", tmp)
        return 1
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

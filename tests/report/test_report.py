#!/usr/bin/python3
"""The HTML report in a real browser (issue 24): headless Chromium (Debian's chromium and
chromium-driver through python3-selenium) opens report.html from a file, with no network,
and must see no console error, a WebGL canvas with the surface drawn on it, the picture,
and the same figures as the map's JSON.

Usage: test_report.py BRENIER_COMPUTE DATA_DIR WORK_DIR
Prints 'N passed, N failed'; exits non-zero on any failure.
"""
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "cli"))
from clitest import Checks  # noqa: E402
from selenium import webdriver  # noqa: E402
from selenium.webdriver.chrome.options import Options  # noqa: E402
from selenium.webdriver.chrome.service import Service  # noqa: E402

exe, data, work = sys.argv[1:4]
T = Checks(exe)
os.makedirs(work, exist_ok=True)
check, run = T.check, T.run


def leaves(j, key=""):
    """The JSON's leaves by dotted key, as the report's tables name them."""
    if isinstance(j, dict):
        for k, v in j.items():
            yield from leaves(v, f"{key}.{k}" if key else k)
    elif isinstance(j, list) and j and isinstance(j[0], (dict, list)):
        for i, v in enumerate(j):
            yield from leaves(v, f"{key}.{i}")
    else:
        yield key, j


def browser():
    o = Options()
    for a in ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--enable-unsafe-swiftshader",
              "--use-angle=swiftshader", "--window-size=1400,1000", "--no-first-run", "--disable-extensions"]:
        o.add_argument(a)
    o.binary_location = "/usr/bin/chromium"
    o.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=o)


CANVAS_PIXELS = """
const c = document.getElementById('surface');
const x = document.createElement('canvas'); x.width = c.width; x.height = c.height;
const g = x.getContext('2d'); g.drawImage(c, 0, 0);
const d = g.getImageData(0, 0, x.width, x.height).data;
let drawn = 0; const colours = new Set();
for (let i = 0; i < d.length; i += 4) {
  if (d[i] < 250 || d[i + 1] < 250 || d[i + 2] < 250) { ++drawn; colours.add((d[i] >> 3) * 1024 + (d[i + 1] >> 3) * 32 + (d[i + 2] >> 3)); }
}
return [drawn, d.length / 4, colours.size];
"""


def check_report(driver, html, report, what, picture_width=1600, surface=True):
    driver.get("file://" + os.path.abspath(html))
    view = None
    for _ in range(100 if surface else 0):
        view = driver.execute_script("return window.brenierView || null")
        if view:
            break
        time.sleep(0.2)
    errors = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
    check(not errors, f"{what}: no console error: {errors[:3]}")
    if surface:
        check(view is not None, f"{what}: the 3-D view started")
        if view:
            check(view["vertices"] == report["mesh"]["vertices"], f"{what}: the view has the mesh's vertices: {view}")
        drawn, total, colours = driver.execute_script(CANVAS_PIXELS)
        check(drawn > 0.05 * total and colours > 20,
              f"{what}: the WebGL canvas shows the surface: {drawn} of {total} pixels, {colours} colours")
    if picture_width:
        width = driver.execute_script("const i = document.getElementById('preview'); return i && i.complete ? i.naturalWidth : 0")
        check(width == picture_width, f"{what}: the picture decoded, {width} pixels wide")
    rows = driver.execute_script(
        "return Array.from(document.querySelectorAll('tr[data-key]')).map(r => "
        "[r.dataset.key, r.dataset.value, r.querySelector('td').textContent])")
    shown = {k: (v, t) for k, v, t in rows}
    expected = dict(leaves(report))
    missing = [k for k in expected if k not in shown and not k.startswith("seconds")]
    check(not missing, f"{what}: every figure of the JSON is in a table: missing {missing[:5]}")
    wrong = []
    for k, (v, t) in shown.items():
        if k not in expected:
            wrong.append((k, "not in the JSON"))
            continue
        e = expected[k]
        if k.startswith("seconds"):
            continue
        if isinstance(e, float):
            if float(v) != e or t != f"{e:.6g}":
                wrong.append((k, v, t, e))
        elif json.loads(v) != e:
            wrong.append((k, v, e))
    check(not wrong, f"{what}: the tables show the JSON's figures: {wrong[:5]}")
    return len(shown)


cases = [("lion-head.off", "disk", "area-preserving"), ("oblong.off", "sphere", "conformal")]
driver = browser()
try:
    for mesh, domain, method in cases:
        html = os.path.join(work, f"{mesh}-{domain}.html")
        rc, so, se = run("map", os.path.join(data, mesh), "--domain", domain, "--method", method, "--report-html", html,
                         "--json")
        check(rc == 0, f"map {mesh} --report-html: exit {rc}, {se.strip()}")
        if rc != 0:
            continue
        report = json.loads(so)
        for k in ["output", "report_html"]:
            report.pop(k, None)
        page = open(html, encoding="utf-8").read()
        check("http://" not in page.split("<script>")[0] and "src=\"http" not in page and "href=\"http" not in page,
              f"{mesh}: the page loads nothing from the network")
        n = check_report(driver, html, report, f"{mesh} on the {domain}")
        check(n > 20, f"{mesh}: {n} figures in the tables")
    # A matrix's and a distance's reports: the picture (the matrix), the figures, no error.
    shapes = [os.path.join(data, f"{n}.off") for n in ["nefertiti", "mesh_with_border", "patch-01", "patch-13"]]
    html = os.path.join(work, "matrix.html")
    rc, so, se = run("matrix", *shapes, "-o", os.path.join(work, "D.csv"), "--method", "omt-linear", "--report-html", html,
                     "--json")
    check(rc == 0, f"matrix --report-html: exit {rc}, {se.strip()}")
    if rc == 0:
        summary = json.loads(so)
        check_report(driver, html, summary, "the matrix report", picture_width=1400, surface=False)
        cells = driver.execute_script("return document.querySelectorAll('table.matrix td').length")
        check(cells == 16, f"the matrix report's table has 4 x 4 distances: {cells}")
    html = os.path.join(work, "distance.html")
    rc, so, se = run("distance", shapes[0], shapes[1], "--report-html", html, "--json")
    check(rc == 0, f"distance --report-html: exit {rc}, {se.strip()}")
    if rc == 0:
        check_report(driver, html, json.loads(so), "the distance report", picture_width=0, surface=False)
finally:
    driver.quit()

rc, so, se = run("map", os.path.join(data, "lion-head.off"), "--report-html", os.path.join(work, "no-such-dir", "r.html"))
check(rc == 2 and "cannot write" in se and se.count("\n") == 1, f"an unwritable report: exit {rc}, {se!r}")
T.finish()

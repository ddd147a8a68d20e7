"""The operator console in a real Chromium (Playwright, Debian's chromium) against a real
`shsas serve`: upload, progress, cancel and delete, the 3-D view, metrics, the iso slider,
errors beside their fields, the key flow, and no request leaving the server's origin.

Every request the page makes that is not for the server is refused and logged by the browser
context (the server's "internet" is blocked); each test ends by checking that log is empty.
``SHSAS_UPDATE_SCREENSHOTS=1`` also writes the screenshots to docs/img/ (the docs' pictures).
"""

from __future__ import annotations

import io
import json
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from .conftest import REPO, SERVER_START_S, SHSAS, start_server, write_demo_survey

pytestmark = [pytest.mark.service, pytest.mark.slow]

CHROMIUM = os.environ.get("SHSAS_CHROMIUM", "/usr/bin/chromium")
#: Flags that work in a container without a GPU or a network (SwiftShader draws WebGL).
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: The demo job: one quick method on a small grid; the long one is cancelled mid-run.
DEMO_SPEC = {"methods": "backprojection", "grid": "32", "device": "cpu"}
#: Three methods, quickly: the neural fields start from nothing and take a few steps (the panes
#: need three results, not good ones).
COMPARE_SPEC = {"methods": ["backprojection", "reed", "shsas"], "grid": 24, "iters": 20, "init": "none",
                "num_rays": 16, "num_bins": 8, "device": "cpu"}
LONG_SPEC = {"methods": "shsas", "iters": "100000", "grid": "16", "device": "cpu", "num_rays": "16", "num_bins": "8"}
#: Share of the viewer's pixels that must differ from the empty canvas once the mesh is shown.
MIN_DRAWN_SHARE = 0.05
JOB_TIMEOUT_MS = 180_000
#: Share of a frame's pixels that must be dark (text) for it to count as showing something: a
#: page of text inks a few percent of its pixels, a blank frame none.
MIN_TEXT_SHARE = 0.005
DOCS_IMG = REPO / "docs" / "img"
#: Bytes a first complete 3-D view of a three-method job may download (the issue's goal for
#: the demo bunny; the test's job is smaller: the demo sphere of 10 x 90 pings at grid 24, 20
#: iterations).
FIRST_VIEW_BUDGET = 8_000_000
#: Side (CSS px) of the axes drawn in the 3-D view's corner (web/src/viewer.js, GIZMO_PX).
GIZMO_PX = 84
#: Jobs on one page of the console's list (web/src/jobs.js, PAGE_SIZE).
PAGE_SIZE = 20


def _need(what: str) -> None:
    if os.environ.get("SHSAS_REQUIRE_BROWSER") == "1":
        pytest.fail(f"{what} (SHSAS_REQUIRE_BROWSER=1: .ci/run installs it)")
    pytest.skip(what)


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _need("playwright is not installed (pip install -e '.[dev]')")
    if not Path(CHROMIUM).exists():
        _need(f"no Chromium at {CHROMIUM} (apt-get install chromium)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[dict]:
    if not (REPO / "service/console/static/index.html").is_file():
        pytest.fail("the console is not built: run `make console` (make test does)")
    tmp = tmp_path_factory.mktemp("console")
    # default lease timings: the fast ones of other tests lose leases on a loaded machine
    env = {"SHSAS_DATA_DIR": str(tmp / "data"), "SHSAS_LOCAL_POLL_INTERVAL_S": "0.2"}
    proc, base = start_server(tmp, env, timeout=SERVER_START_S)
    yield {"base": base, "tmp": tmp, "env": env, "demo": write_demo_survey(tmp / "demo.h5")}
    proc.stop()


class Page:
    """A fresh browser context and page; requests off the server's origin are refused and logged."""

    def __init__(self, browser, base: str, width: int = 1280, height: int = 800):
        self.base = base
        self.ctx = browser.new_context(viewport={"width": width, "height": height})
        self.outside: list[str] = []
        self.errors: list[str] = []
        self.ctx.route("**/*", self._route)
        self.page = self.ctx.new_page()
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))

    def _route(self, route) -> None:
        url = route.request.url
        if url.startswith(self.base + "/") or url.startswith(("data:", "blob:")):
            route.continue_()
        else:
            self.outside.append(url)
            route.abort("internetdisconnected")

    def close(self) -> None:
        self.ctx.close()
        assert not self.outside, f"the page asked for things off the server: {self.outside}"
        assert not self.errors, f"uncaught errors in the page: {self.errors}"


@pytest.fixture
def ui(browser, server) -> Iterator[Page]:
    p = Page(browser, server["base"])
    p.page.goto(server["base"] + "/")
    p.page.wait_for_selector("#spec-grid")
    yield p
    p.close()


def fill_spec(page, values: dict[str, str]) -> None:
    """Set the spec form: ``methods`` is a comma list of the boxes to tick, the rest are inputs."""
    for name, value in values.items():
        if name == "methods":
            for box in page.query_selector_all("input[name=methods]"):
                box.set_checked(box.get_attribute("value") in value.split(","))
        else:
            page.fill(f"#spec-{name}", value)


def job_row(page, status: str | None = None):
    sel = "li.job" + (f"[data-status={status}]" if status else "")
    return page.wait_for_selector(sel, timeout=JOB_TIMEOUT_MS)


def progress_of(row) -> float:
    return float(row.get_attribute("data-progress"))


def dark_share(png: bytes) -> float:
    """Share of the pixels of a screenshot darker than mid-grey (text on a light page)."""
    from PIL import Image

    return float((np.asarray(Image.open(io.BytesIO(png)).convert("L")) < 128).mean())


def shot(page, name: str, tmp: Path, **kw) -> bytes:
    png = page.screenshot(**kw)
    (tmp / name).write_bytes(png)
    if os.environ.get("SHSAS_UPDATE_SCREENSHOTS") == "1":
        DOCS_IMG.mkdir(parents=True, exist_ok=True)
        (DOCS_IMG / name).write_bytes(png)
    return png


def test_upload_progress_cancel_delete(ui, server) -> None:
    page = ui.page
    page.set_input_files("#survey-input", str(server["demo"]))
    fill_spec(page, LONG_SPEC)
    page.click("#submit-btn")
    row = job_row(page)
    job_id = row.get_attribute("data-job-id")
    # the progress moves: two rising values seen on the page while the job runs
    running = ("id => { const r = document.querySelector(`li.job[data-job-id='${id}']`);"
               " return r && (r.dataset.status === 'running' && Number(r.dataset.progress) > 0"
               " || !['queued', 'running'].includes(r.dataset.status)); }")
    page.wait_for_function(running, arg=job_id, timeout=JOB_TIMEOUT_MS)
    row = page.query_selector(f"li.job[data-job-id='{job_id}']")
    assert row.get_attribute("data-status") == "running", page.inner_text(f"li.job[data-job-id='{job_id}']")
    first = progress_of(row)
    page.wait_for_function("([id, p]) => Number(document.querySelector(`li.job[data-job-id='${id}']`)"
                           ".dataset.progress) > p", arg=[job_id, first], timeout=JOB_TIMEOUT_MS)
    # the live loss: a curve of the values read while the page watched, as the API gave them
    curve = f"li.job[data-job-id='{job_id}'] svg.loss"
    page.wait_for_function("s => Number(document.querySelector(s)?.dataset.samples) >= 3", arg=curve,
                           timeout=JOB_TIMEOUT_MS)
    assert page.is_visible(curve)  # drawn, not only computed
    label = page.get_attribute(curve, "aria-label")
    assert label.startswith("loss from ") and len(page.get_attribute(f"{curve} polyline", "points").split()) >= 3
    loss = httpx.get(f"{server['base']}/reconstructions/{job_id}").json()["live_metrics"]["loss"]
    assert loss > 0 and "loss" in page.inner_text(f"li.job[data-job-id='{job_id}'] .meta")
    meta = page.inner_text(f"li.job[data-job-id='{job_id}'] .meta")
    assert "running for" in meta and "shsas" in meta, meta  # elapsed time, methods
    assert page.inner_text(f"li.job[data-job-id='{job_id}'] .title") == server["demo"].name  # the file's name
    shot(page, "console-running.png", server["tmp"])
    page.click(f"li.job[data-job-id='{job_id}'] button.cancel")
    page.wait_for_selector(f"li.job[data-job-id='{job_id}'][data-status=cancelled]", timeout=JOB_TIMEOUT_MS)
    assert httpx.get(f"{server['base']}/reconstructions/{job_id}").json()["status"] == "cancelled"
    # delete: DELETE /reconstructions/{id} (a server without it answers 405 and the page says so)
    supported = "delete" in httpx.get(f"{server['base']}/openapi.json").json()["paths"]["/reconstructions/{job_id}"]
    # Delete asks first, saying it is permanent; "Keep it" keeps the job
    page.click(f"li.job[data-job-id='{job_id}'] button.delete")
    page.wait_for_selector("#confirm-delete[open]")
    assert "cannot be undone" in page.inner_text("#confirm-delete") and job_id[:8] in page.inner_text("#confirm-delete")
    page.click("#confirm-delete button[value=keep]")
    page.wait_for_selector("#confirm-delete", state="hidden")
    page.wait_for_timeout(1500)  # a delete would have been sent by now; the list polls every second
    assert httpx.get(f"{server['base']}/reconstructions/{job_id}").status_code == 200
    assert page.query_selector(f"li.job[data-job-id='{job_id}']") is not None
    page.click(f"li.job[data-job-id='{job_id}'] button.delete")
    page.click("#confirm-delete-yes")
    if supported:
        page.wait_for_selector(f"li.job[data-job-id='{job_id}']", state="detached", timeout=30_000)
        assert httpx.get(f"{server['base']}/reconstructions/{job_id}").status_code == 404
    else:
        page.wait_for_function("() => document.querySelector('#banner').textContent.includes('cannot delete')")


#: Within one stage, two ETAs (the later aged back to the earlier one's moment) differ by at
#: most this factor (the issue's bound; worker/eta.py).
MAX_ETA_SWING = 2.0
#: How long the test reads the running job's ETA (s).
ETA_WATCH_S = 20.0


def test_running_job_status_eta_and_log(ui, server) -> None:
    """A running job's own page: plain stage name, progress, elapsed time, a steady ETA, the
    live loss and its log lines, followed while it runs."""
    import time

    page = ui.page
    page.set_input_files("#survey-input", str(server["demo"]))
    fill_spec(page, LONG_SPEC)
    page.click("#submit-btn")
    job_id = job_row(page).get_attribute("data-job-id")
    row = f"li.job[data-job-id='{job_id}']"
    page.wait_for_selector(f"{row}[data-status=running] a.details", timeout=JOB_TIMEOUT_MS)
    assert page.is_hidden(f"{row} a.open")  # no result yet: its page has the status and the log
    page.click(f"{row} a.details")
    page.wait_for_function("id => location.hash === `#/jobs/${id}`", arg=job_id)
    page.wait_for_selector("#result-live:not([hidden])")
    assert page.evaluate("document.activeElement.id") == "result-h"
    # the log is open while the job runs, and follows it: the worker's lines, this job's only
    page.wait_for_function("() => Number(document.querySelector('#log-lines').dataset.lines) >= 2",
                           timeout=JOB_TIMEOUT_MS)
    assert page.evaluate("document.querySelector('#log-box').open")
    log = page.inner_text("#log-lines")
    assert " info attempt 1 on " in log and " info load at 0.0 %" in log, log
    assert job_id not in log
    # a steady ETA: read for a while, every stage's readings within the bound
    page.wait_for_function("() => document.querySelector('#live-text').dataset.eta !== ''", timeout=JOB_TIMEOUT_MS)
    readings: list[tuple[float, float, str]] = []
    t_end = time.monotonic() + ETA_WATCH_S
    while time.monotonic() < t_end:
        eta = page.get_attribute("#live-text", "data-eta")
        stage = page.get_attribute(row, "data-stage")
        text = page.inner_text("#live-text")
        if eta:
            readings.append((time.monotonic(), float(eta), stage))
            assert "left" in text and "running for" in text, text
        assert ":" not in text.split(" · ")[0], text  # a plain stage name, not "fit:shsas"
        page.wait_for_timeout(500)
    worst = 1.0
    for i, (t1, e1, s1) in enumerate(readings):
        for t2, e2, s2 in readings[i + 1:]:
            if s1 == s2 and e1 > 0:
                aged = e2 + (t2 - t1)
                worst = max(worst, e1 / aged, aged / e1)
    assert len(readings) >= 10 and worst <= MAX_ETA_SWING, (worst, readings)
    assert page.is_visible("#live-loss")  # the loss curve of the values read
    # more lines came while the page watched (progress every 15 s, with the loss)
    page.wait_for_function("n => Number(document.querySelector('#log-lines').dataset.lines) > n",
                           arg=len(log.splitlines()), timeout=JOB_TIMEOUT_MS)
    shot(page, "console-job-status.png", server["tmp"])
    # after a reload the loss curve starts from the log's history (a loss every 15 s)
    logged = [ln for ln in page.inner_text("#log-lines").splitlines() if ", loss " in ln]
    page.reload()
    page.wait_for_selector("#result-live:not([hidden])")
    page.wait_for_function("n => window.shsasConsole.result.log.losses.length >= n", arg=len(logged))
    assert logged, "no progress line with the loss in the log"
    first = float(logged[0].split(", loss ")[1].split(",")[0])
    assert page.evaluate("window.shsasConsole.result.log.losses[0]") == pytest.approx(first, rel=1e-3)
    page.click(f"{row} button.cancel")
    page.wait_for_function("() => document.querySelector('#result-state').textContent.includes('cancelled')",
                           timeout=JOB_TIMEOUT_MS)
    assert page.is_hidden("#result-live")
    page.wait_for_function("() => document.querySelector('#log-lines').textContent.includes('cancelled')",
                           timeout=30_000)


def test_demo_job_result_view(ui, server) -> None:
    from PIL import Image

    page, base = ui.page, server["base"]
    # the first attempt's connection drops: the page offers a retry, which queues the job once
    dropped = []

    def drop_once(route):
        dropped.append(route.request.headers.get("idempotency-key"))
        route.abort("connectionreset")

    page.route("**/reconstructions", lambda route: drop_once(route) if route.request.method == "POST" and not dropped
               else route.fallback())
    before = {j["id"] for j in httpx.get(base + "/reconstructions").json()["items"]}
    page.set_input_files("#survey-input", str(server["demo"]))
    fill_spec(page, DEMO_SPEC)
    page.fill("#label-input", "demo sphere, pass 1")
    page.click("#submit-btn")
    page.wait_for_selector("#retry-btn:not([hidden])")
    assert "dropped" in page.inner_text("#upload-status")
    page.click("#retry-btn")
    page.wait_for_function("() => document.querySelector('#upload-status').textContent.startsWith('queued as')")
    new = [j for j in httpx.get(base + "/reconstructions").json()["items"] if j["id"] not in before]
    assert len(new) == 1 and dropped, new
    job_id = new[0]["id"]
    assert new[0]["label"] == "demo sphere, pass 1" and new[0]["input"]["filename"] == server["demo"].name
    row = f"li.job[data-job-id='{job_id}']"
    page.wait_for_selector(f"{row}[data-status=succeeded]", timeout=JOB_TIMEOUT_MS)
    assert page.inner_text(f"{row} .title") == "demo sphere, pass 1"
    assert page.inner_text(f"{row} .file") == server["demo"].name
    assert page.inner_text(f"{row} .meta").startswith("ran ")  # how long it ran
    # "View result" from a list scrolled down: the result comes into view with the focus, at
    # its own address, and the list beside it does not move
    page.evaluate("window.scrollTo(0, document.body.scrollHeight)")
    jobs_top = page.evaluate("document.querySelector('#jobs').getBoundingClientRect().top + window.scrollY")
    page.click(f"{row} .open")
    page.wait_for_selector(f"body[data-viewer-ready='{job_id}']", state="attached", timeout=60_000)
    assert page.url.endswith(f"/#/jobs/{job_id}")
    assert page.evaluate("document.activeElement.id") == "result-h"
    box = page.locator("#viewer").bounding_box()
    assert 0 <= box["y"] < 800 - 100, f"the 3-D view is off-screen (top at {box['y']:.0f} px)"
    assert page.evaluate("document.querySelector('#jobs').getBoundingClientRect().top + window.scrollY") == jobs_top
    # reload, back and forward: the address reopens the job
    page.reload()
    page.wait_for_selector(f"body[data-viewer-ready='{job_id}']", state="attached", timeout=60_000)
    assert "demo sphere, pass 1" in page.inner_text("#result-h")
    page.go_back()
    page.wait_for_selector("#result-hint:not([hidden])")
    assert page.is_hidden("#result-body")
    page.go_forward()
    page.wait_for_selector(f"body[data-viewer-ready='{job_id}']", state="attached", timeout=60_000)
    # "View result" again on the job already open (no change of address) still brings it into view
    page.evaluate("window.scrollTo(0, document.body.scrollHeight)")
    page.focus(f"{row} .open")
    page.click(f"{row} .open")
    page.wait_for_function("() => document.activeElement.id === 'result-h'")
    assert 0 <= page.locator("#viewer").bounding_box()["y"] < 800 - 100

    # the viewer draws the mesh: compare with the same canvas with every layer hidden
    layers = page.query_selector_all("#layers input[type=checkbox]")
    on = [box.is_checked() for box in layers]
    for box in layers:
        box.set_checked(False)
    empty = np.asarray(Image.open(io.BytesIO(page.locator("#viewer").screenshot())).convert("RGB"), dtype=np.int16)
    for box, was in zip(layers, on, strict=True):
        box.set_checked(was)
    drawn = np.asarray(Image.open(io.BytesIO(page.locator("#viewer").screenshot())).convert("RGB"), dtype=np.int16)
    share = float((np.abs(drawn - empty).max(axis=2) > 16).mean())
    assert share > MIN_DRAWN_SHARE, f"only {share:.3f} of the viewer's pixels show the mesh"
    scene = page.evaluate("window.__shsasViewer.summary()")
    assert scene["backprojection mesh"]["triangles"] > 0 and scene["ground truth"]["triangles"] > 0

    # the metrics table is report.json's
    report = httpx.get(f"{base}/reconstructions/{job_id}/artifacts/report.json").json()
    (m,) = report["methods"]
    cells = page.eval_on_selector_all("#metrics tr[data-method=backprojection] td",
                                      "tds => tds.map(td => [td.dataset.metric, td.dataset.value, td.textContent])")
    values = {**m["metrics"], **{k: m[k] for k in ("threshold", "points", "faces", "seconds")}}
    assert len(cells) >= 6
    for name, raw, text in cells:
        want = values.get(name)
        if want is None:
            assert text == "–", (name, text)
        else:
            assert float(raw) == pytest.approx(want, rel=1e-12), name
            assert float(text) == pytest.approx(want, rel=1e-3), (name, text)
    # the MIPs, the survey plot and the files
    assert page.eval_on_selector("#mip img", "img => img.complete && img.naturalWidth > 0")
    summary = dict(page.eval_on_selector_all("#survey-summary tr", "trs => trs.map(tr => [tr.cells[0].textContent, "
                                                                   "tr.cells[1].textContent])"))
    assert summary["pings"] == "900" and summary["platform"] == report["survey"]["platform"]
    names = page.eval_on_selector_all("#artifacts a", "as => as.map(a => a.textContent)")
    assert sorted(names) == sorted(a["name"] for a in httpx.get(f"{base}/reconstructions/{job_id}").json()["artifacts"])
    shot(page, "console-result.png", server["tmp"])

    # the iso slider, moved with the keyboard, re-extracts on the server: the point count changes
    points0 = m["points"]
    page.select_option("#iso-method", "backprojection")
    page.focus("#iso")
    for _ in range(15):
        page.keyboard.press("ArrowRight")
    tau = float(page.input_value("#iso"))
    page.wait_for_function("t => Number(document.querySelector('#iso-status').dataset.tau) === t", arg=tau,
                           timeout=60_000)
    points = int(page.get_attribute("#iso-status", "data-points"))
    direct = httpx.get(f"{base}/reconstructions/{job_id}/extract",
                       params={"method": "backprojection", "threshold": tau}).json()
    assert tau > m["threshold"] + 0.1 and points == direct["points"] and points < points0
    page.wait_for_function("n => window.__shsasViewer.summary()['backprojection points'].points === n", arg=points)
    # ... and the metrics table follows the level: the row's scores are those the server gave
    # for it (the demo survey has ground truth), not the job's own any more
    row = "#metrics tr[data-method=backprojection]"
    page.wait_for_function("([r, t]) => Number(document.querySelector(r).dataset.tau) === t", arg=[row, tau])
    shown = dict(page.eval_on_selector_all(f"{row} td", "tds => tds.map(td => [td.dataset.metric, td.dataset.value])"))
    assert float(shown["threshold"]) == direct["threshold"] and int(float(shown["points"])) == points
    for key in ("pc_surface_f1", "pc_fscore", "mesh_surface_f1", "mesh_pieces"):
        assert float(shown[key]) == pytest.approx(direct["metrics"][key], rel=1e-9), key
    assert float(shown["pc_surface_f1"]) != pytest.approx(m["metrics"]["pc_surface_f1"], rel=1e-6)
    assert "scores at τ" in page.inner_text("#metrics-note")

    # report.html opens in a sandboxed frame (no scripts from user data on this origin)
    page.click("#artifacts a:text-is('report.html')")
    page.wait_for_selector("#report-frame:not([hidden])")
    assert page.get_attribute("#report-frame", "sandbox") == ""
    # ... and shows it: the frame's pixels carry the report's text, not a blank white box
    frame = page.frame_locator("#report-frame")
    frame.locator("h1").wait_for()
    assert frame.locator("h1").inner_text() == "shsas reconstruction report"
    page.wait_for_function("() => true", polling=500)  # one more frame painted
    ink = dark_share(page.locator("#report-frame").screenshot())
    assert ink > MIN_TEXT_SHARE, f"the report frame looks blank ({ink:.4f} of its pixels are dark)"
    shot(page, "console-report.png", server["tmp"], clip=page.locator("#report-frame").bounding_box())

    # a phone-sized window: one column, nothing wider than the screen
    page.set_viewport_size({"width": 390, "height": 844})
    assert page.evaluate("document.documentElement.scrollWidth") <= 391
    page.evaluate("window.scrollTo(0, 0)")
    shot(page, "console-phone.png", server["tmp"])


def test_viewer_tools_reset_scale_measure(ui, server) -> None:
    """Opened straight from its address: reset view, a scale bar in metres, a distance measured
    between two clicked surface points, the colour legend and the view saved as an image."""
    page, base = ui.page, server["base"]
    done = [j for j in httpx.get(base + "/reconstructions", params={"status": "succeeded"}).json()["items"]
            if j["spec"]["methods"] == ["backprojection"]]
    assert done, "needs the demo job of test_demo_job_result_view"
    job_id = done[0]["id"]
    page.goto(f"{base}/#/jobs/{job_id}")
    page.wait_for_selector(f"body[data-viewer-ready='{job_id}']", state="attached", timeout=60_000)
    cam = "() => window.__shsasViewer.camera.position.toArray()"
    home = page.evaluate(cam)
    # the scale bar: a round length, drawn as long as that length is on screen at the orbit centre
    bar = page.locator("#scalebar")
    assert bar.is_visible()
    metres, px = float(bar.get_attribute("data-metres")), float(bar.get_attribute("data-px"))
    assert f"{metres:.0e}"[0] in "125" and 40 <= px <= 130 and abs(bar.bounding_box()["width"] - px) < 2
    per_px = page.evaluate("""() => { const v = window.__shsasViewer; const d = v.camera.position.distanceTo(v.controls.target);
        return 2 * d * Math.tan(v.camera.fov * Math.PI / 360) / v.canvas.clientHeight; }""")
    assert metres == pytest.approx(px * per_px, rel=1e-6)
    # the survey frame's axes in the lower-right corner: red x, green y, blue z, turning with
    # the view
    def corner() -> np.ndarray:
        from PIL import Image

        img = np.asarray(Image.open(io.BytesIO(page.locator("#viewer").screenshot())).convert("RGB")).astype(int)
        return img[-GIZMO_PX:, -GIZMO_PX:]

    def axis_pixels(c: np.ndarray) -> dict[str, int]:
        r, g, b = c[..., 0], c[..., 1], c[..., 2]  # by the dominant channel (lines are anti-aliased)
        return {"x": int(((r > g + 60) & (r > b + 60)).sum()), "y": int(((g > r + 50) & (g > b + 30)).sum()),
                "z": int(((b > r + 60) & (b > g + 30)).sum())}

    before_turn = corner()
    page.evaluate("() => { const v = window.__shsasViewer; v.gizmo.scene.visible = false; v.render(); }")
    bare = axis_pixels(corner())
    page.evaluate("() => { const v = window.__shsasViewer; v.gizmo.scene.visible = true; v.render(); }")
    drawn = axis_pixels(before_turn)
    assert all(drawn[a] - bare[a] > 20 for a in "xyz"), (drawn, bare)
    # turn the view, then "Reset view" brings back the first one
    box = page.locator("#viewer").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(cx, cy)
    page.mouse.down()
    page.mouse.move(cx + 150, cy + 40, steps=6)
    page.mouse.up()
    assert not np.allclose(page.evaluate(cam), home, atol=1e-4)
    assert np.abs(corner() - before_turn).sum(axis=2).astype(bool).mean() > 0.02  # the axes turned too
    # keyboard zoom: "+" brings the camera closer to the orbit centre, "-" takes it back
    dist = "() => { const v = window.__shsasViewer; return v.camera.position.distanceTo(v.controls.target); }"
    d0 = page.evaluate(dist)
    page.focus("#viewer")
    page.keyboard.press("+")
    assert page.evaluate(dist) == pytest.approx(0.8 * d0, rel=1e-9)
    page.keyboard.press("-")
    assert page.evaluate(dist) == pytest.approx(d0, rel=1e-9)
    page.click("#reset-view")
    assert np.allclose(page.evaluate(cam), home, atol=1e-9)
    # measure: two clicks on the surface; the distance is the one between the two picked points
    page.click("#measure")
    assert page.get_attribute("#measure", "aria-pressed") == "true"
    page.mouse.click(cx, cy)
    page.wait_for_function("() => window.shsasConsole.tools.picks.length === 1")
    page.mouse.click(cx + 40, cy + 25)
    page.wait_for_function("() => window.shsasConsole.tools.picks.length === 2")
    d = float(page.get_attribute("#measure-out", "data-metres"))
    picks = page.evaluate("() => window.shsasConsole.tools.picks.map(p => p.toArray())")
    assert d == pytest.approx(float(np.linalg.norm(np.subtract(*picks))), rel=1e-9) and d > 0
    diag = page.evaluate("() => { const b = window.__shsasViewer.box(); return b.max.distanceTo(b.min); }")
    assert d < diag  # both points on what is drawn
    assert page.inner_text("#measure-out").startswith("distance ")
    # the colour legend: each layer's swatch is the colour it is drawn in; the intensity scale
    # shows while a point cloud is drawn
    swatches = dict(page.eval_on_selector_all("#layers label", "ls => ls.map(l => [l.textContent.trim(), "
                                              "l.querySelector('.swatch').dataset.colour])"))
    drawn = page.evaluate("""() => Object.fromEntries([...window.__shsasViewer.layers].filter(([, o]) => o.userData.kind === 'mesh')
        .map(([n, o]) => { let c = null; o.traverse(m => { if (m.isMesh) c = '#' + m.material.color.getHexString(); }); return [n, c]; }))""")
    assert drawn and all(swatches[name] == colour for name, colour in drawn.items()), (swatches, drawn)
    assert swatches["backprojection points"] == "intensity" and page.is_hidden("#cloud-legend")
    page.check("#layer-backprojection-points")
    page.wait_for_selector("#cloud-legend:not([hidden])")
    assert "intensity" in page.inner_text("#cloud-legend")
    # "Save image": the view as drawn, a PNG named after the survey, the same size as the canvas
    from PIL import Image

    with page.expect_download() as dl:
        page.click("#screenshot")
    path = dl.value.path()
    assert dl.value.suggested_filename == f"{Path(done[0]['input']['filename']).stem}_view.png"
    img = Image.open(path)
    size = page.evaluate("() => [window.__shsasViewer.canvas.width, window.__shsasViewer.canvas.height]")
    assert list(img.size) == size
    pixels = np.asarray(img.convert("RGB")).reshape(-1, 3)
    assert (np.abs(pixels.astype(int) - [16, 21, 28]).sum(axis=1) > 30).mean() > MIN_DRAWN_SHARE  # not just the background


def test_compare_panes_move_together(ui, server) -> None:
    """A job's methods side by side at #/jobs/{id}/compare, one pane each, one camera for all;
    the first view is drawn from the worker's light previews, the full files one click away."""
    page, base = ui.page, server["base"]
    with open(server["demo"], "rb") as fh:
        r = httpx.post(base + "/reconstructions", files={"survey": ("demo.h5", fh)},
                       data={"spec": json.dumps(COMPARE_SPEC), "label": "three methods"}, timeout=120)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    fetched: list[str] = []
    page.on("requestfinished", lambda req: fetched.append(req.url.split("?")[0]))
    row = f"li.job[data-job-id='{job_id}']"
    page.wait_for_selector(f"{row}[data-status=succeeded]", timeout=JOB_TIMEOUT_MS)
    page.click(f"{row} .compare")
    page.wait_for_selector(f"body[data-compare-ready='{job_id}']", state="attached", timeout=60_000)
    assert page.url.endswith(f"/#/jobs/{job_id}/compare")
    assert page.eval_on_selector_all("#compare-panes figcaption", "fs => fs.map(f => f.textContent.split(' —')[0])") == [
        "backprojection", "Reed et al. (SH degree 0)", "SH-SAS"]
    # the pipeline's warnings stand above the views (and on the row), as the API gives them
    warnings = httpx.get(f"{base}/reconstructions/{job_id}").json()["warnings"]
    shown = page.eval_on_selector_all("#result-warnings li", "lis => lis.map(li => li.textContent)")
    assert len(shown) == len(warnings) and all(w["message"] in t for w, t in zip(warnings, shown, strict=True))
    assert page.is_visible("#result-warnings") == bool(warnings)
    assert page.inner_text(f"{row} .warn").count("⚠") == len(warnings)
    cams = "() => window.shsasConsole.result.panes.map(v => v.camera.position.toArray())"
    before = page.evaluate(cams)
    assert all(np.allclose(c, before[0]) for c in before)  # framed alike
    # drag in the second pane: every pane turns the same way
    box = page.locator("#compare-panes canvas").nth(1).bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] / 2 + 120, box["y"] + box["height"] / 2 + 30, steps=8)
    page.mouse.up()
    after = page.evaluate(cams)
    assert not np.allclose(after[1], before[1], atol=1e-4), "the drag did not move the camera"
    for c in after:
        assert np.allclose(c, after[1], atol=1e-9), after
    # the wheel in the first pane zooms all of them
    box0 = page.locator("#compare-panes canvas").nth(0).bounding_box()
    page.mouse.move(box0["x"] + 50, box0["y"] + 50)
    page.mouse.wheel(0, 300)
    page.wait_for_function("() => { const p = window.shsasConsole.result.panes.map(v => v.camera.position.toArray());"
                           " return p.every(c => c.every((x, k) => Math.abs(x - p[0][k]) < 1e-9)); }")
    zoomed = page.evaluate(cams)
    assert not np.allclose(zoomed[0], after[0], atol=1e-4)
    shot(page, "console-compare.png", server["tmp"])
    # the first view came from the previews, not the full files
    glbs = [u.rsplit("/", 1)[1] for u in fetched if u.endswith(".glb") and "/artifacts/" in u]
    assert sorted(glbs) == sorted(f"{m}_mesh_preview.glb" for m in ("backprojection", "reed", "shsas")), glbs
    page.click("#full-res")
    page.wait_for_function("() => document.querySelector('#full-res').hidden")
    page.wait_for_selector(f"body[data-compare-ready='{job_id}']", state="attached", timeout=60_000)
    page.wait_for_function("n => performance.getEntriesByType('resource').filter(e => /_mesh\\.glb$/.test(e.name)).length >= n",
                           arg=3)
    # back to the single view: its own address
    page.click("#tab-view")
    page.wait_for_selector("#compare", state="hidden")
    assert page.url.endswith(f"/#/jobs/{job_id}") and page.evaluate("window.shsasConsole.result.panes.length") == 0
    # the download budget of a first complete view with three methods: every response body from
    # a fresh page load on the job's address until every layer is drawn
    fresh = Page(ui.page.context.browser, base)
    try:
        got: list[tuple[str, int]] = []
        fresh.page.on("requestfinished", lambda req: got.append((req.url, req.sizes()["responseBodySize"])))
        fresh.page.goto(f"{base}/#/jobs/{job_id}")
        fresh.page.wait_for_selector(f"body[data-viewer-ready='{job_id}']", state="attached", timeout=60_000)
        total = sum(n for _, n in got)
        print(f"first complete view of {job_id[:8]}: {total / 1e6:.2f} MB in {len(got)} responses")  # -s shows it
        assert total <= FIRST_VIEW_BUDGET, (total, got)
        assert not any(u.split("?")[0].endswith(".ply") for u, _ in got)  # clouds wait to be switched on
    finally:
        fresh.close()


def test_two_jobs_side_by_side(ui, server) -> None:
    """Two jobs ticked in the list open side by side at #/compare/{a}/{b}: one pane each with
    all its methods, one camera for both, one metrics table with the rows of both; a reload
    keeps the view."""
    page, base = ui.page, server["base"]
    ids = []
    for label, spec in (("coarse grid", {"methods": ["backprojection"], "grid": 16, "device": "cpu"}),
                        ("fine grid", {"methods": ["backprojection"], "grid": 32, "device": "cpu"})):
        with open(server["demo"], "rb") as fh:
            r = httpx.post(base + "/reconstructions", files={"survey": ("demo.h5", fh)},
                           data={"spec": json.dumps(spec), "label": label}, timeout=120)
        assert r.status_code == 202, r.text
        ids.append(r.json()["id"])
    for job_id in ids:
        page.wait_for_selector(f"li.job[data-job-id='{job_id}'][data-status=succeeded]", timeout=JOB_TIMEOUT_MS)
    assert page.is_hidden("#compare-jobs")
    for job_id in ids:
        page.check(f"li.job[data-job-id='{job_id}'] .pick-box")
    page.click("#compare-jobs")
    ready = ",".join(ids)
    page.wait_for_selector(f"body[data-compare-ready='{ready}']", state="attached", timeout=60_000)
    assert page.url.endswith(f"/#/compare/{ids[0]}/{ids[1]}")
    assert page.inner_text("#result-h") == "coarse grid beside fine grid"
    captions = page.eval_on_selector_all("#compare-panes figcaption", "fs => fs.map(f => f.textContent)")
    assert [c.split(" —")[0] for c in captions] == ["coarse grid", "fine grid"]
    rows = page.eval_on_selector_all("#metrics tbody tr", "trs => trs.map(tr => [tr.dataset.job, tr.dataset.method])")
    assert rows == [[ids[0], "backprojection"], [ids[1], "backprojection"]]
    faces = [int(float(page.get_attribute(f"#metrics tr[data-job='{i}'] td[data-metric=faces]", "data-value"))) for i in ids]
    want = [httpx.get(f"{base}/reconstructions/{i}/artifacts/report.json").json()["methods"][0]["faces"] for i in ids]
    assert faces == want
    assert page.is_hidden("#job-extras") and page.is_hidden("#single-view")
    cams = "() => window.shsasConsole.result.panes.map(v => v.camera.position.toArray())"
    box = page.locator("#compare-panes canvas").nth(0).bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] / 2 - 100, box["y"] + box["height"] / 2 + 20, steps=8)
    page.mouse.up()
    a, b = page.evaluate(cams)
    assert np.allclose(a, b, atol=1e-9)
    shot(page, "console-compare-jobs.png", server["tmp"])
    page.reload()
    page.wait_for_selector(f"body[data-compare-ready='{ready}']", state="attached", timeout=60_000)
    # one job's own page again: its MIPs, survey and files are back
    page.goto(f"{base}/#/jobs/{ids[1]}")
    page.wait_for_selector(f"body[data-viewer-ready='{ids[1]}']", state="attached", timeout=60_000)
    assert page.is_visible("#job-extras") and page.is_visible("#single-view")


def test_errors_shown_beside_their_fields(ui, server) -> None:
    page = ui.page
    posts: list[str] = []  # uploads (the estimates the form asks for as it changes are not)
    page.on("request", lambda r: posts.append(r.url) if r.method == "POST" and "/reconstructions" in r.url else None)
    # a file that is no survey, dropped on the drop zone: refused from its first bytes, before
    # any upload, with the message under the file field and in the list of problems
    page.evaluate("""() => {
        const dt = new DataTransfer();
        dt.items.add(new File(['this is not a survey\\n'.repeat(50)], 'notes.txt', {type: 'text/plain'}));
        document.querySelector('#drop').dispatchEvent(new DragEvent('drop', {dataTransfer: dt, bubbles: true}));
    }""")
    assert "notes.txt" in page.inner_text("#survey-name")
    page.click("#submit-btn")
    page.wait_for_function("() => document.querySelector('#err-survey').textContent.length > 0", timeout=60_000)
    assert "not a recognised survey" in page.inner_text("#err-survey")
    assert "not a recognised survey" in page.inner_text("#submit-errors")
    assert posts == [], posts
    # an emptied numeric field is flagged, not sent as its default
    page.set_input_files("#survey-input", str(server["demo"]))
    page.fill("#spec-iters", "")
    page.fill("#spec-sh_degree", "")
    page.click("#submit-btn")
    page.wait_for_selector("#submit-errors:not([hidden])")
    assert page.inner_text("#err-spec-iters").startswith("iters: empty")
    assert page.inner_text("#err-spec-sh_degree").startswith("sh_degree: empty")
    listed = page.eval_on_selector_all("#submit-errors li", "lis => lis.map(li => li.textContent)")
    assert [t.split(":")[0] for t in listed] == ["sh_degree", "iters"], listed
    assert page.evaluate("document.activeElement.id") == "spec-sh_degree" and posts == []
    page.reload()
    page.wait_for_selector("#spec-grid")
    # a spec value over its limit: the API's message beside that field, which gets the focus
    page.set_input_files("#survey-input", str(server["demo"]))
    fill_spec(page, {"grid": "9999"})
    posts.clear()
    page.click("#submit-btn")
    page.wait_for_function("() => document.querySelector('#err-spec-grid').textContent.length > 0", timeout=60_000)
    assert len(posts) == 1  # this one went to the server, which refused it
    msg = page.inner_text("#err-spec-grid")
    assert msg.startswith("spec.grid") and "512" in msg
    assert page.evaluate("document.activeElement.id") == "spec-grid"
    assert page.inner_text("#err-spec-iters") == "" and page.inner_text("#err-survey") == ""
    assert page.inner_text("#submit-errors li").startswith("spec.grid")  # every refusal listed in view
    shot(page, "console-error.png", server["tmp"])


def test_presets_with_run_time_estimates(ui, server) -> None:
    """Quick look, standard and paper, each with the cost model's CPU estimate; choosing one
    sets the form; the estimate follows the form and names what a submission would be refused
    for, before any upload."""
    page = ui.page
    uploads: list[str] = []
    page.on("request", lambda r: uploads.append(r.url) if r.method == "POST" and "/reconstructions" in r.url else None)
    names = ["quick", "standard", "paper"]
    page.wait_for_function("ns => ns.every(n => document.querySelector(`#preset-${n}-cost`)?.dataset.seconds)",
                           arg=names, timeout=30_000)
    secs = {n: float(page.get_attribute(f"#preset-{n}-cost", "data-seconds")) for n in names}
    assert secs["quick"] < secs["standard"] < secs["paper"], secs
    assert page.is_checked("#preset-standard")  # the form starts at the spec's defaults
    page.wait_for_function("() => document.querySelector('#estimate').dataset.seconds")
    assert float(page.get_attribute("#estimate", "data-seconds")) == secs["standard"]
    page.check("#preset-quick")
    ticked = page.eval_on_selector_all("input[name=methods]:checked", "bs => bs.map(b => b.value)")
    assert ticked == ["backprojection"]
    page.wait_for_function("s => Number(document.querySelector('#estimate').dataset.seconds) === s", arg=secs["quick"])
    assert "on a CPU worker" in page.inner_text("#estimate")
    page.check("#preset-paper")
    assert page.input_value("#spec-iters") == "50000" and page.input_value("#spec-num_rays") == "4800"
    assert len(page.eval_on_selector_all("input[name=methods]:checked", "bs => bs")) == 3  # all methods again
    # the paper's setting on the CPU queue: refused, said before any upload
    page.fill("#spec-device", "cpu")
    assert not page.is_checked("#preset-paper")  # an edited form is no longer the preset
    page.wait_for_function("() => document.querySelector('#estimate').textContent.includes('would be refused')",
                           timeout=30_000)
    assert "SHSAS_MAX_CPU_JOB_S" in page.inner_text("#estimate")
    top = page.locator("#submit").bounding_box()
    shot(page, "console-presets.png", server["tmp"], clip={"x": top["x"], "y": top["y"], "width": top["width"], "height": 700})
    page.fill("#spec-iters", "")
    page.wait_for_function("() => document.querySelector('#estimate').textContent.includes('fill in every field')")
    assert uploads == []


def insert_jobs(server, n: int) -> list[str]:
    """``n`` finished jobs (every third failed, the rest cancelled) straight into the server's job
    store, as submissions of the keyless owner would leave them, plus one running job held by a
    worker elsewhere (fresh heartbeat) older than all of them. Returns the ids, running one first."""
    import json
    import time
    import uuid

    from jobs.store import LOCAL_OWNER, JobStore, jobs

    store = JobStore(f"sqlite:///{Path(server['env']['SHSAS_DATA_DIR']) / 'shsas.db'}")
    now = time.time()
    rows, ids = [], []
    for i in range(n + 1):
        running = i == n
        status = "running" if running else "failed" if i % 3 == 0 else "cancelled"
        jid = uuid.uuid4().hex
        ids.append(jid)
        rows.append({"id": jid, "owner": LOCAL_OWNER, "spec": json.dumps({"methods": ["backprojection"]}),
                     "input_digest": "0" * 64, "input_name": "survey.h5", "input_bytes": 1, "queue": "cpu",
                     "status": status, "progress": 0.5 if running else 0.0, "attempts": 1,
                     "cancel_requested": False, "created_at": now - 3600 + (0 if running else i),
                     "started_at": now - 3600, "finished_at": None if running else now - 60,
                     "updated_at": now, "artifacts": "[]", "error": "inserted by the test" if status == "failed" else None,
                     "client_name": f"scan-{i:03d}.h5", "label": "held elsewhere" if running else None,
                     "lease_owner": "elsewhere" if running else None,
                     "heartbeat_at": now + 86400 if running else None})  # never stale within the test
    with store.engine.begin() as conn:
        conn.execute(jobs.insert(), rows)
    store.dispose()
    return [ids[-1], *ids[:-1]]


def remove_jobs(server, ids: list[str]) -> None:
    from jobs.store import JobStore

    store = JobStore(f"sqlite:///{Path(server['env']['SHSAS_DATA_DIR']) / 'shsas.db'}")
    for jid in ids:
        store.delete(jid)
    store.dispose()


def listed_ids(page) -> list[str]:
    return page.eval_on_selector_all("li.job", "lis => lis.map(li => li.dataset.jobId)")


def walk_pages(page) -> list[str]:
    """Every job id the list shows, page by page with "Older", from the first page."""
    seen = listed_ids(page)
    while page.is_enabled("#jobs-older"):
        before = page.inner_text("#jobs-page")
        page.click("#jobs-older")
        page.wait_for_function("t => document.querySelector('#jobs-page').textContent !== t", arg=before)
        page.wait_for_function("() => document.querySelectorAll('li.job').length > 0")
        seen += listed_ids(page)
    return seen


def test_every_job_reachable_by_paging_filter_and_search(ui, server) -> None:
    page, base = ui.page, server["base"]
    ids = insert_jobs(server, 120)
    try:
        everything, cursor = [], None
        while True:  # what the API holds for this owner: the 121 jobs plus the other tests'
            got = httpx.get(base + "/reconstructions", params={"limit": 100, **({"cursor": cursor} if cursor else {})}).json()
            everything += [j["id"] for j in got["items"]]
            if not (cursor := got["next_cursor"]):
                break
        page.reload()
        page.wait_for_function("n => document.querySelectorAll('li.job').length === n", arg=PAGE_SIZE)
        assert listed_ids(page)[0] == ids[0]  # the running job first, although it is the oldest
        assert "running" in page.inner_text(f"li.job[data-job-id='{ids[0]}'] .meta")
        page.evaluate("document.querySelector('#spec-box').open = false")  # the list, not the form
        shot(page, "console-list.png", server["tmp"])
        walked = walk_pages(page)
        assert len(walked) == len(set(walked)) and set(walked) == set(everything) and set(ids) <= set(walked)
        # back to newer pages
        page.click("#jobs-newer")
        last = (len(everything) + PAGE_SIZE - 1) // PAGE_SIZE
        page.wait_for_function("t => document.querySelector('#jobs-page').textContent === t", arg=f"page {last - 1}")
        # a status filter: only the failed ones, every one of them, across pages
        page.select_option("#jobs-status", "failed")
        page.wait_for_function("() => document.querySelector('#jobs-page').textContent === 'page 1' && "
                               "[...document.querySelectorAll('li.job')].every(li => li.dataset.status === 'failed')")
        failed = walk_pages(page)
        want = {j["id"] for j in httpx.get(base + "/reconstructions", params={"status": "failed", "limit": 100}).json()["items"]}
        assert set(failed) == want and len(failed) == len(want) >= 40
        # a text search, over the uploaded file names, combined with the filter
        page.select_option("#jobs-status", "")
        page.fill("#jobs-search", "SCAN-07")
        page.wait_for_function("() => document.querySelectorAll('li.job').length === 10")
        assert sorted(page.eval_on_selector_all("li.job .title", "ts => ts.map(t => t.textContent)")) == [
            f"scan-{i:03d}.h5" for i in range(70, 80)]
        page.fill("#jobs-search", "no such job")
        page.wait_for_selector("#jobs-empty:not([hidden])")
        assert page.inner_text("#jobs-empty") == "No job matches this filter."
    finally:
        remove_jobs(server, ids)


def test_leaving_mid_upload_asks_first(ui, server) -> None:
    """While an upload is in flight the page asks before it is left; when none is, it does not."""
    page = ui.page
    dialogs: list[str] = []

    def answer(d) -> None:
        dialogs.append(d.type)
        d.dismiss()  # stay on the page

    page.on("dialog", answer)
    held = []
    page.route("**/reconstructions", lambda route: held.append(route) if route.request.method == "POST"
               else route.fallback())  # the upload never gets an answer while the test looks
    page.set_input_files("#survey-input", str(server["demo"]))
    page.click("#submit-btn")
    page.wait_for_function("() => document.querySelector('#upload-status').textContent.length > 0")
    page.wait_for_timeout(300)
    page.close(run_before_unload=True)
    page.wait_for_timeout(1000)
    assert dialogs == ["beforeunload"] and not page.is_closed()
    held[0].abort("connectionreset")  # the upload ends: the page may now be left without a question
    page.wait_for_selector("#retry-btn:not([hidden])")
    page.close(run_before_unload=True)
    page.wait_for_event("close", timeout=10_000) if not page.is_closed() else None
    assert dialogs == ["beforeunload"] and page.is_closed()


def test_page_loads_nothing_from_elsewhere(ui, server) -> None:
    """Every request of a full page load goes to the server (the fixture refuses and logs the rest)."""
    seen: list[str] = []
    ui.page.on("request", lambda r: seen.append(r.url))
    ui.page.reload()
    ui.page.wait_for_selector("#spec-grid")
    assert any(u.endswith("/console/app.js") for u in seen) and any("/schemas/reconstruction-spec" in u for u in seen)
    assert all(u.startswith((server["base"], "data:", "blob:")) for u in seen), seen
    assert ui.page.evaluate("document.querySelectorAll('script[src^=http], link[href^=http]').length") == 0


def test_keyboard_reaches_the_controls(ui) -> None:
    page = ui.page
    page.keyboard.press("Tab")
    assert page.evaluate("document.activeElement.textContent") == "Skip to the jobs"
    reached = set()
    for _ in range(120):
        page.keyboard.press("Tab")
        reached.add(page.evaluate("document.activeElement.id"))
        if "submit-btn" in reached:
            break
    assert {"key-input", "survey-input", "spec-methods-backprojection", "spec-grid", "spec-device",
            "submit-btn"} <= reached, reached


def test_key_flow(browser, server) -> None:
    """Last in the module: once a key exists the server wants it, from the page as from curl."""
    created = subprocess.run([*SHSAS, "keys", "create", "console-test"], capture_output=True, text=True,
                             timeout=120, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO), **server["env"]})
    assert created.returncode == 0, created.stderr
    key = created.stdout.strip().splitlines()[-1]
    ui = Page(browser, server["base"])
    try:
        page = ui.page
        page.goto(server["base"] + "/")
        page.wait_for_selector("#banner:not([hidden])")
        assert "API key required" in page.inner_text("#banner")
        page.fill("#key-input", "shsas_wrong_key")
        page.press("#key-input", "Enter")
        page.wait_for_function("() => document.querySelector('#banner').textContent.includes('invalid or revoked')")
        assert "paste an API key" in page.inner_text("#banner")
        page.fill("#key-input", key)
        page.click("#key-form button[type=submit]")
        page.wait_for_selector("#banner", state="hidden")
        page.wait_for_selector("#jobs-empty:not([hidden])")  # a new key owns no jobs yet
        assert key not in page.url and page.input_value("#key-input") == ""
        assert page.evaluate("sessionStorage.getItem('shsas.apiKey')") == key
        assert page.evaluate("localStorage.length") == 0
        # the key lives for the tab's session only
        other = ui.ctx.new_page()
        other.goto(server["base"] + "/")
        other.wait_for_selector("#banner:not([hidden])")
        assert "API key required" in other.inner_text("#banner")
        other.close()
    finally:
        ui.close()

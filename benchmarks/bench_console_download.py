"""Console benchmark: how many bytes a browser downloads before the first complete 3-D view of a
finished job, and how many more the full-resolution files cost. Prints figures, never asserts.

Opens the console at ``#/jobs/{id}`` in Debian's Chromium (Playwright), waits until every layer
of the view is drawn (``body[data-viewer-ready]``), and sums the body sizes of every response
the page received from loading the page on (the page and its script included). Then presses
"Load full resolution" and sums what that adds. Goal: with 3 methods on the demo bunny, at most
8 MB for the first complete view.

    # a server with a finished job (e.g. the demo bunny with 3 methods, submitted through the API):
    PYTHONPATH=$PWD python benchmarks/bench_console_download.py --base http://127.0.0.1:8000 --job ID
"""

from __future__ import annotations

import argparse
from collections import defaultdict

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu"]


def measure(base: str, job: str, key: str | None) -> None:
    from playwright.sync_api import sync_playwright

    sizes: dict[str, int] = defaultdict(int)
    phase = {"now": "first view"}
    per_phase: dict[str, dict[str, int]] = {"first view": {}, "full resolution": {}}

    def done(req) -> None:
        n = req.sizes()["responseBodySize"]
        name = req.url.split("?")[0].replace(base, "")
        per_phase[phase["now"]][name] = per_phase[phase["now"]].get(name, 0) + n
        sizes[phase["now"]] += n

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        if key:
            page.add_init_script(f"sessionStorage.setItem('shsas.apiKey', {key!r})")
        page.on("requestfinished", done)
        page.goto(f"{base}/#/jobs/{job}")
        page.wait_for_selector(f"body[data-viewer-ready='{job}']", state="attached", timeout=600_000)
        page.wait_for_load_state("networkidle")
        phase["now"] = "full resolution"
        if page.is_visible("#full-res"):
            page.click("#full-res")
            page.wait_for_function("() => document.querySelector('#full-res').hidden")
            page.wait_for_selector(f"body[data-viewer-ready='{job}']", state="attached", timeout=600_000)
            page.wait_for_load_state("networkidle")
        scene = page.evaluate("window.__shsasViewer.summary()")
        browser.close()
    for name, files in per_phase.items():
        print(f"\n{name}: {sizes[name] / 1e6:.2f} MB in {len(files)} responses")
        for url, n in sorted(files.items(), key=lambda kv: -kv[1])[:12]:
            print(f"  {n / 1e6:8.3f} MB  {url}")
    print("\nlayers after full resolution:", {k: v.get("triangles", v.get("points")) for k, v in scene.items()})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="the server, e.g. http://127.0.0.1:8000")
    ap.add_argument("--job", required=True, help="a succeeded job's id")
    ap.add_argument("--key", help="API key, when the server wants one")
    a = ap.parse_args()
    measure(a.base.rstrip("/"), a.job, a.key)


if __name__ == "__main__":
    main()

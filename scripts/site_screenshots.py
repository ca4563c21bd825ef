#!/usr/bin/env python
"""Screenshots of the documentation site as users see it, taken with headless Chromium.

    python scripts/site_screenshots.py [--mathjax DIR] [--out docs/assets]

Builds the site (``mkdocs build --strict``) into a temporary directory, serves it on localhost
and saves ``home.png`` (the home page) and ``api.png`` (the API page of ``lobattodae``) at
1440×1000. The site loads MathJax from a CDN; on a machine without that network, ``--mathjax``
points at a local copy of MathJax 3's ``es5`` directory (``npm pack mathjax@3``), which is
served in its place so that the formulas render as they do online. Needs ``chromium`` on the
PATH (Debian: ``apt-get install chromium``).
"""

from __future__ import annotations

import argparse
import functools
import http.server
import pathlib
import shutil
import subprocess
import sys
import tempfile
import threading

ROOT = pathlib.Path(__file__).resolve().parent.parent
CDN = "https://cdn.jsdelivr.net/npm/mathjax@3/es5/tex-mml-chtml.js"
PAGES = {"home.png": "", "api.png": "api/lobattodae/"}
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--hide-scrollbars", "--virtual-time-budget=5000", "--window-size=1440,1000"]


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format, *args):  # noqa: A002 - the base class's signature
        pass


def build(site: pathlib.Path, mathjax: pathlib.Path | None) -> None:
    subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(site)], cwd=ROOT, check=True)
    if mathjax is None:
        return
    shutil.copytree(mathjax, site / "_mathjax")
    for page in site.rglob("*.html"):
        text = page.read_text(encoding="utf-8")
        if CDN in text:
            page.write_text(text.replace(CDN, "/_mathjax/tex-mml-chtml.js"), encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mathjax", type=pathlib.Path, help="a local copy of MathJax 3's es5 directory")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "docs" / "assets")
    ns = parser.parse_args()
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        sys.exit("chromium is not on the PATH (Debian: apt-get install chromium)")
    ns.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        site = pathlib.Path(tmp) / "site"
        build(site, ns.mathjax)
        handler = functools.partial(_QuietHandler, directory=str(site))
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        try:
            for name, path in PAGES.items():
                profile = pathlib.Path(tmp) / f"profile-{name}"
                url = f"http://127.0.0.1:{server.server_port}/{path}"
                subprocess.run([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                                f"--screenshot={ns.out / name}", url], check=True, capture_output=True, timeout=120)
                print(f"wrote {ns.out / name} ({url})")
        finally:
            server.shutdown()


if __name__ == "__main__":
    main()

"""Full-page screenshots of a leaderboard page in headless Chromium, wide and phone width.

    python scripts/screenshot_leaderboard.py HTML_PATH OUT_DIR

Writes ``OUT_DIR/leaderboard-1400.png`` and ``OUT_DIR/leaderboard-390.png``
(viewport widths in CSS pixels). Drives Debian's ``/usr/bin/chromium`` through
Python playwright (``executable_path``, no downloaded browser) with the flags
that keep it quiet on a closed network; ``tests/test_leaderboard.py`` opens
the page through :func:`open_chromium` too.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
#: Flags that keep Chromium from reaching out (it runs on closed networks, e.g. CI).
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync"]
#: Viewport widths of the screenshots: a laptop window and a phone.
WIDTHS = (1400, 390)


@contextlib.contextmanager
def open_chromium() -> Iterator:
    """A headless Chromium browser context (fresh profile, removed afterwards)."""
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as profile, sync_playwright() as pw:
        browser = pw.chromium.launch_persistent_context(
            profile, executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


def screenshots(html_path: str | Path, out_dir: str | Path,
                widths: tuple[int, ...] = WIDTHS) -> list[Path]:
    """Save a full-page PNG of ``html_path`` per viewport width; returns their paths."""
    url = Path(html_path).resolve().as_uri()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    with open_chromium() as browser:
        for width in widths:
            page = browser.new_page()
            page.set_viewport_size({"width": width, "height": 900})
            page.goto(url)
            page.wait_for_load_state("load")
            path = out / f"leaderboard-{width}.png"
            page.screenshot(path=str(path), full_page=True)
            page.close()
            paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("html_path", help="the leaderboard page, e.g. results/leaderboard/"
                        "leaderboard.html")
    parser.add_argument("out_dir", help="directory for the PNGs")
    args = parser.parse_args(argv)
    if not Path(args.html_path).is_file():
        parser.error(f"no such file: {args.html_path}")
    for path in screenshots(args.html_path, args.out_dir):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Open a round's replay page in a real headless browser (Debian's chromium) and check it renders.

    python scripts/check_replay.py data/round/demo_face_round_replay.html [--screenshot docs/round_replay.png]

Checks: the page's DOM after its scripts ran holds plotly's plot (its slider and the booms' traces),
and the screenshot is not blank (enough pixels of the booms' colours). Exits 1 with the reason otherwise;
exits 2 when no chromium is installed. The test tests/test_schedule.py runs it when chromium is present.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--window-size=1200,800",
         "--virtual-time-budget=15000"]


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def run_browser(html: Path, *extra: str, timeout: float = 120) -> subprocess.CompletedProcess:
    exe = chromium()
    with tempfile.TemporaryDirectory() as profile:
        return subprocess.run([exe, *FLAGS, f"--user-data-dir={profile}", *extra, html.resolve().as_uri()],
                              capture_output=True, text=True, timeout=timeout)


def check(html: Path, screenshot: Path) -> list[str]:
    """Problems found (empty: the replay renders)."""
    problems = []
    dom = run_browser(html, "--dump-dom").stdout
    for needle, what in (("plotly-graph-div", "plotly's plot"), ("slider", "the time slider"),
                         ("boom L", "boom L's trace")):
        if needle not in dom:
            problems.append(f"the rendered page lacks {what} ({needle!r})")
    screenshot.parent.mkdir(parents=True, exist_ok=True)
    run_browser(html, f"--screenshot={screenshot.resolve()}")
    if not screenshot.exists() or screenshot.stat().st_size == 0:
        return [*problems, f"no screenshot written to {screenshot}"]
    from matplotlib.image import imread

    img = imread(screenshot)[..., :3]
    blue = ((img[..., 2] > 0.55) & (img[..., 0] < 0.35)).sum()  # boom L (#1f77b4)
    orange = ((img[..., 0] > 0.85) & (img[..., 1] > 0.35) & (img[..., 1] < 0.65) & (img[..., 2] < 0.3)).sum()
    if blue < 50 or orange < 50:
        problems.append(f"the screenshot shows too little of the booms ({blue} blue, {orange} orange pixels)")
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("html", type=Path)
    ap.add_argument("--screenshot", type=Path, default=None)
    a = ap.parse_args(argv)
    if chromium() is None:
        print("no chromium: apt-get install -y chromium", file=sys.stderr)
        return 2
    shot = a.screenshot or a.html.with_suffix(".png")
    problems = check(a.html, shot)
    for p in problems:
        print(p, file=sys.stderr)
    print(f"{'FAILED' if problems else 'ok'}: {a.html} -> {shot}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())

"""Render ``dvc plots show``'s page in headless chromium with the network cut off, and check every plot drew.

    dvc repro                                    # (or any training) so data/models/*_history.csv exist
    python scripts/check_plots_offline.py --screenshot docs/img/dvc_plots_offline.png

Runs ``dvc plots show`` in the repository (its page template, .dvc/plots/offline.html, carries vega), then
loads the page with every host unresolvable and a dead proxy, and counts the drawn charts (vega-embed's
canvases) against the page's plots. Exit status 0 when all of them drew.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from check_dashboard import CHROMIUM_FLAGS, chromium, shrink_png  # noqa: E402

OFFLINE = ["--proxy-server=127.0.0.1:9", "--host-resolver-rules=MAP * ~NOTFOUND"]


def render(repo: Path, dvc: str = "dvc", targets: list[str] | None = None) -> Path:
    out = subprocess.run([dvc, "plots", "show", *(targets or [])], cwd=repo, capture_output=True, text=True,
                         timeout=300)
    if out.returncode != 0:
        raise RuntimeError(f"dvc plots show failed: {out.stderr[-2000:]}")
    return repo / "dvc_plots" / "index.html"


def check(page: Path, screenshot: Path | None = None) -> dict:
    html = page.read_text()
    with tempfile.TemporaryDirectory(prefix="chromium-") as profile:
        flags = [*CHROMIUM_FLAGS, *OFFLINE, f"--user-data-dir={profile}", "--window-size=1100,1500"]
        dom = subprocess.run([chromium(), *flags, "--dump-dom", page.resolve().as_uri()], capture_output=True,
                             text=True, timeout=180).stdout
    if screenshot is not None:
        with tempfile.TemporaryDirectory(prefix="chromium-") as profile:
            subprocess.run([chromium(), *CHROMIUM_FLAGS, *OFFLINE, f"--user-data-dir={profile}",
                            "--window-size=1100,1500", f"--screenshot={screenshot.resolve()}",
                            page.resolve().as_uri()], capture_output=True, timeout=180, check=True)
        shrink_png(screenshot)
    report = {"page": str(page), "plots": len(re.findall(r"vegaEmbed\('#", html)),
              "drawn": dom.count("<canvas"), "cdn_scripts": len(re.findall(r"<script[^>]+src=\"https?:", html))}
    report["ok"] = report["plots"] > 0 and report["drawn"] == report["plots"] and report["cdn_scripts"] == 0
    return report


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("targets", nargs="*", help="plot ids or files for dvc plots show (default: all)")
    parser.add_argument("--repo", type=Path, default=Path(__file__).resolve().parents[1])
    parser.add_argument("--dvc", default="dvc")
    parser.add_argument("--screenshot", type=Path)
    args = parser.parse_args()
    report = check(render(args.repo, args.dvc, args.targets), args.screenshot)
    for key, value in report.items():
        print(f"{key}: {value}")
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())

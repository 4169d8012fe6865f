"""Open the MLflow dashboard in a real headless browser and check it lands on the runs table.

    python scripts/check_dashboard.py                                  # the project's store, experiment boom-ik
    python scripts/check_dashboard.py experiment=quick --screenshot docs/dashboard_runs.png
    python scripts/check_dashboard.py tracking.uri=sqlite:////tmp/x/mlflow.db experiment=quick

Starts the UI as ``python -m pipeline.dashboard`` does (on a free port), loads the URL that stage prints
in Debian's chromium (headless, fresh profile, no background networking), and checks the rendered page:
the runs table's header and the experiment's newest run names are there, and the GenAI overview is not.
For contrast it loads the experiment's plain page too, which MLflow 3.17 opens on the GenAI overview.
Exit status 0 when the runs table shows; the arguments are config overrides, as for a stage.
"""

from __future__ import annotations

import argparse
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run", "--window-size=1400,900",
                  "--virtual-time-budget=20000", "--hide-scrollbars"]
RUNS_TABLE = "Run Name"        # the runs table's first column header
GENAI = ("Tokens",)            # the GenAI overview's token charts ("Traces" is in the sidebar of both views)


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def browse(url: str, *, screenshot: Path | None = None, browser: str | None = None) -> str:
    """The DOM of ``url`` after its scripts ran (a fresh profile each time: no stored workflowType)."""
    browser = browser or chromium()
    if browser is None:
        raise RuntimeError("no chromium: apt-get install -y chromium")
    with tempfile.TemporaryDirectory(prefix="chromium-") as profile:
        what = [f"--screenshot={screenshot}"] if screenshot else ["--dump-dom"]
        out = subprocess.run([browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", *what, url],
                             capture_output=True, text=True, timeout=180)
    if out.returncode != 0:
        raise RuntimeError(f"chromium failed ({out.returncode}): {out.stderr[-2000:]}")
    return out.stdout


def shrink_png(path: Path, colours: int = 64) -> None:
    """A screenshot for the docs: palette PNG (a UI screenshot has few colours)."""
    from PIL import Image

    Image.open(path).convert("RGB").quantize(colours).save(path, optimize=True)


def check(overrides: list[str], screenshot: Path | None = None) -> dict:
    """Start the UI on the configured store, load its runs URL, and report what the page shows."""
    from mlflow.tracking import MlflowClient

    from pipeline.core.config import compose
    from pipeline.tracking import dashboard
    from pipeline.tracking.runs import TrackingSettings

    cfg = compose([*overrides, f"tracking.ui_port={free_port()}"])
    settings = TrackingSettings.from_config(cfg.tracking)
    proc, url = dashboard.start(settings)
    try:
        exp_id = url.split("/experiments/")[1].split("/")[0]
        names = [r.info.run_name for r in MlflowClient(settings.uri).search_runs(
            [exp_id], order_by=["attributes.start_time DESC"], max_results=5)]
        runs_dom = browse(url)
        plain_dom = browse(url.split("/runs?")[0])
        if screenshot is not None:
            browse(url, screenshot=screenshot.resolve())
            shrink_png(screenshot)
    finally:
        if proc is not None:
            dashboard.stop(proc)
    report = {
        "url": url,
        "runs_table": RUNS_TABLE in runs_dom,
        "run_names_shown": [n for n in names if n in runs_dom],
        "run_names": names,
        "genai_on_runs_url": [w for w in GENAI if w in runs_dom],
        "genai_on_plain_url": [w for w in GENAI if w in plain_dom],
        "runs_table_on_plain_url": RUNS_TABLE in plain_dom,
    }
    report["ok"] = (report["runs_table"] and report["run_names_shown"] == names
                    and not report["genai_on_runs_url"])
    return report


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("overrides", nargs="*", help="config overrides (experiment=quick, tracking.uri=...)")
    parser.add_argument("--screenshot", type=Path, help="write a PNG of the runs page here")
    args = parser.parse_args()
    report = check(args.overrides, args.screenshot)
    for key, value in report.items():
        print(f"{key}: {value}")
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())

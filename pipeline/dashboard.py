"""Stage ``dashboard``: the MLflow UI on the project's store, and the URL that opens on the runs.

    python -m pipeline.dashboard                     # boom-ik's runs: http://127.0.0.1:5000/#/experiments/<id>/runs?...
    python -m pipeline.dashboard experiment=quick    # the quick study's experiment, boom-ik-quick
    python -m pipeline.dashboard tracking.ui_port=5001

It prints the URL of the experiment's runs table (MLflow 3.17 opens an experiment on its GenAI overview
otherwise) and serves until Ctrl-C. With ``tracking.uri`` an MLflow server it only prints that server's URL.
A port another process listens on (another MLflow UI, on another store) is refused, exit 2 naming
``tracking.ui_port``: no URL is printed that would open another store's runs.
"""

from __future__ import annotations

from omegaconf import DictConfig

from pipeline.core.signals import terminate_as_interrupt
from pipeline.core.stage import run_stage, stage_main
from pipeline.tracking import dashboard
from pipeline.tracking.runs import TrackingSettings


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, serve, threads=None)


def serve(cfg: DictConfig) -> None:
    """Start the UI, print its runs table's URL, serve until Ctrl-C or SIGTERM (while starting too),
    then stop the UI and its web server (a few seconds) and return without a traceback."""
    settings = TrackingSettings.from_config(cfg.tracking)
    proc = None
    try:
        with terminate_as_interrupt():  # Ctrl-C or SIGTERM: the UI (its own process group) goes too
            proc, url = dashboard.start(settings)
            print(f"MLflow dashboard, experiment {settings.experiment} (its runs table):\n  {url}", flush=True)
            if proc is not None:
                proc.wait()
    except KeyboardInterrupt:
        print("MLflow dashboard: stopping", flush=True)
    finally:
        if proc is not None:
            dashboard.stop(proc)


if __name__ == "__main__":
    main()

"""The dashboard: the URL that opens MLflow 3.17 on the runs table, and (opt-in, with chromium) a real
headless browser showing that table on a fresh profile, where the experiment's plain page shows GenAI."""

import importlib.util
import shutil
import sys
from pathlib import Path

import pytest

from pipeline.tracking.dashboard import runs_url, ui_command
from pipeline.tracking.runs import TrackingSettings, stage_run

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "check_dashboard.py"


def load_script():
    spec = importlib.util.spec_from_file_location("check_dashboard_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_runs_url_is_the_runs_route_with_the_workflow_type():
    assert runs_url("http://127.0.0.1:5000/", "7") == \
        "http://127.0.0.1:5000/#/experiments/7/runs?workflowType=machine_learning"


def test_the_ui_serves_the_configured_store(tmp_path):
    s = TrackingSettings.from_config({"enabled": False, "uri": f"sqlite:///{tmp_path}/m.db", "experiment": "e",
                                      "artifact_root": str(tmp_path / "art"), "ui_port": 5123})
    cmd = ui_command(s, s.ui_host, s.ui_port)
    assert cmd[cmd.index("--backend-store-uri") + 1] == f"sqlite:///{tmp_path}/m.db"
    assert cmd[cmd.index("--port") + 1] == "5123" and cmd[cmd.index("--host") + 1] == "127.0.0.1"


def test_the_ui_starts_without_mlflow_s_job_execution_unless_the_environment_asks():
    from pipeline.tracking.dashboard import ui_environment

    env = ui_environment({"PATH": "/bin"})
    assert env == {"PATH": "/bin", "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
    asked = {"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "true"}
    assert ui_environment(asked) == asked


@pytest.mark.parametrize("port", [0, 70000, "x", True])
def test_a_bad_port_is_named(tmp_path, port):
    from pipeline.core.errors import ConfigError

    with pytest.raises(ConfigError, match="tracking.ui_port"):
        TrackingSettings.from_config({"enabled": False, "experiment": "e", "ui_port": port})


def _listening():
    """A socket listening on a free loopback port (another process's server, for the dashboard): (socket, port)."""
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(1)
    return s, s.getsockname()[1]


def test_a_taken_port_is_refused_naming_it_and_no_url_is_printed(tmp_path, capsys):
    """Once the stage printed a URL to whatever answered there (another store's experiment), exit 0, or crashed
    with a traceback: now exit 2 naming tracking.ui_port, before the UI starts, and no URL."""
    from pipeline.core.config import compose
    from pipeline.core.stage import run_stage
    from pipeline.dashboard import serve

    taken, port = _listening()
    with taken:
        cfg = compose([f"tracking.uri=sqlite:///{tmp_path}/d.db", f"tracking.artifact_root={tmp_path}/art",
                       f"tracking.ui_port={port}"])
        with pytest.raises(SystemExit) as e:
            run_stage(cfg, serve, threads=None)
    out = capsys.readouterr()
    assert e.value.code == 2
    assert f"tracking.ui_port = {port}: 127.0.0.1:{port} is in use by another process" in out.err
    assert "http" not in out.out and "http" not in out.err


def test_an_answer_from_another_server_is_never_taken_for_the_ui(tmp_path, monkeypatch):
    """Should the port be taken between the check and the UI's start, the health check may be answered by the
    other server: the answer counts only when this UI's process tree listens on the port."""
    import http.server
    import subprocess
    import sys
    import threading

    from pipeline.core.errors import ConfigError
    from pipeline.tracking import dashboard

    class Health(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - http.server's name
            self.send_response(200)
            self.end_headers()

        def log_message(self, *args):
            pass

    other = http.server.HTTPServer(("127.0.0.1", 0), Health)  # another store's UI
    port = other.server_address[1]
    threading.Thread(target=other.serve_forever, daemon=True).start()
    started, popen = [], subprocess.Popen

    def fake_ui(cmd, **kw):  # a UI that never gets the port
        started.append(popen([sys.executable, "-c", "import time; time.sleep(60)"], start_new_session=True))
        return started[-1]

    monkeypatch.setattr(dashboard, "port_free", lambda host, port: True)  # the race: checked free, then taken
    monkeypatch.setattr(dashboard.subprocess, "Popen", fake_ui)
    monkeypatch.setattr(dashboard, "prepare_store", lambda settings: "1")  # the store is not under test
    s = TrackingSettings.from_config({"enabled": False, "uri": f"sqlite:///{tmp_path}/m.db", "experiment": "e",
                                      "artifact_root": str(tmp_path / "art"), "ui_port": port})
    try:
        with pytest.raises(ConfigError, match=f"tracking.ui_port = {port}: .* is in use by another process"):
            dashboard.start(s)
    finally:
        other.shutdown()
        other.server_close()
    assert started and started[0].poll() is not None  # the UI started is stopped again


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("chromium") is None, reason="needs chromium (apt-get install -y chromium)")
def test_a_headless_browser_lands_on_the_runs_table(tmp_path):
    check_dashboard = load_script()
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    settings = TrackingSettings.from_config({"enabled": True, "uri": uri, "experiment": "boom-ik-quick",
                                             "artifact_root": str(tmp_path / "art")})
    for name in ("train-cuikm", "evaluate"):
        with stage_run(settings, name, {"stage": name}) as run:
            run.log_metrics({"val_hole_mm": 3.0}, step=0)
    report = check_dashboard.check(["experiment=quick", f"tracking.uri={uri}",
                                    f"tracking.artifact_root={tmp_path / 'art'}"])
    assert report["ok"], report
    assert report["run_names_shown"] == ["evaluate", "train-cuikm"]
    assert report["genai_on_plain_url"] and not report["runs_table_on_plain_url"]  # what a plain URL gives


def _dvc() -> str | None:
    local = Path(sys.executable).with_name("dvc")
    return str(local) if local.is_file() else shutil.which("dvc")


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("chromium") is None or _dvc() is None, reason="needs chromium and dvc")
def test_dvc_plots_render_offline_with_the_project_template(tmp_path):
    """The project's plots section, template and page in a scratch DVC repo: all four charts draw in a
    browser that cannot reach any host, each method in its own colour on a log axis."""
    import yaml

    root = Path(__file__).resolve().parents[1]
    repo = tmp_path / "repo"
    shutil.copytree(root / ".dvc" / "plots", repo / ".dvc" / "plots")
    shutil.copy(root / ".dvc" / "config", repo / ".dvc" / "config")
    plots = yaml.safe_load((root / "dvc.yaml").read_text())["plots"]
    (repo / "dvc.yaml").write_text(yaml.safe_dump({"plots": plots}))
    (repo / "params.yaml").write_text("paths:\n  data: data\n")
    (repo / "data" / "models").mkdir(parents=True)
    for k, m in enumerate(["sikm", "sikm_best", "uikm", "cuikm"]):
        rows = [f"{s},{1000 / (s + 1) + k},{2.0 / (s + 1)},{900 / (s + 1)},{800 / (s + 1)}" for s in (0, 50, 100, 149)]
        (repo / "data" / "models" / f"{m}_history.csv").write_text(
            "step,val_hole_mm,loss,val_start_mm,val_preview_mm\n" + "\n".join(rows) + "\n")
    script = importlib.util.spec_from_file_location("check_plots_offline", SCRIPT.with_name("check_plots_offline.py"))
    sys.path.insert(0, str(SCRIPT.parent))
    module = importlib.util.module_from_spec(script)
    script.loader.exec_module(module)
    page = module.render(repo, _dvc())
    spec = page.read_text()
    assert '"type": "log"' in spec and "regexp('^.*/|_history[.]csv$', 'g')" in spec
    report = module.check(page)
    assert report == {**report, "plots": 4, "drawn": 4, "cdn_scripts": 0, "ok": True}


@pytest.mark.slow
@pytest.mark.parametrize("when", ["starting", "serving"])
def test_ctrl_c_stops_the_dashboard_and_its_ui_without_a_traceback(tmp_path, when):
    """Ctrl-C while the UI starts or serves: the stage stops the UI's process group and exits 0, with no
    traceback (it once printed one, and waited 30 s for the UI's web server)."""
    import os
    import signal
    import subprocess

    import psutil

    cmd = [sys.executable, "-m", "pipeline.dashboard", f"tracking.uri=sqlite:///{tmp_path}/d.db",
           f"tracking.artifact_root={tmp_path}/art", "tracking.ui_port=5397", f"hydra.run.dir={tmp_path}/h"]
    proc = subprocess.Popen(cmd, cwd=SCRIPT.parents[1], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen = []
    marker = "Security middleware" if when == "starting" else "runs table"
    while not any(marker in line for line in seen):
        line = proc.stdout.readline()
        assert line, "".join(seen)
        seen.append(line)
    ui = [int(p) for p in subprocess.run(["pgrep", "-f", "5397"], capture_output=True, text=True).stdout.split()
          if int(p) != proc.pid]
    tree = [" ".join(c.cmdline()) for c in psutil.Process(proc.pid).children(recursive=True)]
    proc.send_signal(signal.SIGINT)
    out = "".join(seen) + proc.communicate(timeout=60)[0]
    if when == "serving":  # the UI and its web server; MLflow's job execution stays off (no runner, no consumers)
        assert len(tree) == 2 and not any("jobs" in c or "huey" in c for c in tree), tree
    assert proc.returncode == 0, out
    assert "Traceback" not in out and "stopping" in out
    for pid in ui:  # the UI and its web server are gone too
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)

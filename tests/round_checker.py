"""The independent round checker as the tests use it: its command's module loaded from the checkout's
``scripts/check_round.py`` (as a user runs it; it imports nothing of ``pipeline``), and one in-process run of
its command."""

from __future__ import annotations

import contextlib
import importlib.util
import io
import json

from pipeline.core.config import PROJECT_ROOT

SCRIPT = PROJECT_ROOT / "scripts" / "check_round.py"


def load_checker():
    spec = importlib.util.spec_from_file_location("check_round_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


cr = load_checker()


def run_checker(traj, overrides, *extra) -> tuple[int, dict | None, str]:
    """``check_round.py <traj> <overrides> <extra>`` in-process: (exit code, its JSON report or None, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = cr.main([str(traj), *overrides, *extra])
        except SystemExit as e:
            rc = e.code
    return rc, (json.loads(out.getvalue()) if out.getvalue() else None), err.getvalue()

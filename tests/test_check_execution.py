"""scripts/check_round.py on executed rounds (issue 27, spec section 8): actions and interlocks made BY
HAND here from the small twin round's trajectory file (naive but safe interlocks: every pair of actions
of the two booms ordered as planned), so these tests need nothing of the planner's execution code. The
good set passes every draw; each planted fault fails with its exit code and message; the execution rule
and the episode floors agree with hand values and brute force."""

import contextlib
import importlib
import importlib.util
import io
import json

import numpy as np
import pandas as pd
import pytest

from pipeline.core.config import PROJECT_ROOT

_spec = importlib.util.spec_from_file_location("check_round_script", PROJECT_ROOT / "scripts" / "check_round.py")
cr = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cr)
ex = importlib.import_module("round_check.execute")  # the checker's own modules, through the script's path
ep = importlib.import_module("round_check.episodes")
rc_actions = importlib.import_module("round_check.actions")
JOINTS = [f"q{i}" for i in range(1, 9)]


def actions_from(traj: pd.DataFrame) -> pd.DataFrame:
    """Each boom's actions read off its rows: a move from the last row standing where the previous
    action left it to the next collar row (or the last row), a drill from a collar row to the end of
    its retraction (three rows on)."""
    out = []
    for boom, g in traj.groupby("boom", sort=False):
        t, q, ev, hole = g["t"].to_numpy(), g[JOINTS].to_numpy(), g["event"].to_numpy(), g["hole_id"].to_numpy()
        anchor, n = 0, 0
        for c in [*np.flatnonzero(ev == "collar"), len(t) - 1]:
            moving = np.flatnonzero(np.abs(q[anchor:c + 1] - q[anchor]).max(1) > 0)
            if len(moving):
                out.append((boom, n, "move", "", t[anchor + moving[0] - 1], t[c]))
                n += 1
            if ev[c] == "collar":
                out.append((boom, n, "drill", hole[c], t[c], t[c + 3]))
                n += 1
                anchor = c + 3
    return pd.DataFrame(out, columns=["boom", "action", "kind", "hole_id", "t_start", "t_end"])


def naive_interlocks(acts: pd.DataFrame) -> pd.DataFrame:
    """Every pair of actions of two booms, one ending before the other starts, ordered as planned."""
    a = acts.to_dict("records")
    rows = [(y["boom"], y["action"], x["boom"], x["action"]) for x in a for y in a
            if x["boom"] != y["boom"] and x["t_end"] <= y["t_start"] + 1e-9]
    return pd.DataFrame(rows, columns=["boom", "action", "after_boom", "after_action"])


@pytest.fixture(scope="module")
def base(small_twin_round):
    tmp, overrides = small_twin_round
    traj = pd.read_csv(tmp / "small_trajectory.csv", keep_default_na=False, dtype={"hole_id": str})
    acts = actions_from(traj)
    return tmp, overrides, acts, naive_interlocks(acts)


def _set(base, name, acts=None, locks=None, traj=None):
    """A copy of the round's set under ``name`` with its actions and interlocks (changed by the lambdas)."""
    tmp, _, a, i = base
    dst = tmp / f"x_{name}"
    dst.mkdir()
    t = pd.read_csv(tmp / "small_trajectory.csv", keep_default_na=False, dtype={"hole_id": str})
    (traj(t) if traj else t).to_csv(dst / "small_trajectory.csv", index=False)
    for f in ("small_round.csv", "small_round.json"):
        (dst / f).write_bytes((tmp / f).read_bytes())
    (acts(a.copy()) if acts else a).to_csv(dst / "small_actions.csv", index=False)
    (locks(i.copy()) if locks else i).to_csv(dst / "small_interlocks.csv", index=False)
    return dst / "small_trajectory.csv"


def _run(base, traj, *extra):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = cr.main([str(traj), *base[1], *extra])
        except SystemExit as e:
            rc = e.code
    return rc, (json.loads(out.getvalue()) if out.getvalue() else None), err.getvalue()


def _fails(base, traj, *needles, code=1, extra=("--execute", "4")):
    rc, report, err = _run(base, traj, *extra)
    text = "\n".join(report["violations"] + report["not_certified"]) if report else err
    assert rc == code, (rc, text)
    for n in needles:
        assert n in text, (n, text)
    return report, text


def _first_wait(acts):
    """R's first action waits at park for an action of L (the plan's serialised cut holes): that action."""
    r0 = acts[(acts["boom"] == "R") & (acts["action"] == 0)].iloc[0]
    l_ = acts[(acts["boom"] == "L") & (np.abs(acts["t_end"] - r0["t_start"]) < 1e-6)]
    assert len(l_) == 1 and r0["t_start"] > 1.0, "the small round's R waits at park for one action of L"
    return l_.iloc[0]


# -- the good set ---------------------------------------------------------------------------------

def test_the_good_set_passes_every_draw(base):
    rc, report, err = _run(base, _set(base, "good"), "--execute", "30", "--seed", "3")
    assert rc == 0, (err, report and report["violations"][:5])
    ex_ = report["execution"]
    n_holes = int((base[2]["kind"] == "drill").sum())
    assert ex_["checked"] and ex_["draws"] == 1 + 30 + n_holes + 2 and ex_["draws_by_kind"]["hole_at_3x"] == n_holes
    assert ex_["deadlocks"] == 0 and ex_["violations"] == 0 and ex_["violating_draws"] == 0
    mk = ex_["makespan_s"]
    assert mk["nominal"] == pytest.approx(mk["trajectory"], abs=1e-6) == report["makespan_s"]
    assert mk["p50"] <= mk["p95"] <= mk["max"] and mk["max"] > mk["trajectory"]
    # not vacuous: the two booms' simultaneous moves out of and into the centre are a candidate, swept
    # densely: its least distance is the trajectory's least boom-boom distance (the same instant)
    assert ex_["close_episode_pairs"] > 0 and ex_["windows_swept"] >= 1
    assert ex_["min_executed_candidate_distance_m"] >= report["pairs"]["L-R"]["distance_m"]["certified"] >= 0.3
    assert ex_["standing_at_interlocks_s"]["max"] >= ex_["standing_at_interlocks_s"]["p95"] > 0


def test_without_actions_the_execution_is_not_checked_and_said_so(small_twin_round):
    tmp, overrides = small_twin_round
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert cr.main([str(tmp / "small_trajectory.csv"), *overrides]) == 0
    assert json.loads(out.getvalue())["execution"]["checked"] is False
    with contextlib.redirect_stderr(io.StringIO()) as err:
        assert cr.main([str(tmp / "small_trajectory.csv"), *overrides, "--execute", "3"]) == 2
    assert "no actions file to execute" in err.getvalue()


# -- planted faults (exit 1) ----------------------------------------------------------------------

def test_a_deleted_interlock_the_round_needs_breaks_d_boom(base):
    """R waits at park for L to drill its cut hole; without that interlock R moves in while L drills:
    the booms meet, in the nominal draw and in others, and the plan is not reproduced."""
    wait = _first_wait(base[2])

    def delete(i):
        return i[~((i["boom"] == "R") & (i["action"] == 0) & (i["after_boom"] == "L")
                   & (i["after_action"] == wait["action"]))]

    report, text = _fails(base, _set(base, "deleted", locks=delete), "executed draw 0 (nominal",
                          "booms L and R", f"L#{wait['action']} (drill {wait['hole_id']})", "< d_boom 0.3 m",
                          "R#0", "no interlock holds it until its planned start")
    ex_ = report["execution"]
    assert ex_["violating_draws"] > 1 and ex_["windows_confirmed"] >= 1
    low = [float(m.split("distance ")[1].split(" m")[0]) for m in report["violations"] if "executed draw" in m]
    assert min(low) < 0.3


def test_an_interlock_cycle_is_a_deadlock(base):
    wait = _first_wait(base[2])  # R#0 waits for it: make it wait for R#1 too

    def cycle(i):
        return pd.concat([i, pd.DataFrame([{"boom": "L", "action": wait["action"], "after_boom": "R",
                                            "after_action": 1}])], ignore_index=True)

    report, text = _fails(base, _set(base, "cycle", locks=cycle), "deadlock:", f"L#{wait['action']}", "R#1", "R#0")
    assert report["execution"]["deadlocks"] == 1


def test_an_action_waiting_for_itself_is_a_deadlock(base):
    def itself(i):
        return pd.concat([i, pd.DataFrame([{"boom": "L", "action": 2, "after_boom": "L", "after_action": 2}])])

    _fails(base, _set(base, "itself", locks=itself), "deadlock: L#2", code=1)


# -- input errors (exit 2) ------------------------------------------------------------------------

def test_a_missing_action_row(base):
    _fails(base, _set(base, "missing", acts=lambda a: a.drop(index=2)), "small_actions.csv: boom 'L'",
           "action 3", "follows action 1: expected 2", code=2)


def test_an_action_listed_twice(base):
    _fails(base, _set(base, "twice", acts=lambda a: pd.concat([a, a.iloc[[1]]])), "action 1 is listed twice", code=2)


def test_an_interlock_naming_a_missing_action_or_boom(base):
    def missing(i):
        i.loc[3, "after_action"] = 99
        return i

    _fails(base, _set(base, "noaction", locks=missing), "small_interlocks.csv: row 5", "has no action 99",
           code=2)
    _fails(base, _set(base, "noboom", locks=lambda i: i.replace({"after_boom": {"L": "X"}})),
           "small_interlocks.csv: row 2", "after_boom 'X' is not a boom of the rig", code=2)


def test_bad_kind_drill_without_hole_and_missing_column(base):
    def kind(a):
        a.loc[0, "kind"] = "hover"
        return a

    def nameless(a):
        a.loc[1, "hole_id"] = ""
        return a

    _fails(base, _set(base, "kind", acts=kind), "row 2: kind 'hover' is not one of ['move', 'drill']", code=2)
    _fails(base, _set(base, "nameless", acts=nameless), "row 3: a drill without hole_id", code=2)
    _fails(base, _set(base, "nocol", acts=lambda a: a.drop(columns=["t_end"])), "missing column(s) ['t_end']",
           code=2)


def test_a_drill_window_that_is_not_the_holes(base):
    tmp = base[0]
    t = pd.read_csv(tmp / "small_trajectory.csv", keep_default_na=False, dtype={"hole_id": str})

    def short(a):  # ends at the retract row, not at the end of the retraction
        k = t.index[(t["boom"] == "L") & (t["event"] == "retract") & (t["hole_id"] == a.loc[1, "hole_id"])][0]
        a.loc[1, "t_end"] = t.loc[k, "t"]
        return a

    _fails(base, _set(base, "drillwin", acts=short), f"drill of hole {base[2].loc[1, 'hole_id']} spans",
           "the hole's collar to the end of its retraction", code=2)

    def other(a):  # names L's other hole
        a.loc[1, "hole_id"] = a.loc[3, "hole_id"]
        return a

    _fails(base, _set(base, "drillhole", acts=other), f"drill of hole {base[2].loc[3, 'hole_id']} spans", code=2)


def test_actions_that_disagree_with_the_trajectory(base):
    def late(a):  # L's first move starts a second late: the boom moves before its first action
        a.loc[0, "t_start"] = 1.0
        return a

    _fails(base, _set(base, "late", acts=late), "is not the time of any of its rows", code=2)
    t = pd.read_csv(base[0] / "small_trajectory.csv", keep_default_na=False)
    second = t.loc[t.index[t["boom"] == "L"][2], "t"]

    def later(a):
        a.loc[0, "t_start"] = second
        return a

    _fails(base, _set(base, "later", acts=later), "boom 'L': moves before its first action", "a boom stands still",
           code=2)

    def drill_as_move(a):
        a.loc[1, ["kind", "hole_id"]] = ["move", ""]
        return a

    _fails(base, _set(base, "asmove", acts=drill_as_move), "holds a drill row", code=2)

    def wait_inside(t):  # a planned wait in the middle of a move: its motion would depend on timing
        k = t.index[(t["boom"] == "L") & (t["event"] == "move")][10]
        t.loc[k, "event"] = "wait"
        return t

    _fails(base, _set(base, "waitinside", traj=wait_inside), "holds a wait row", code=2)


# -- the execution rule and the floors against independent values ---------------------------------

def test_the_execution_rule_against_hand_values(tmp_path):
    acts = pd.DataFrame([("L", 0, "move", "", 0, 2), ("L", 1, "drill", "A", 2, 12), ("L", 2, "move", "", 12, 15),
                         ("R", 0, "move", "", 12, 14), ("R", 1, "drill", "B", 14, 20), ("R", 2, "move", "", 20, 21)],
                        columns=["boom", "action", "kind", "hole_id", "t_start", "t_end"])
    acts.to_csv(tmp_path / "a.csv", index=False)
    pd.DataFrame([("R", 0, "L", 1)], columns=["boom", "action", "after_boom", "after_action"]).to_csv(
        tmp_path / "i.csv", index=False)
    a = rc_actions.read_actions(tmp_path / "a.csv", ["L", "R"])
    g = ex.graph(a, rc_actions.read_interlocks(tmp_path / "i.csv", a))
    assert g.cycle is None
    # A at 2x (20 s): L#1 2..22; R#0 waits until 22, 22..24; R#1 (B, 6 s) 24..30; R#2 30..31; L#2 22..25
    dur = np.array([[2, 20, 3, 2, 6, 1], [2, 10, 3, 2, 6, 1]], float)
    s, e = ex.execute(g, dur)
    np.testing.assert_allclose(s, [[0, 2, 22, 22, 24, 30], [0, 2, 12, 12, 14, 20]])
    np.testing.assert_allclose(e, s + dur)
    pd.DataFrame([("R", 0, "L", 1), ("L", 2, "R", 2)], columns=["boom", "action", "after_boom", "after_action"]
                 ).to_csv(tmp_path / "i2.csv", index=False)
    g = ex.graph(a, rc_actions.read_interlocks(tmp_path / "i2.csv", a))
    assert g.cycle is None  # L#2 after R#2: a wait, not a cycle
    pd.DataFrame([("R", 0, "L", 1), ("L", 1, "R", 2)], columns=["boom", "action", "after_boom", "after_action"]
                 ).to_csv(tmp_path / "i3.csv", index=False)
    g = ex.graph(a, rc_actions.read_interlocks(tmp_path / "i3.csv", a))
    assert sorted(g.cycle) == [1, 3, 4, 5]  # L#1 <- R#2 <- R#1 <- R#0 <- L#1
    w = ep.executed_windows(s[:, 3:], e[:, 3:])  # R's episodes: pause at park until 22, R#0, pause, ...
    np.testing.assert_allclose(w[0][0], [0, 22, 24, 24, 30, 30, 31])
    np.testing.assert_allclose(w[1][0], [22, 24, 24, 30, 30, 31, np.inf])


def test_the_draws():
    d = ex.draws(["A", "B", "C"], np.array([0, 0, 1]), ["L", "R"], 200, 7, True)
    assert len(d.labels) == 1 + 200 + 3 + 2 and d.labels[0].startswith("nominal")
    f = d.factor
    assert (f[0] == 1).all() and (f[1:201] >= 0.7).all() and (f[1:201] < 1.5).all() and f[1:201].std() > 0.2
    np.testing.assert_array_equal(f[201:204], [[3, 1, 1], [1, 3, 1], [1, 1, 3]])
    np.testing.assert_array_equal(f[204:], [[1.5, 1.5, 0.7], [0.7, 0.7, 1.5]])
    assert np.array_equal(ex.draws(["A"], np.array([0]), ["L"], 5, 7, False).factor,
                          ex.draws(["A"], np.array([0]), ["L"], 5, 7, False).factor)  # seeded


def test_episode_floors_lie_under_a_dense_brute_force(base):
    """Each certified floor between two episodes is at most the least capsule distance over dense
    samples of both episodes' configurations (every pair of instants); an episode pair flagged below
    d_boom has dense samples below it."""
    tmp, overrides, _, _ = base
    st = cr.settings.settings(overrides)
    rows = cr.files.read_trajectory(tmp / "small_trajectory.csv", {b.name: b.model.joint_names for b in st.booms})
    a = rc_actions.read_actions(_set(base, "floors").with_name("small_actions.csv"), ["L", "R"])
    win = [ep.episode_windows(a, b, rows[n]) for b, n in enumerate("LR")]
    cells = [ep.Cells(st.booms[b], rows[n], win[b]) for b, n in enumerate("LR")]
    fl = ep.floors(cells[0], cells[1], st.d_boom)
    rad = [b.radius for b in st.booms[0].model.bodies]

    def dense(b, e, n=150):
        w = win[b][e]
        t = np.linspace(w[0], w[1], n) if w[1] > w[0] else w[:1]
        r = rows["LR"[b]]
        q = np.stack([np.interp(t, r.t, r.q[:, j]) for j in range(8)], -1)
        return st.booms[b].model.body_points(st.booms[b].model.frames(q)) + st.booms[b].base

    rng = np.random.default_rng(0)
    picks = [(i, j) for i in range(fl.floor.shape[0]) for j in range(fl.floor.shape[1])]
    picks = [picks[k] for k in rng.choice(len(picks), 40, replace=False)] + [tuple(x) for x in np.argwhere(fl.below)]
    for i, j in picks:
        Pa, Pb = dense(0, i), dense(1, j)
        best = min((cr.distance.segment_distance(*np.broadcast_arrays(Pa[:, None, x, 0], Pa[:, None, x, 1],
                                                                      Pb[None, :, y, 0], Pb[None, :, y, 1]))
                    - rad[x] - rad[y]).min() for x in range(2) for y in range(2))
        assert fl.floor[i, j] <= best + 1e-12, (i, j)
        if fl.below[i, j]:
            assert best < st.d_boom + 0.05, (i, j, best)  # a sample below it; dense points within their spacing
        elif fl.floor[i, j] < 5:  # a floor that clears is not vacuous where the episodes are near
            assert fl.floor[i, j] >= min(st.d_boom, best - 0.05), (i, j, fl.floor[i, j], best)

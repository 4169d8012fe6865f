"""scripts/check_round.py on executed rounds (docs/reference.md section 8): actions and interlocks made BY
HAND here from the small twin round's trajectory file (naive interlocks: every pair of actions of the two
booms that do not overlap in the plan ordered as planned), so these tests need nothing of the planner's
execution code. The naive set passes every draw, but not the exact certification (the plan's
two simultaneous moves are apart only at their planned relative timing); each planted fault fails with
its exit code and message; the execution rule and the episode floors agree with hand values and brute
force. The certification itself: tests/test_certify.py."""

import contextlib
import importlib
import importlib.util
import io
import json

import numpy as np
import pandas as pd
import pytest
from round_checker import cr, run_checker

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
    return run_checker(traj, base[1], *extra)


def _fails(base, traj, *needles, code=1, extra=("--execute", "4")):
    rc, report, err = _run(base, traj, *extra)
    text = "\n".join(report["violations"] + report["not_certified"]) if report else err
    assert rc == code, (rc, text)
    for n in needles:
        assert n in text, (n, text)
    return report, text


def _only_certified(report, acts):
    """The set's only violations are the certification's, and they are the naive set's known gap: L's move
    out of its first hole and R's first move into its own (with R standing where that move left it, which
    the interlocks make wait for L's move), both started by the end of L's first drill, unordered."""
    assert report["violations"] and all(v.startswith("certified: ") for v in report["violations"]), \
        report["violations"][:5]
    cert = report["execution"]["certified"]
    wait = _first_wait(acts)
    l_move = f"L#{int(wait['action']) + 1} (move to hole"
    assert cert["violating_pairs"] >= 1 and cert["not_certified_pairs"] == 0
    assert all(v["segments"][0].startswith(l_move) and v["segments"][1].startswith("R") for v in cert["violating"])
    assert any(v["segments"][1].startswith("R#0 (move to hole") for v in cert["violating"])
    assert cert["least_sampled_distance_m"] < 0.3 and report["execution"]["violating_draws"] == 0


def _first_wait(acts):
    """R's first action waits at park for an action of L (the plan's serialised cut holes): that action."""
    r0 = acts[(acts["boom"] == "R") & (acts["action"] == 0)].iloc[0]
    l_ = acts[(acts["boom"] == "L") & (np.abs(acts["t_end"] - r0["t_start"]) < 1e-6)]
    assert len(l_) == 1 and r0["t_start"] > 1.0, "the small round's R waits at park for one action of L"
    return l_.iloc[0]


# -- the good set ---------------------------------------------------------------------------------

def test_the_good_set_passes_every_draw_but_not_the_certification(base):
    """Every draw is clear; the exact certification is not: the naive set leaves the plan's simultaneous
    moves unordered, apart only at their planned relative timing (they start on the same event, so
    no drilling time moves them apart: only a move taking other than its planned time would)."""
    rc, report, err = _run(base, _set(base, "good"), "--execute", "30", "--seed", "3")
    assert rc == 1, (err, report and report["violations"][:5])
    _only_certified(report, base[2])
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


def test_a_drill_whose_joints_change_is_refused(base):
    """Spec section 8: a drill is at constant joints, which is what lets an executed drill last any time."""
    def nudge(t):  # L's first drill row moved by 1 mrad on q1
        k = t.index[(t["boom"] == "L") & (t["event"] == "drill")][0]
        t.loc[k, "q1"] = t.loc[k, "q1"] + 1e-3
        return t

    _fails(base, _set(base, "drillmoves", traj=nudge), "the joints change by 0.001", "a drill is at constant joints",
           code=2)


def test_a_stretched_drill_stands_at_its_hole_not_in_its_next_move():
    """An executed window inside a drill that runs longer than planned: the boom stands at the hole for the
    whole of it. Laying its rows out by the drill's start (as a move's are) would run past the planned end
    into the boom's next move, and report that move's configurations as the drill's (a false violation
    found on the round benchmark's gen 150 trio)."""
    rows_mod = importlib.import_module("round_check.files")
    executed = importlib.import_module("round_check.executed")
    t = np.array([0.0, 1.0, 2.0, 50.0, 60.0, 61.0, 62.0])  # a move, the drill (collar..end), the next move
    q = np.zeros((len(t), 8))
    q[:2, 0] = [0.5, 0.2]
    q[2:5, 0] = 0.2  # at the hole from t = 1 to the end of the drill at 60
    q[5:, 0] = [0.6, 0.9]  # then away
    r = rows_mod.BoomRows(t, q, np.array(["park", "move", "collar", "drill", "retract", "move", "move"]),
                          np.array(["", "", "h", "h", "h", "", ""]), np.arange(len(t)))
    planned = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 60.0], [60.0, 60.0], [60.0, 62.0], [62.0, 62.0]])
    # the drill started at 1 and, at 1.5x, ends at 89.5: the window 70..80 lies past its planned end
    still = executed._window_rows(r, planned, 3, 1.0, 70.0, 80.0, still=True)
    assert np.allclose(still.q[:, 0], 0.2) and still.t[0] == 70.0 and still.t[-1] == 80.0
    shifted = executed._window_rows(r, planned, 3, 1.0, 70.0, 80.0)  # what a move's layout would give
    assert shifted.q[:, 0].max() > 0.2  # the next move's configurations: the fault the still layout avoids
    move = executed._window_rows(r, planned, 5, 100.0, 100.5, 101.5)  # a move shifted to its executed start
    assert np.allclose(move.q[:, 0], np.interp([60.5, 61.0, 61.5], t, q[:, 0]))


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


def test_floors_start_from_the_episodes_whatever_other_pairs_split(base):
    """A boom's cells are shared by its pairs with the other booms (a three-boom rig): floors computed after
    another pair has split the cells are the floors of fresh cells, one per pair of episodes. They started
    from every cell once, so a trio's third pair began from millions of cell pairs, hit the cap and kept
    unrefined floors tens of metres below the truth (gen 150 trio of the round benchmark)."""
    tmp, overrides, _, _ = base
    st = cr.settings.settings(overrides)
    rows = cr.files.read_trajectory(tmp / "small_trajectory.csv", {b.name: b.model.joint_names for b in st.booms})
    a = rc_actions.read_actions(_set(base, "floors_shared").with_name("small_actions.csv"), ["L", "R"])
    win = [ep.episode_windows(a, b, rows[n]) for b, n in enumerate("LR")]

    def cells():
        return [ep.Cells(st.booms[b], rows[n], win[b]) for b, n in enumerate("LR")]

    fresh = ep.floors(*cells(), st.d_boom)
    L, R = cells()
    ep.floors(L, ep.Cells(st.booms[1], rows["R"], win[1]), st.d_boom)  # another pair splits L's cells first
    assert len(L.episode) > L.episodes
    shared = ep.floors(L, R, st.d_boom)
    assert shared.floor.shape == fresh.floor.shape == (len(win[0]), len(win[1]))
    np.testing.assert_array_equal(shared.floor, fresh.floor)
    np.testing.assert_array_equal(shared.below, fresh.below)


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


# -- realised sets (--realised): made here from the planned files, re-timed per action ------------

def execute_by_hand(acts: pd.DataFrame, locks: pd.DataFrame, factor: dict) -> pd.DataFrame:
    """The execution rule, written out plainly (a second method, not the checker's): actions taken in
    planned start order (a topological order: every interlock and sequence edge points forward in the
    plan), each starting once its boom's previous action and every action ``locks`` makes it wait for
    have ended; a move keeps its duration, drill ``(boom, action)`` takes ``factor`` times its own."""
    acts = acts.assign(S=np.nan, E=np.nan)
    end = {}
    for i in acts.sort_values(["t_start", "t_end"]).index:
        a = acts.loc[i]
        key = (a["boom"], int(a["action"]))
        ready = [end.get((a["boom"], key[1] - 1), 0.0)]
        ready += [end[(x, int(y))] for x, y in
                  locks[(locks["boom"] == key[0]) & (locks["action"] == key[1])][["after_boom", "after_action"]]
                  .itertuples(index=False)]
        dur = (a["t_end"] - a["t_start"]) * factor.get(key, 1.0)
        acts.loc[i, ["S", "E"]] = max(ready), max(ready) + dur
        end[key] = max(ready) + dur
    return acts


def realise(tmp, name, acts, locks, factor, obey=None, table=None, stem="small"):
    """A realised set ``<stem>_executed_*`` in ``tmp/name`` from the planned one in ``tmp``: the
    actions executed by hand (:func:`execute_by_hand`, obeying ``obey``, default all ``locks``),
    each action's planned rows moved to its realised start and stretched by its own factor (a move
    keeps its pace, a drill's collar/drill/retract rows scale together), a pause carried by the rows
    either side of it; the round table and actions at the realised times; ``locks`` as the
    interlocks file; ``table`` changes the realised round table. Returns the trajectory's path and
    the realised actions."""
    dst = tmp / name
    dst.mkdir()
    traj = pd.read_csv(tmp / f"{stem}_trajectory.csv", keep_default_na=False, dtype={"hole_id": str})
    done = execute_by_hand(acts, locks if obey is None else obey, factor)
    parts = []
    for boom, g in traj.groupby("boom", sort=False):
        parts.append(g.iloc[:1])  # the park row at t = 0
        for _, a in done[done["boom"] == boom].sort_values("action").iterrows():
            inside = g[(g["t"] >= a["t_start"] - 1e-9) & (g["t"] <= a["t_end"] + 1e-9)].copy()
            scale = (a["E"] - a["S"]) / (a["t_end"] - a["t_start"])
            inside["t"] = a["S"] + (inside["t"] - a["t_start"]) * scale
            if a["kind"] == "move":  # a move ends on the collar row of the drill it leads to: there it waits
                ends = inside["event"].isin(["collar", "drill", "retract"])
                inside.loc[ends, ["event", "hole_id"]] = ["wait", ""]
            parts.append(inside)
    out = pd.concat(parts, ignore_index=True)
    # a row shared by two actions (or by the park row and a first action at t = 0) appears twice when
    # no pause parts them, the same joints at the same realised time: keep the later action's
    same_t = (out["boom"] == out["boom"].shift(-1)) & (out["t"].shift(-1) - out["t"] <= 1e-9)
    assert np.allclose(out.loc[same_t, JOINTS].to_numpy(), out.shift(-1).loc[same_t, JOINTS].to_numpy())
    out = out[~same_t]
    out.to_csv(dst / f"{stem}_executed_trajectory.csv", index=False)
    r = pd.read_csv(tmp / f"{stem}_round.csv", keep_default_na=False)
    drills = done[done["kind"] == "drill"].set_index("hole_id")
    r["t_start"] = r["hole_id"].map(drills["S"]).fillna(r["t_start"])
    r["t_end"] = r["hole_id"].map(drills["E"]).fillna(r["t_end"])
    (table(r) if table else r).to_csv(dst / f"{stem}_executed_round.csv", index=False)
    s = json.loads((tmp / f"{stem}_round.json").read_text())
    s.update({"makespan_s": float(out["t"].max()), "realised": True})
    (dst / f"{stem}_executed.json").write_text(json.dumps(s))
    real = done.assign(t_start=done["S"], t_end=done["E"]).drop(columns=["S", "E"])
    real.to_csv(dst / f"{stem}_executed_actions.csv", index=False)
    locks.to_csv(dst / f"{stem}_executed_interlocks.csv", index=False)
    return dst / f"{stem}_executed_trajectory.csv", real


def _realised(base, name, factor, **kw):
    tmp, _, acts, locks = base
    return realise(tmp, name, acts, locks, factor, **kw)


def _edit(path, change):
    """Rewrite the CSV at ``path`` through ``change`` (a DataFrame -> DataFrame)."""
    df = pd.read_csv(path, keep_default_na=False, dtype={"hole_id": str})
    change(df).to_csv(path, index=False)


def _hole(acts, boom, action):
    return acts[(acts["boom"] == boom) & (acts["action"] == action)].iloc[0]


def test_a_realised_round_with_a_stretched_drill_passes(base):
    """L's first drill at 1.3x, L's later actions shifted, R's first move (interlocked after it) later."""
    acts = base[2]
    c01 = _hole(acts, "L", 1)
    traj, real = _realised(base, "real_good", {("L", 1): 1.3})
    rc, report, err = _run(base, traj, "--realised")
    assert rc == 0, (err, report and report["violations"][:5])
    f = report["realised"]["factor"]
    assert f["max"] == pytest.approx(1.3, abs=1e-9) and f["min"] == pytest.approx(1.0, abs=1e-9)
    assert report["realised"]["factor_per_hole"][c01["hole_id"]] == pytest.approx(1.3, abs=1e-9)
    assert report["realised"]["interrupted"] == [] and report["holes"]["drilled"] == 6
    ex_ = report["execution"]
    assert ex_["checked"] and ex_["interlocks_broken"] == 0 and ex_["interlock_rows"] == len(base[3])
    # not vacuous: R's first move did wait for the stretched drill (an interlock held with no slack)
    r0 = _hole(real, "R", 0)
    assert r0["t_start"] == pytest.approx(_hole(real, "L", 1)["t_end"])
    assert r0["t_start"] > _hole(acts, "R", 0)["t_start"] + 20
    assert ex_["least_interlock_slack_s"] == pytest.approx(0.0, abs=1e-6)
    planned = json.loads((base[0] / "small_round.json").read_text())["makespan_s"]
    assert report["makespan_s"] == pytest.approx(planned + 0.3 * (c01["t_end"] - c01["t_start"]), abs=1e-6)


def test_a_realised_set_needs_realised_and_refuses_draws(base):
    traj, _ = _realised(base, "real_flags", {("L", 1): 1.3})
    _fails(base, traj, "a realised set (small_executed.json beside it", "check it with --realised", code=2, extra=())
    _fails(base, traj, "small_executed.json", "\"realised\": true", "--realised", code=2,
           extra=("--round", str(traj.with_name("small_executed_round.csv")), "--summary",
                  str(traj.with_name("small_executed.json"))))
    _fails(base, traj, "--execute with --realised", code=2, extra=("--realised", "--execute", "3"))
    _fails(base, traj, "--draws with --realised", code=2, extra=("--realised", "--draws", str(traj)))
    planned = base[0] / "small_trajectory.csv"
    _fails(base, planned, "not named <stem>_executed_trajectory.csv", code=2, extra=("--realised",))
    _fails(base, planned, "small_round.json", "no \"realised\": true", code=2,
           extra=("--realised", "--round", str(base[0] / "small_round.csv"), "--summary",
                  str(base[0] / "small_round.json")))


def test_a_realised_drill_whose_parts_scale_by_different_factors(base):
    c01 = _hole(base[2], "L", 1)
    traj, _ = _realised(base, "real_parts", {("L", 1): 1.3})

    def later_retract(t):  # the drilling part 2 s longer, the retraction 2 s shorter: same total
        k = t.index[(t["boom"] == "L") & (t["event"] == "retract") & (t["hole_id"] == c01["hole_id"])][0]
        t.loc[k, "t"] += 2.0
        return t

    _edit(traj, later_retract)
    _fails(base, traj, f"hole {c01['hole_id']}: collaring, drilling, retraction last", "times one factor",
           "the whole drill 1.300000x", extra=("--realised",))


def test_a_realised_actions_file_whose_drill_disagrees_with_the_trajectory(base):
    c01 = _hole(base[2], "L", 1)
    traj, _ = _realised(base, "real_actions", {("L", 1): 1.3})

    def planned_duration(a):  # the execute stage wrote the planned drilling time, not the realised one
        k = a.index[(a["boom"] == "L") & (a["action"] == 1)][0]
        a.loc[k, "t_end"] = a.loc[k, "t_start"] + (c01["t_end"] - c01["t_start"])
        return a

    _edit(traj.with_name("small_executed_actions.csv"), planned_duration)
    planned = c01["t_end"] - c01["t_start"]
    _fails(base, traj, f"boom L, hole {c01['hole_id']}: its drill action", f"lasts {planned:.6f} s, its drilling",
           f"{1.3 * planned:.6f} s", "do not follow its actions", extra=("--realised",))


def test_an_interlock_broken_by_the_realised_times(base):
    """The execute stage let R's first move start at its planned time, not waiting for L's stretched drill."""
    tmp, _, acts, locks = base
    wait = _first_wait(acts)
    ignored = locks[~((locks["boom"] == "R") & (locks["action"] == 0) & (locks["after_boom"] == "L")
                      & (locks["after_action"] == wait["action"]))]
    traj, real = _realised(base, "real_lock", {("L", int(wait["action"])): 1.3}, obey=ignored)
    report, text = _fails(base, traj, "interlock", "R#0 (move to hole", "starts at",
                          f"before L#{wait['action']} (drill {wait['hole_id']}) ends", extra=("--realised",))
    assert report["execution"]["interlocks_broken"] >= 1 and report["execution"]["least_interlock_slack_s"] < -20


def _interrupted(base, name, action=3, factor=0.4, collared=True, table=None):
    """L's ``action`` (a drill) stopped at ``factor`` of its time and reported ``interrupted``; with
    ``collared=False`` stopped before collaring ended: its collar row made a wait, no drill or
    retract rows, the boom standing through the action."""
    hole = _hole(base[2], "L", action)["hole_id"]

    def report_it(r):
        r.loc[r["hole_id"] == hole, "status"] = "interrupted"
        return table(r) if table else r

    traj, real = _realised(base, name, {("L", action): factor}, table=report_it)
    if not collared:
        def uncollar(t):
            rows = t.index[(t["boom"] == "L") & (t["hole_id"] == hole)]
            t.loc[rows[0], ["event", "hole_id"]] = ["wait", ""]
            return t.drop(index=rows[1:])

        _edit(traj, uncollar)
    return traj, real, hole


def test_an_interrupted_hole_is_reported_and_passes(base):
    traj, _, hole = _interrupted(base, "real_stop")
    rc, report, err = _run(base, traj, "--realised")
    assert rc == 0, (err, report and report["violations"][:5])
    assert report["realised"]["interrupted"] == [{"hole_id": hole, "boom": "L", "drilled": True,
                                                  "factor": pytest.approx(0.4, abs=1e-9)}]
    assert report["realised"]["factor"]["min"] == pytest.approx(0.4, abs=1e-9)
    assert report["holes"]["reported_not_drilled"] == 1
    traj, _, hole = _interrupted(base, "real_stop_early", collared=False)
    rc, report, err = _run(base, traj, "--realised")
    assert rc == 0, (err, report and report["violations"][:5])
    assert report["realised"]["interrupted"] == [{"hole_id": hole, "boom": "L", "drilled": False, "factor": None}]
    assert report["holes"]["drilled"] == 5


def test_an_interrupted_hole_drilled_again(base):
    """R's later drill renamed to L's interrupted hole (rows, actions, round table): drilled twice."""
    other = _hole(base[2], "R", 3)["hole_id"]
    traj, _, hole = _interrupted(base, "real_twice", table=lambda r: r[r["hole_id"] != other])
    _edit(traj, lambda t: t.replace({"hole_id": {other: hole}}))
    _edit(traj.with_name("small_executed_actions.csv"), lambda a: a.replace({"hole_id": {other: hole}}))
    _fails(base, traj, f"hole {hole}: interrupted, yet drilled 2 times", "boom L at t=", "boom R at t=",
           "never again by any boom", extra=("--realised",))


def test_a_realised_hole_neither_drilled_nor_reported(base):
    hole = _hole(base[2], "L", 3)["hole_id"]
    traj, _, _ = _interrupted(base, "real_lost", collared=False, table=lambda r: r[r["hole_id"] != hole])
    _fails(base, traj, f"hole {hole}: neither drilled nor reported in the round table", extra=("--realised",))


def test_an_interrupted_status_in_a_planned_table_is_refused(base):
    tmp = base[0]
    traj = _set(base, "planned_stop")
    _edit(traj.with_name("small_round.csv"), lambda r: r.assign(status=np.where(r.index == 0, "interrupted",
                                                                                r["status"])))
    _fails(base, traj, "small_round.csv: row 2: status 'interrupted'", "check it with --realised", code=2, extra=())
    assert tmp.is_dir()


# -- --draws: a planned round under exactly a file's draws ----------------------------------------

def _draws(path, rows):
    pd.DataFrame(rows, columns=["draw", "label", "hole_id", "factor"]).to_csv(path, index=False)
    return path


def test_a_draws_file_whose_draws_pass(base):
    tmp, _, acts, locks = base
    traj = _set(base, "draws_good")
    drills = acts[acts["kind"] == "drill"]
    c01 = _hole(acts, "L", 1)
    rng = np.random.default_rng(5)
    rows = [(0, "random", h, f) for h, f in zip(drills["hole_id"], rng.uniform(0.7, 1.5, len(drills)), strict=True)]
    rows += [(1, f"stall {c01['hole_id']}", c01["hole_id"], 3.0)]
    rows += [(2, "slow L", h, 1.5) for h in drills[drills["boom"] == "L"]["hole_id"]]
    rows += [(3, "random", h, 0.8) for h in drills["hole_id"][:2]]
    f = _draws(traj.with_name("draws.csv"), rows)
    rc, report, err = _run(base, traj, "--draws", str(f))
    assert rc == 1, (err, report and report["violations"][:5])  # the certification's gap, nothing of the draws
    _only_certified(report, acts)
    ex_ = report["execution"]
    assert ex_["draws"] == 1 + 4 and ex_["draws_by_kind"]["file"] == 4 and ex_["draws_by_kind"]["random"] == 0
    kinds = ex_["draws_file_by_kind"]
    assert {k: v["draws"] for k, v in kinds.items()} == {"random": 2, "stall": 1, "slow": 1}
    assert all(v["violating_draws"] == 0 for v in kinds.values())
    # the stall draw's makespan is the hand execution's (a second method of the execution rule)
    hand = execute_by_hand(acts, locks, {("L", 1): 3.0})["E"].max()
    assert kinds["stall"]["makespan_s"]["max"] == pytest.approx(hand, abs=1e-6)
    hand = execute_by_hand(acts, locks, {("L", int(a)): 1.5 for a in drills[drills["boom"] == "L"]["action"]})
    assert kinds["slow"]["makespan_s"]["max"] == pytest.approx(hand["E"].max(), abs=1e-6)
    rc, both, err = _run(base, traj, "--draws", str(f), "--execute", "3")  # with the checker's own draws too
    assert rc == 1 and both["execution"]["draws"] == 1 + 3 + len(drills) + 2 + 4
    _only_certified(both, acts)


def test_a_bad_draws_file(base):
    traj = _set(base, "draws_bad")
    h = base[2][base[2]["kind"] == "drill"]["hole_id"].tolist()
    d = traj.parent
    _fails(base, traj, "bad0.csv: row 3: factor = '0.0' is not a finite number > 0", code=2,
           extra=("--draws", str(_draws(d / "bad0.csv", [(0, "random", h[0], 1.2), (0, "random", h[1], 0.0)]))))
    _fails(base, traj, "badneg.csv: row 2: factor = '-1.0'", code=2,
           extra=("--draws", str(_draws(d / "badneg.csv", [(0, "slow", h[0], -1.0)]))))
    _fails(base, traj, "badnan.csv: row 2: factor = 'inf'", code=2,
           extra=("--draws", str(_draws(d / "badnan.csv", [(0, "slow", h[0], np.inf)]))))
    _fails(base, traj, "badhole.csv: row 3: hole_id 'ZZ9' is not a hole of the plan", code=2,
           extra=("--draws", str(_draws(d / "badhole.csv", [(0, "x", h[0], 1.0), (0, "x", "ZZ9", 1.0)]))))
    _fails(base, traj, "baddup.csv: rows 2, 4: draw '0' lists hole", code=2,
           extra=("--draws", str(_draws(d / "baddup.csv", [(0, "x", h[0], 1.0), (1, "y", h[0], 1.0),
                                                             (0, "x", h[0], 2.0)]))))
    _fails(base, traj, "badlabel.csv: draw '0' has 2 labels", code=2,
           extra=("--draws", str(_draws(d / "badlabel.csv", [(0, "x", h[0], 1.0), (0, "y", h[1], 1.0)]))))
    pd.DataFrame({"draw": [0], "hole_id": [h[0]], "factor": [1.0]}).to_csv(d / "badcol.csv", index=False)
    _fails(base, traj, "badcol.csv: missing column(s) ['label']", code=2, extra=("--draws", str(d / "badcol.csv")))
    _fails(base, traj, "nosuch.csv: no such draws file", code=2, extra=("--draws", str(d / "nosuch.csv")))
    _fails(base, base[0] / "small_trajectory.csv", "no actions file to execute", code=2,  # nothing to execute
           extra=("--draws", str(d / "bad0.csv")))


def test_a_draws_file_on_a_round_missing_an_interlock_counts_its_broken_draws(base):
    """R's first move no longer waits for L's cut hole: the file's draws break d_boom, counted per kind."""
    wait = _first_wait(base[2])

    def delete(i):
        return i[~((i["boom"] == "R") & (i["action"] == 0) & (i["after_boom"] == "L")
                   & (i["after_action"] == wait["action"]))]

    traj = _set(base, "draws_deleted", locks=delete)
    f = _draws(traj.with_name("draws.csv"), [(7, f"stall {wait['hole_id']}", wait["hole_id"], 3.0),
                                             (8, "slow", wait["hole_id"], 1.5)])
    report, text = _fails(base, traj, f"executed draw 1 (file draw 7 (stall {wait['hole_id']}))", "< d_boom",
                          extra=("--draws", str(f)))
    kinds = report["execution"]["draws_file_by_kind"]
    assert kinds["stall"]["violating_draws"] == 1 and kinds["slow"]["violating_draws"] == 1

"""The checker's exact certification of a round's robustness (``scripts/round_check/certify.py``):
every pair of segments of two booms that some drilling durations can make overlap keeps d_boom between
all their configurations, whatever the draws.

Hand-built two-boom rounds (jumbo8 joints written by hand, the checker's own modules called directly):
a round the sampled draws pass but the certification fails, with the durations that break it shown by
the pipeline's own kinematics; zones that make it safe and zones that do not (and one that deadlocks); a
final stand at park that the other boom's later action reaches. The ordering itself against executions
of random dependency graphs. A real round planned by ``pipeline.schedule``: intact it passes; each of
its interlocks deleted in turn fails, and the failure is shown real by durations this file finds and a
dense check with the pipeline's kinematics (not the checker's)."""

from __future__ import annotations

import importlib
import importlib.util
import math

import numpy as np
import pandas as pd
import pytest
import torch
from conftest import CHECK_STAGE
from fk_rounds import boom_joints
from round_checker import cr, run_checker

rc_actions = importlib.import_module("round_check.actions")  # the checker's own modules, through the script's path
rc_certify = importlib.import_module("round_check.certify")
rc_execute = importlib.import_module("round_check.execute")
rc_executed = importlib.import_module("round_check.executed")
rc_files = importlib.import_module("round_check.files")
rc_settings = importlib.import_module("round_check.settings")

JOINTS = [f"q{i}" for i in range(1, 9)]
D_BOOM = 0.3
r = math.radians
MID_L = [r(3), 0.0, 3.5, 0.0, 0.0, r(-3), 0.0, 2.5]  # L's feed on its inner side, collar near y = +0.2
MID_R = [r(-3), 0.0, 3.5, 0.0, 0.0, r(3), r(180), 2.5]  # R's near y = -0.2: the two capsules overlap
OUT_L = boom_joints(1, 0, 180)[0].tolist()  # L's outer side, over 0.7 m from anything of R's below
OUT_R = boom_joints(6, 1, 0)[[0, 5]].tolist()  # R's outer side, clear of MID_L and of L's way there
OVER_R = [r(10), 0.0, 3.6, 0.0, 0.0, r(-10), r(180), 2.5]  # R swung towards L's side: into L's park


# -- the pipeline's kinematics: an independent judge of what the checker reports --------------------

@pytest.fixture(scope="module")
def judge(safety):
    """``judge(qL (n, 8), qR (n, 8))``: the boom-boom distance (m) by the pipeline's rig and BoomPair."""
    from pipeline.assembly.rig import load_rig
    from pipeline.geometry.boom_pair import BoomPair

    twin = load_rig("twin", safety.tunnel, safety.distances, safety.points_per_capsule)
    pair = BoomPair(twin.booms[0].boom, twin.booms[1].boom, twin.d_boom)
    assert twin.d_boom == D_BOOM

    def distance(qa, qb):
        qa, qb = np.atleast_2d(np.asarray(qa, float)), np.atleast_2d(np.asarray(qb, float))
        with torch.inference_mode():
            fa = twin.booms[0].frames(torch.as_tensor(qa, dtype=torch.float64))
            fb = twin.booms[1].frames(torch.as_tensor(qb, dtype=torch.float64))
            return pair.distances(fa, fb).flatten(-2).amin(-1).numpy()

    return distance


# -- hand-built rounds ---------------------------------------------------------------------------

class Hand:
    """A round written by hand: per boom its steps from park, ``("move", joints, s)`` or ``("drill", hole,
    s)``; its rows (one per action boundary: moves linear in joint space, drills standing), actions,
    interlocks (``(boom, action, after_boom, after_action)``) and zones files, read by the checker."""

    def __init__(self, tmp, steps, locks=(), zones=None):
        self.st = rc_settings.settings(["rig=twin"])
        self.park = {b.name: np.asarray(b.park, float) for b in self.st.booms}
        self.rows, rows, self.spec = {}, [], {}
        for b in ("L", "R"):
            t, q = [0.0], [self.park[b]]
            for k, (kind, what, s) in enumerate(steps.get(b, ())):
                t.append(t[-1] + s)
                q.append(np.asarray(what, float) if kind == "move" else q[-1])
                rows.append((b, k, kind, what if kind == "drill" else "", t[-2], t[-1]))
                if kind == "drill":
                    self.spec[what] = float(s)
            n = len(t)
            self.rows[b] = rc_files.BoomRows(np.array(t), np.stack(q), np.full(n, "move"), np.full(n, ""),
                                             np.arange(n) + 2)
        tmp.mkdir(parents=True, exist_ok=True)
        pd.DataFrame(rows, columns=rc_actions.ACTION_COLUMNS).to_csv(tmp / "a.csv", index=False)
        pd.DataFrame(list(locks), columns=rc_actions.INTERLOCK_COLUMNS).to_csv(tmp / "i.csv", index=False)
        self.acts = rc_actions.read_actions(tmp / "a.csv", ["L", "R"])
        self.locks = rc_actions.read_interlocks(tmp / "i.csv", self.acts)
        if zones is not None:
            pd.DataFrame(list(zones), columns=rc_actions.ZONE_COLUMNS).to_csv(tmp / "z.csv", index=False)
        self.zones = rc_actions.read_zones(tmp / "z.csv" if zones is not None else None, self.acts)
        self.graph = rc_execute.graph(self.acts, self.locks)
        self.floors = rc_executed.episode_floors(self.st, self.rows, self.acts)

    def certify(self):
        return rc_certify.certify(self.acts, self.locks, self.zones, self.graph, self.floors[2], self.st.d_boom,
                                  self.floors[1])

    def sampled(self, n=100):
        """The sampled evidence: the nominal draw, n random ones, each hole at 3x, each boom slow."""
        drill = self.acts.kind == "drill"
        dr = rc_execute.draws(list(self.acts.hole[drill]), self.acts.boom[drill], self.acts.booms, n, 0, True)
        return rc_executed.check(self.st, self.rows, self.acts, self.locks, self.graph, dr, self.spec, 0.005, 4,
                                 self.zones, self.floors)

    def execute(self, factor: dict[str, float]):
        """Start and end of every action with the named holes' drilling times scaled (the checker's rule)."""
        dur = (self.acts.t_end - self.acts.t_start).copy()
        for k in np.flatnonzero(self.acts.kind == "drill"):
            dur[k] *= factor.get(self.acts.hole[k], 1.0)
        if len(self.zones):
            s, e, stuck = rc_execute.execute_zones(self.acts, self.graph, self.zones, dur[None])
            assert stuck == [None]
            return s[0], e[0]
        s, e = rc_execute.execute(self.graph, dur[None])
        return s[0], e[0]

    def k(self, boom, action):
        return int(self.acts.first[self.acts.booms.index(boom)] + action)


def _pairs(cert):
    return {tuple(v["segments"]) for v in cert["violating"]}


# L drills the middle hole first, then goes home; R drills four holes on its outer side, then its own
# middle hole: R gets to the middle about 300 s after L has left it in the plan.
MIDDLE = {"L": [("move", MID_L, 10.0), ("drill", "hL", 100.0), ("move", None, 10.0)],
          "R": [("move", OUT_R[0], 10.0), ("drill", "r1", 100.0), ("move", OUT_R[1], 5.0), ("drill", "r2", 100.0),
                ("move", OUT_R[0], 5.0), ("drill", "r3", 100.0), ("move", OUT_R[1], 5.0), ("drill", "r4", 100.0),
                ("move", MID_R, 10.0), ("drill", "r5", 100.0), ("move", None, 10.0)]}


def _middle(tmp, locks=(), zones=None):
    st = rc_settings.settings(["rig=twin"])
    park = {b.name: b.park for b in st.booms}
    steps = {b: [(kind, park[b] if kind == "move" and what is None else what, s) for kind, what, s in seq]
             for b, seq in MIDDLE.items()}
    return Hand(tmp, steps, locks, zones)


def test_sampling_passes_but_the_exact_certification_fails(tmp_path, judge):
    """No interlock: L's drill at the middle and R's are unordered. The sampled draws never bring them
    together (L's drill would have to last over 4x its time while R's run at 1x, or R's four holes be
    much quicker than 0.7x); the certification fails, and L's middle hole at 5x shows it real."""
    h = _middle(tmp_path)
    sampled = h.sampled(100)
    assert sampled["draws"] == 1 + 100 + 6 + 2 and sampled["deadlocks"] == 0
    assert sampled["violating_draws"] == 0 and not sampled["messages"]  # the sampling passes
    cert, msgs, unclear = h.certify()
    assert ("L#1 (drill hL)", "R#9 (drill r5)") in _pairs(cert)
    assert all(p[0].startswith(("L#0", "L#1", "L#2", "L standing")) and p[1].startswith(("R#8", "R#9", "R#10"))
               for p in _pairs(cert)), _pairs(cert)  # only the middle's segments: the outer holes are clear
    assert cert["violating_pairs"] == len(cert["violating"]) == len(msgs) and not unclear
    assert cert["least_sampled_distance_m"] < 0 < cert["pairs_checked"]  # capsules inside each other
    assert "certified: booms L and R: L#1 (drill hL) and R#9 (drill r5)" in "\n".join(msgs)
    # the pipeline's kinematics, at durations this test chose: L's hole at 5x holds L in the middle while R
    # drills its own middle hole
    s, e = h.execute({"hL": 5.0})
    lo, hi = max(s[h.k("L", 1)], s[h.k("R", 9)]), min(e[h.k("L", 1)], e[h.k("R", 9)])
    assert hi - lo > 50.0
    assert judge(MID_L, MID_R)[0] < D_BOOM
    # ordered by an interlock (R goes in only once L is out), the round is certified
    ok, msgs, unclear = _middle(tmp_path / "ok", locks=[("R", 8, "L", 2)]).certify()
    assert ok["violating_pairs"] == 0 and not msgs and not unclear
    assert ok["least_certified_distance_m"] >= D_BOOM and ok["least_sampled_distance_m"] - ok[
        "least_certified_distance_m"] <= 1e-3 + 1e-12
    assert ok["pairs_checked"] < cert["pairs_checked"]


def test_a_zone_makes_the_middle_safe_and_the_draws_take_turns(tmp_path):
    """The middle as a zone (L's section: its three actions; R's: move in, drill, move out): the pairs
    inside it never overlap, the rest is clear, so the round is certified; the draws wait at the zone."""
    zones = [("middle", "L", 0, 2), ("middle", "R", 8, 10)]
    h = _middle(tmp_path, zones=zones)
    cert, msgs, unclear = h.certify()
    assert cert["violating_pairs"] == 0 and not msgs and not unclear, msgs
    z = cert["zones"]
    assert cert["zone_excluded_pairs"] >= 9 and {k: z[k] for k in ("sections", "zones", "file", "possible_deadlocks")
                                                 } == {"sections": 2, "zones": 1, "file": str(tmp_path / "z.csv"),
                                                       "possible_deadlocks": 0}
    assert z["interleavings_explored"] and z["states"] > 2 * (3 + 11)  # more than one path through the states
    assert cert["segments"]["R"]["lasting_waits"] == 1  # R may stand before the zone, where R#7 left it
    sampled = h.sampled(50)
    assert sampled["violating_draws"] == 0 and sampled["deadlocks"] == 0 and sampled["zones"] == 2
    assert not sampled["messages"]  # the nominal draw reproduces the plan: R never had to wait for the zone
    # the zone holds R out while L drills long: R's move in starts when L's move out ends
    s, e = h.execute({"hL": 5.0})
    assert s[h.k("R", 8)] == pytest.approx(e[h.k("L", 2)]) and s[h.k("R", 8)] > e[h.k("R", 7)] + 50.0


def test_zones_that_do_not_keep_the_booms_apart(tmp_path):
    """R's drill in the middle outside its section, or the two sections in different zones: still unordered."""
    cases = {"short": [("middle", "L", 0, 2), ("middle", "R", 8, 8)],  # R's section is its move in only
             "apart": [("left", "L", 0, 2), ("right", "R", 8, 10)]}
    for name, zones in cases.items():
        cert, msgs, _ = _middle(tmp_path / name, zones=zones).certify()
        assert ("L#1 (drill hL)", "R#9 (drill r5)") in _pairs(cert), name
        assert cert["violating_pairs"] > 0 and msgs
    cert, _, _ = _middle(tmp_path / "short2", zones=cases["short"]).certify()
    assert ("L#1 (drill hL)", "R#8 (move to hole r5)") not in _pairs(cert)  # that one is inside both sections


def test_a_zone_and_an_interlock_that_deadlock(tmp_path):
    """L inside the zone waits (interlock) for R's drill in the middle, which R can do only inside it."""
    h = _middle(tmp_path, locks=[("L", 2, "R", 9)], zones=[("middle", "L", 0, 2), ("middle", "R", 8, 10)])
    cert, msgs, _ = h.certify()
    assert cert["zones"]["possible_deadlocks"] == 2  # found by the pairwise test and by every interleaving
    assert any(m.startswith("zone deadlock: L may enter") and "R#8 (move to hole r5)" in m for m in msgs), msgs
    assert any(m.startswith("zone deadlock: in some order") and "L#2" in m and "R#8" in m for m in msgs), msgs
    sampled = h.sampled(10)
    assert sampled["deadlocks"] == sampled["draws"] == 1 + 10 + 6 + 2
    assert "deadlock in draw 0 (nominal" in sampled["messages"][0] and "R#8" in sampled["messages"][0]


def test_a_final_stand_at_park_that_the_other_boom_reaches(tmp_path, judge):
    """L drills one long hole on its outer side and goes home; R, meanwhile, reaches over towards L's park
    (once L has left it: interlock R#2 after L#0). In the plan L is still out, and every sampled draw keeps
    it out (its hole lasts 1000 s, R's reach ends by 430 s at the latest); but L stands at park after its
    last action for the rest of the round, unordered with R's reach: a short L hole shows it."""
    steps = {"L": [("move", OUT_L, 10.0), ("drill", "hL", 1000.0), ("move", None, 10.0)],
             "R": [("move", OUT_R[0], 10.0), ("drill", "r1", 100.0), ("move", OVER_R, 10.0), ("drill", "r2", 100.0),
                   ("move", None, 10.0)]}
    st = rc_settings.settings(["rig=twin"])
    park = {b.name: b.park for b in st.booms}
    steps = {b: [(k, park[b] if k == "move" and w is None else w, s) for k, w, s in seq] for b, seq in steps.items()}
    h = Hand(tmp_path, steps, locks=[("R", 2, "L", 0)])
    assert h.sampled(100)["violating_draws"] == 0
    cert, msgs, _ = h.certify()
    final = "L at park after its last action"
    assert (final, "R#3 (drill r2)") in _pairs(cert) and (final, "R#2 (move to hole r2)") in _pairs(cert)
    assert any(m.startswith(f"certified: booms L and R: {final} and R#3 (drill r2)") for m in msgs)
    s, e = h.execute({"hL": 0.05})  # L home at 70 s, R reaches over from 110 s
    assert e[h.k("L", 2)] < s[h.k("R", 2)]
    assert judge(park["L"], OVER_R)[0] < D_BOOM
    # L's way home waits for R's return: certified
    ok, msgs, _ = Hand(tmp_path / "ok", steps, locks=[("R", 2, "L", 0), ("L", 2, "R", 4)]).certify()
    assert ok["violating_pairs"] == 0 and not msgs
    assert ok["segments"]["L"] == {"actions": 3, "lasting_waits": 1, "final_stand": 1}
    # R reaching over only once L is home orders every action, yet L's final stand is unordered with the reach
    # (the nominal round would show it too): the stand after the last action is a segment of its own
    late, _, _ = Hand(tmp_path / "late", steps, locks=[("R", 2, "L", 2)]).certify()
    assert {p[0] for p in _pairs(late)} == {final}


def test_zones_files_read_and_refused(tmp_path):
    h = _middle(tmp_path / "h")
    acts = h.acts
    assert len(rc_actions.read_zones(None, acts)) == 0 and len(rc_actions.read_zones(tmp_path / "none.csv", acts)) == 0
    (tmp_path / "header.csv").write_text("zone,boom,first_action,last_action\n")
    assert len(rc_actions.read_zones(tmp_path / "header.csv", acts)) == 0
    bad = {"boom,first_action,last_action\nL,0,1\n": "missing column(s) ['zone']",
           "zone,boom,first_action,last_action\nz,X,0,1\n": "row 2: boom 'X' is not a boom of the rig",
           "zone,boom,first_action,last_action\nz,L,0,9\n": "row 2: boom 'L' has no action 9 (last_action)",
           "zone,boom,first_action,last_action\nz,L,2,1\n": "row 2: last_action 1 is before first_action 2",
           "zone,boom,first_action,last_action\nz,L,0,x\n": "last_action = 'x' is not a finite number",
           "zone,boom,first_action,last_action\n,L,0,1\n": "row 2: no zone named",
           "zone,boom,first_action,last_action\nz,R,0,3\nz,R,3,5\n": "rows 2 and 3: two sections of boom 'R'"}
    for i, (text, message) in enumerate(bad.items()):
        (tmp_path / f"b{i}.csv").write_text(text)
        with pytest.raises(cr.InputError, match=None) as e:
            rc_actions.read_zones(tmp_path / f"b{i}.csv", acts)
        assert message in str(e.value), (text, str(e.value))
    z = rc_actions.read_zones(_write(tmp_path / "ok.csv", "zone,boom,first_action,last_action\nm,R,8,10\nm,L,0,2\n"),
                              acts)
    assert list(z.first) == [h.k("R", 8), h.k("L", 0)] and list(z.last) == [h.k("R", 10), h.k("L", 2)]


def _write(path, text):
    path.write_text(text)
    return path


# -- the ordering against executions ---------------------------------------------------------------

def _random_round(tmp, rng, n_l, n_r, n_locks):
    rows, t = [], 0.0
    for b, n in (("L", n_l), ("R", n_r)):
        t = 0.0
        for k in range(n):
            kind = "move" if k % 2 == 0 else "drill"
            rows.append((b, k, kind, f"{b}{k}" if kind == "drill" else "", t, t + 1.0))
            t += 1.0
    pd.DataFrame(rows, columns=rc_actions.ACTION_COLUMNS).to_csv(tmp / "a.csv", index=False)
    acts = rc_actions.read_actions(tmp / "a.csv", ["L", "R"])
    locks = []
    while len(locks) < n_locks:  # across booms, from an earlier "rank" to a later one: never a cycle
        a, b = ("L", "R") if rng.random() < 0.5 else ("R", "L")
        na, nb = (n_l, n_r) if a == "L" else (n_r, n_l)
        u, v = int(rng.integers(nb)), int(rng.integers(na))  # b's u before a's v
        if (v + 0.5) / na > (u + 0.5) / nb:
            locks.append((a, v, b, u))
    pd.DataFrame(locks, columns=rc_actions.INTERLOCK_COLUMNS).to_csv(tmp / "i.csv", index=False)
    return acts, rc_actions.read_interlocks(tmp / "i.csv", acts)


def test_ordered_segments_never_overlap_and_unordered_ones_can(tmp_path):
    """Random rounds of two booms (moves and drills alternating, random interlocks), every action's duration
    free (the certification's model): executed under extreme and random durations, a pair of segments the
    certification orders never overlaps for a positive time, and each unordered pair does in some draw."""
    rng = np.random.default_rng(7)
    seen = dict.fromkeys(("ordered", "unordered", "waits", "wait_pairs_ordered"), 0)
    for case in range(12):
        tmp = tmp_path / f"r{case}"
        tmp.mkdir()
        acts, locks = _random_round(tmp, rng, int(rng.integers(3, 8)), int(rng.integers(3, 8)),
                                    int(rng.integers(1, 6)))
        g = rc_execute.graph(acts, locks)
        assert g.cycle is None
        order = rc_certify.Order(acts, g, rc_actions.Zones.none())
        segs = [rc_certify.Segments(acts, b, order, rc_actions.Zones.none()) for b in range(2)]
        n = len(acts)
        base = 1e-3
        durs = []
        for i in range(n):  # one action very long, another long, the rest short; and at random
            for j in range(n):
                d = np.full(n, base)
                d[i], d[j] = 1e3, 5e2 if i != j else 1e3
                durs.append(d)
        durs.append(np.full(n, 1.0))
        durs += list(np.exp(rng.uniform(np.log(1e-3), np.log(1e3), (400, n))))
        s, e = rc_execute.execute(g, np.array(durs))
        ev = np.concatenate([s, e, np.zeros((len(durs), 1)), np.full((len(durs), 1), np.inf)], 1)
        A, B = segs
        lo = np.maximum(ev[:, A.start][:, :, None], ev[:, B.start][:, None, :])
        hi = np.minimum(ev[:, A.end][:, :, None], ev[:, B.end][:, None, :])
        overlap = (hi - lo > 1e-9).any(0)
        ordered = order.before[np.ix_(A.end, B.start)] | order.before[np.ix_(B.end, A.start)].T
        assert not (ordered & overlap).any(), case  # sound: what it orders never overlaps
        assert (ordered | overlap).all(), (case, np.argwhere(~ordered & ~overlap))  # and nothing more
        seen["ordered"] += int(ordered.sum())
        seen["unordered"] += int((~ordered).sum())
        seen["waits"] += int((A.episode[:-1] % 2 == 0).sum() + (B.episode[:-1] % 2 == 0).sum())
        seen["wait_pairs_ordered"] += int(ordered[(A.episode % 2 == 0)[:, None] & (B.episode % 2 == 0)[None, :]].sum())
    assert min(seen.values()) > 0, seen  # not vacuous: waits that last, pairs either way


# -- a round planned by the pipeline, its interlocks deleted one by one --------------------------------

STAGE = [s for s in CHECK_STAGE if s not in ("schedule.interlocks=false", "round.postures=1")] + [
    "draws.count=20"]


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """A twin round of eight middle holes of the demo face (|y| <= 0.8 m, every fourth), planned with its
    interlocks by the stage (three: the booms work side by side in the middle)."""
    from pipeline import demo_face, schedule
    from pipeline.core.config import compose

    tmp = tmp_path_factory.mktemp("certify")
    base = ["experiment=tiny", f"paths.data={tmp}/data", f"tracking.uri=sqlite:///{tmp}/mlflow.db",
            f"tracking.artifact_root={tmp}/artifacts"]
    demo_face.run(compose(base))
    holes = pd.read_csv(tmp / "data" / "plans" / "demo_face.csv")
    plan = tmp / "small.csv"
    holes[holes["collar_y"].abs() <= 0.8].iloc[::4].reset_index(drop=True).to_csv(plan, index=False)
    stage = [*STAGE, f"plan={plan}"]
    schedule.run(compose([*base, *stage]))
    return tmp, ["experiment=tiny", f"paths.data={tmp}/data", *stage]


_check = run_checker


class Executor:
    """This file's own execution of an actions file: the rule by hand (a boom's next action once its previous
    one and every interlock's action have ended), vectorised over draws of drilling factors, and the booms'
    configurations at any executed instant laid out from the planned trajectory (a move's rows shifted to
    its executed start, a drill and a pause standing where the boom is)."""

    def __init__(self, acts: pd.DataFrame, locks: pd.DataFrame, traj: pd.DataFrame):
        self.acts = acts.sort_values(["boom", "action"]).reset_index(drop=True)
        a = self.acts
        self.n = len(a)
        at = {(b, int(k)): i for i, (b, k) in enumerate(zip(a["boom"], a["action"], strict=True))}
        self.at = at
        self.preds = [[at[(b, int(k) - 1)]] if k > 0 else [] for b, k in zip(a["boom"], a["action"], strict=True)]
        for row in locks.itertuples():
            self.preds[at[(row.boom, int(row.action))]].append(at[(row.after_boom, int(row.after_action))])
        self.order, placed = [], set()
        while len(self.order) < self.n:
            ready = [i for i in range(self.n) if i not in placed and all(p in placed for p in self.preds[i])]
            assert ready, "the interlocks have a cycle"
            self.order += ready
            placed |= set(ready)
        self.ts, self.te = a["t_start"].to_numpy(float), a["t_end"].to_numpy(float)
        self.drill = (a["kind"] == "drill").to_numpy()
        self.rows = {b: (g["t"].to_numpy(float), g[JOINTS].to_numpy(float)) for b, g in traj.groupby("boom")}

    def run(self, factor: np.ndarray):
        """Starts and ends ``(draws, n)`` with each drill's planned duration times ``factor (draws, n)``."""
        dur = (self.te - self.ts) * np.where(self.drill, factor, 1.0)
        S, E = np.zeros_like(dur), np.zeros_like(dur)
        for i in self.order:
            S[:, i] = np.max([E[:, p] for p in self.preds[i]], 0) if self.preds[i] else 0.0
            E[:, i] = S[:, i] + dur[:, i]
        return S, E

    def actions(self, boom):
        return np.flatnonzero((self.acts["boom"] == boom).to_numpy())

    def window(self, boom, episode, S, E):
        """Executed window of an episode (``2p`` the pause before action p, ``2i + 1`` action i) and, for a
        move, the action (its configurations depend on the time in it)."""
        k = self.actions(boom)
        if episode % 2:
            i = k[episode // 2]
            return S[:, i], E[:, i], (None if self.drill[i] else i)
        p = episode // 2
        lo = np.zeros(len(S)) if p == 0 else E[:, k[p - 1]]
        hi = np.full(len(S), np.inf) if p == len(k) else S[:, k[p]]
        return lo, hi, None

    def configurations(self, boom, S, E, t):
        """``(len(t), 8)`` joints of the boom at executed instants ``t`` of one draw (``S``, ``E``: ``(n,)``)."""
        k = self.actions(boom)
        bounds = np.stack([S[k], E[k]], 1).ravel()
        pos = np.searchsorted(bounds, t, side="right")  # odd: in action pos // 2; even: before action pos // 2
        when = np.empty(len(t))
        for j, p in enumerate(pos):
            if p % 2:
                i = k[p // 2]
                when[j] = self.ts[i] if self.drill[i] else t[j] - S[i] + self.ts[i]
            else:
                when[j] = self.ts[k[p // 2]] if p // 2 < len(k) else self.te[k[-1]]
        rt, rq = self.rows[boom]
        return np.stack([np.interp(when, rt, rq[:, c]) for c in range(rq.shape[1])], -1)


FACTORS = np.geomspace(1 / 50, 50, 401)  # the adversary's drilling factors, 0.02x to 50x


def _adversary(ex: Executor, entry: dict, grid=FACTORS):
    """Drilling factors that put both booms, at one instant, where the checker's violating pair says (each
    segment's configuration at its planned instant ``at_planned_s``), or None. Searched along one factor for
    all of a boom's drills or for one drill alone; where both segments are moves (fixed durations) the
    factor that brings the two instants together is bisected."""
    (ba, bb), (ea, eb), (ta, tb) = entry["booms"], entry["episodes"], entry["at_planned_s"]
    masks = [(ex.acts["boom"] == b).to_numpy() & ex.drill for b in (ba, bb)]
    masks += [np.eye(ex.n, dtype=bool)[i] for i in np.flatnonzero(ex.drill)]
    for m in masks:
        F = np.where(m[None, :], grid[:, None], 1.0)

        def instants(F):
            S, E = ex.run(F)
            (la, ha, ma), (lb, hb, mb) = ex.window(ba, ea, S, E), ex.window(bb, eb, S, E)
            return S, E, la, ha, ma, lb, hb, mb

        S, E, la, ha, ma, lb, hb, mb = instants(F)
        if ma is not None and mb is not None:  # two moves: the offsets must match exactly
            gap = (la + ta - ex.ts[ma]) - (lb + tb - ex.ts[mb])
            for h in np.flatnonzero(np.sign(gap[1:]) != np.sign(gap[:-1])):
                x0, x1 = 0.0, 1.0
                for _ in range(60):
                    mid = (x0 + x1) / 2
                    _, _, la_, _, _, lb_, _, _ = instants(F[h] + mid * (F[h + 1] - F[h]))
                    g = (la_ + ta - ex.ts[ma]) - (lb_ + tb - ex.ts[mb])
                    x0, x1 = (mid, x1) if np.sign(g[0]) == np.sign(gap[h]) else (x0, mid)
                f = F[h] + x0 * (F[h + 1] - F[h])
                S, E, la_, *_ = instants(f[None])
                return f, S[0], E[0], float(la_[0] + ta - ex.ts[ma])
            continue
        if ma is not None:
            T = la + ta - ex.ts[ma]
            ok = (T >= lb) & (T <= hb)
        elif mb is not None:
            T = lb + tb - ex.ts[mb]
            ok = (T >= la) & (T <= ha)
        else:
            lo, hi = np.maximum(la, lb), np.minimum(ha, hb)
            ok, T = hi > lo, np.where(np.isfinite(hi), (lo + hi) / 2, lo + 1.0)
        if ok.any():
            d = int(np.flatnonzero(ok)[0])
            return F[d], S[d], E[d], float(T[d])
    return None


@pytest.mark.slow
def test_a_planned_round_passes_and_each_deleted_interlock_is_caught(planned, tmp_path, judge):
    """Intact, the planner's round is certified. Each interlock deleted in turn: exit 1, the certification
    reports at least one pair; where the nominal still reproduces the plan (only its robustness is at
    stake), one reported pair is shown real: drilling factors this file finds, its own execution, the
    pipeline's kinematics below d_boom at the instant, the checker's distance to 1 mm. An interlock with no
    slack (L's first move waiting at park for R's) changes the plan itself when deleted: the nominal fails
    too, and its reported pairs may be held apart only by fixed move durations, which the certification
    does not take on trust (docs/round.md, "Certified robustness")."""
    tmp, overrides = planned
    locks = pd.read_csv(tmp / "small_interlocks.csv", keep_default_na=False)
    assert len(locks) >= 2, "the middle holes' round should need interlocks"
    rc, report, err = _check(tmp / "small_trajectory.csv", overrides, "--execute", "20")
    assert rc == 0, (err, report and report["violations"][:5])
    cert = report["execution"]["certified"]
    assert cert["violating_pairs"] == 0 and cert["pairs_checked"] > 0 and cert["least_certified_distance_m"] >= D_BOOM
    traj = pd.read_csv(tmp / "small_trajectory.csv", keep_default_na=False, dtype={"hole_id": str})
    acts = pd.read_csv(tmp / "small_actions.csv", keep_default_na=False, dtype={"hole_id": str})
    shown = {}
    for k in range(len(locks)):
        dst = tmp_path / f"without{k}"
        dst.mkdir()
        for f in ("small_trajectory.csv", "small_round.csv", "small_round.json", "small_actions.csv"):
            (dst / f).write_bytes((tmp / f).read_bytes())
        fewer = locks.drop(index=k)
        fewer.to_csv(dst / "small_interlocks.csv", index=False)
        rc, report, err = _check(dst / "small_trajectory.csv", overrides)
        assert rc == 1, (k, err)
        cert = report["execution"]["certified"]
        assert cert["violating_pairs"] >= 1, k  # the certification catches every deletion
        # shown real, by this file's own execution and the pipeline's kinematics: durations that bring the
        # booms within d_boom, found from where the checker says they meet
        ex = Executor(acts, fewer, traj)
        for entry in cert["violating"]:
            found = _adversary(ex, entry)
            if found is None:
                continue
            _, S, E, T = found
            t = T + np.linspace(-0.25, 0.25, 501)
            d = judge(ex.configurations("L", S, E, t), ex.configurations("R", S, E, t))
            if d.min() < D_BOOM:
                shown[k] = (entry["segments"], float(d.min()))
                assert abs(d[250] - entry["distance_m"]) < 1e-3  # the checker's own distance, to 1 mm
                break
        nominal_kept = not any(m.startswith("execution with the model durations") for m in report["violations"])
        if nominal_kept:  # the plan still runs as planned: only its robustness is at stake, and it is broken
            assert k in shown, (k, [e["segments"] for e in cert["violating"]])
    assert shown, "no deletion shown real"


@pytest.mark.slow
def test_a_zones_file_on_the_command_line(planned, tmp_path):
    """``--zones``: a header alone is no zone; a zone around both booms' first actions takes those pairs out;
    a bad file or a missing one exits 2, naming it."""
    tmp, overrides = planned
    traj = tmp / "small_trajectory.csv"
    empty = _write(tmp_path / "empty.csv", "zone,boom,first_action,last_action\n")
    rc, report, err = _check(traj, overrides, "--zones", str(empty))
    assert rc == 0, err
    cert = report["execution"]["certified"]
    assert cert["zones"]["sections"] == 0 and cert["zone_excluded_pairs"] == 0
    both = _write(tmp_path / "both.csv", "zone,boom,first_action,last_action\nstart,L,0,1\nstart,R,0,1\n")
    rc, zoned, err = _check(traj, overrides, "--zones", str(both))
    z = zoned["execution"]["certified"]
    assert z["zones"]["sections"] == 2 and z["zone_excluded_pairs"] >= 1, z
    assert z["pairs_checked"] + z["zone_excluded_pairs"] >= cert["pairs_checked"]
    bad = _write(tmp_path / "bad.csv", "zone,boom,first_action,last_action\nstart,X,0,1\n")
    rc, _, err = _check(traj, overrides, "--zones", str(bad))
    assert rc == 2 and "bad.csv: row 2: boom 'X' is not a boom of the rig" in err
    rc, _, err = _check(traj, overrides, "--zones", str(tmp_path / "nosuch.csv"))
    assert rc == 2 and "nosuch.csv: no such zones file" in err

"""A rig: several booms on one carrier, each with its own base in the rig frame (docs/reference.md, section 7).

The rig frame is the jumbo8 base frame with the carrier on the tunnel centre line; a plan is given in
it. Each boom's base is a translation of the rig frame (no rotation, as the reference's rigs). A boom's
chain computes frames in its own base frame; :meth:`MountedBoom.frames` moves them into the rig frame
by adding the base offset to every frame origin, and everything downstream (tunnel, self and
boom-boom clearances, their Jacobians) works on those frames. So one tunnel definition serves every
boom: the tunnel is not copied or shifted, the boom is. Joints stay in the boom's own base frame.

A rig file (``conf/rig/<name>.yaml``) names each boom, its boom kind (``boom:``, a boom config name),
its base ``[x, y, z]`` (m) and its park configuration (degrees for revolute joints, metres for
prismatic ones). Nothing here reads a file: the composition root (:mod:`pipeline.assembly.rig`) hands
:func:`build_rig` the parsed rig node and one :class:`Boom` per boom of the rig (the composed ``boom``,
another kind's config, or a calibrated model: docs/rig.md). Building checks every boom and names the
file and the boom of the first problem.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import torch

from pipeline.core.errors import ConfigError
from pipeline.core.settings import parse, rule
from pipeline.geometry.boom_config import reject_unknown
from pipeline.geometry.boom_pair import BoomPair
from pipeline.geometry.collision import SAFETY_KINDS, SafetyDistances, SafetyModel
from pipeline.geometry.compiled_rig import CompiledBoom, kernel_ready, pair_clearance
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.tunnel import Tunnel


@dataclass(frozen=True)
class MountSettings:
    """One boom of a rig file, as written (park in degrees / metres)."""

    name: str
    base: list[float]
    park: list[float]
    boom: str = "jumbo8"


@dataclass(frozen=True)
class RigSettings:
    name: str
    d_boom: float = field(default=0.3, metadata=rule(ge=0))


RIG_KEYS = {f.name for f in dataclasses.fields(RigSettings)} | {"booms", "defaults"}
MOUNT_KEYS = {f.name for f in dataclasses.fields(MountSettings)}


def rig_file(name: str) -> str:
    return f"conf/rig/{name}.yaml"


@dataclass(frozen=True)
class RigSpec:
    """A parsed rig file: its booms' settings, not yet checked against boom configs or a tunnel."""

    name: str
    source: str  # the rig file, for messages
    d_boom: float
    mounts: tuple[MountSettings, ...]


def parse_rig(node: Mapping, source: str) -> RigSpec:
    """Read a rig config node; ``source`` (the rig file) prefixes every message."""
    if not isinstance(node, Mapping):
        raise ConfigError(f"{source}: expected a mapping, got {node!r}")
    reject_unknown(node, RIG_KEYS, source)
    settings = parse(RigSettings, {k: node[k] for k in ("name", "d_boom") if k in node}, f"{source}: rig")
    booms = node.get("booms")
    if isinstance(booms, (str, bytes)) or not isinstance(booms, Sequence) or not booms:
        raise ConfigError(f"{source}: booms = {booms!r}: expected a non-empty list of booms")
    mounts, seen = [], set()
    for i, entry in enumerate(booms):
        if not isinstance(entry, Mapping):
            raise ConfigError(f"{source}: booms[{i}] = {entry!r}: expected a mapping with {sorted(MOUNT_KEYS)}")
        where = f"{source}: boom '{entry['name']}'" if isinstance(entry.get("name"), str) else f"{source}: booms[{i}]"
        reject_unknown(entry, MOUNT_KEYS, where)
        m = parse(MountSettings, entry, where)
        if m.name in seen:
            raise ConfigError(f"{where}: duplicate boom name (boom names must be unique in a rig)")
        seen.add(m.name)
        if len(m.base) != 3:
            raise ConfigError(f"{where}.base = {list(m.base)!r}: expected [x, y, z] (m)")
        mounts.append(m)
    return RigSpec(settings.name, source, settings.d_boom, tuple(mounts))


def translate_frames(frames: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """Frames ``(..., F, 4, 4)`` with every origin moved by ``offset (3,)``: a boom's base frame into the
    rig frame. Rotations, hence joint axes and every Jacobian, are unchanged."""
    origin = frames[..., :3, 3] + offset
    return torch.cat([torch.cat([frames[..., :3, :3], origin.unsqueeze(-1)], -1), frames[..., 3:, :]], -2)


class MountedBoom:
    """One boom of a rig: its chain, its base offset and its safety model, all in the rig frame.

    The safety model is today's :class:`SafetyModel` unchanged; it is handed rig-frame frames, so its
    tunnel clearances are measured from this boom's base. Self clearances do not change under a
    translation, and neither do the Jacobians (every point and joint axis moves by the same offset).
    """

    def __init__(self, name: str, boom: Boom, base: Sequence[float], park: torch.Tensor, safety: SafetyModel):
        self.name, self.boom, self.safety = name, boom, safety
        self.base = tuple(float(v) for v in base)
        self.park = park  # (n_joints,) float64, SI units
        self._base_t: dict = {}
        self._kernel: CompiledBoom | None | bool = False  # False: not built yet
        self.compiled = True  # False keeps every clearance on torch (the side-by-side benchmark's baseline)

    def _offset(self, dtype, device) -> torch.Tensor:
        key = (dtype, device)
        if key not in self._base_t:
            self._base_t[key] = torch.tensor(self.base, dtype=dtype, device=device)
        return self._base_t[key]

    def to_rig(self, frames: torch.Tensor) -> torch.Tensor:
        """Frames ``(..., F, 4, 4)`` of the boom's base frame, in the rig frame (origins + base)."""
        return translate_frames(frames, self._offset(frames.dtype, frames.device))

    def frames(self, q: torch.Tensor) -> torch.Tensor:
        """Every frame of the chain at joints ``q`` (own base frame), in the rig frame."""
        return self.to_rig(self.boom.frames(q))

    def tool_pose(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Collar point and drilling direction in the rig frame."""
        return self.boom.tool_pose_from_frames(self.frames(q))

    @property
    def kernel(self) -> CompiledBoom | None:
        """This boom for the compiled kernels (:mod:`pipeline.geometry.compiled_rig`), built on first use;
        ``None`` for a chain the kernels do not compute (its clearances stay on torch), or with :attr:`compiled`
        off. A calibrated boom has one (:class:`~pipeline.geometry.compiled_rig.CompiledBoom`)."""
        if not self.compiled:
            return None
        if self._kernel is False:
            self._kernel = CompiledBoom.for_boom(self.boom, self.base, self.safety)
        return self._kernel

    def clearances(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """Self, wall, ground and arch clearances (m) of this boom at ``q``, seen from its base (float64
        joints on the CPU without gradients: the compiled kernel, equal to the torch model)."""
        if self.kernel is not None and kernel_ready(q):
            return self.kernel.clearances(q)
        return self.safety.clearances_from_frames(self.frames(q))

    def clearances_with_jacobians(self, q: torch.Tensor):
        return self.safety.clearances_with_jacobians(self.frames(q))


class Rig:
    """The booms of a rig in one tunnel, with their pairwise boom-boom clearances."""

    def __init__(self, spec: RigSpec, booms: Sequence[MountedBoom], tunnel: Tunnel):
        self.spec, self.name, self.d_boom, self.tunnel = spec, spec.name, spec.d_boom, tunnel
        self.booms = tuple(booms)
        self.names = [b.name for b in self.booms]
        self._pairs = {(i, j): BoomPair(a.boom, b.boom, spec.d_boom)
                       for i, a in enumerate(self.booms) for j, b in enumerate(self.booms) if i < j}

    def __len__(self) -> int:
        return len(self.booms)

    def index(self, name: str) -> int:
        if name not in self.names:
            raise ConfigError(f"{self.spec.source}: no boom '{name}'; booms: {self.names}")
        return self.names.index(name)

    def pair(self, a: int, b: int) -> BoomPair:
        """The :class:`BoomPair` of booms ``a < b`` (indices)."""
        if not 0 <= a < b < len(self.booms):
            raise ConfigError(f"{self.spec.source}: boom pair ({a}, {b}): expected 0 <= a < b < {len(self.booms)}")
        return self._pairs[(a, b)]

    def boom_clearance(self, a: int, qa: torch.Tensor, b: int, qb: torch.Tensor) -> torch.Tensor:
        """Boom-boom clearance (m, less d_boom) of boom ``a`` at ``qa`` and boom ``b`` at ``qb``."""
        if a > b:
            a, qa, b, qb = b, qb, a, qa
        pair = self.pair(a, b)
        ka, kb = self.booms[a].kernel, self.booms[b].kernel
        if ka is not None and kb is not None and kernel_ready(qa, qb):  # the same numbers, compiled
            return pair_clearance(ka, qa, kb, qb, self.d_boom)
        return pair.clearance(self.booms[a].frames(qa), self.booms[b].frames(qb))

    def boom_clearance_with_jacobians(self, a: int, qa: torch.Tensor, b: int, qb: torch.Tensor):
        """:meth:`boom_clearance` and its gradients with respect to ``qa`` and ``qb`` (in that order)."""
        if a > b:
            c, gb, ga = self.boom_clearance_with_jacobians(b, qb, a, qa)
            return c, ga, gb
        return self.pair(a, b).clearance_with_jacobians(self.booms[a].frames(qa), self.booms[b].frames(qb))

    def parks(self, dtype=torch.float64, device=None) -> list[torch.Tensor]:
        return [b.park.to(dtype=dtype, device=device) for b in self.booms]


def _park(m: MountSettings, boom: Boom, where: str) -> torch.Tensor:
    if len(m.park) != boom.n_joints:
        raise ConfigError(f"{where}.park = {list(m.park)!r}: expected {boom.n_joints} values {boom.joint_names} "
                          "(degrees for revolute joints, metres for prismatic ones)")
    park = torch.tensor([math.radians(v) if j.revolute else v for v, j in zip(m.park, boom.joints, strict=True)],
                        dtype=torch.float64)
    if not bool(boom.within_limits(park)):
        lo, hi = boom.limits()
        bad = [j.name for j, v, a, b in zip(boom.joints, park, lo, hi, strict=True) if not a - 1e-9 <= v <= b + 1e-9]
        raise ConfigError(f"{where}.park = {list(m.park)!r}: joint(s) {bad} outside the range of boom config "
                          f"'{boom.name}'")
    return boom.with_locks(park)


def build_rig(spec: RigSpec, booms: Mapping[str, Boom], tunnel: Tunnel, distances: SafetyDistances,
              points_per_capsule: int = 16, exact: bool = True) -> Rig:
    """Place each boom of ``spec`` (``booms``: boom name in the rig -> its :class:`Boom`, of the kind its
    ``boom:`` names) and check the rig: every base inside the tunnel profile, every park clear of the
    boom itself and of the tunnel (seen from its base), and every two parks at least ``d_boom`` apart.
    Errors name the rig file and the boom."""
    missing = [m.name for m in spec.mounts if m.name not in booms]
    if missing:
        raise ConfigError(f"{spec.source}: no boom model for boom(s) {missing}")
    booms_out = []
    for m in spec.mounts:
        where = f"{spec.source}: boom '{m.name}'"
        boom = booms[m.name]
        if boom.name != m.boom:
            raise ConfigError(f"{where}.boom = {m.boom!r}: given a model of boom {boom.name!r}")
        x, y, z = m.base
        if not bool(tunnel.contains(torch.tensor(y, dtype=torch.float64), torch.tensor(z, dtype=torch.float64))):
            raise ConfigError(f"{where}.base = {list(m.base)!r}: outside the tunnel profile ({tunnel.describe()}: y in "
                              f"{list(tunnel.y_range)} m, z in {list(tunnel.z_range)} m)")
        mounted = MountedBoom(m.name, boom, m.base, _park(m, boom, where),
                              SafetyModel(boom, tunnel, distances, points_per_capsule, exact))
        clear = mounted.clearances(mounted.park)
        broken = {k: round(float(clear[k]), 4) for k in SAFETY_KINDS if float(clear[k]) < 0}
        if broken:
            raise ConfigError(f"{where}.park = {list(m.park)!r}: the park configuration breaks safety distance(s) "
                              f"by {broken} m (clearance < 0) at base {list(m.base)}")
        booms_out.append(mounted)
    rig = Rig(spec, booms_out, tunnel)
    for (i, j), pair in rig._pairs.items():
        a, b = rig.booms[i], rig.booms[j]
        gap = float(pair.distances(a.frames(a.park), b.frames(b.park)).min())
        if gap < spec.d_boom:
            raise ConfigError(f"{spec.source}: boom '{a.name}' and boom '{b.name}' overlap at park: their capsules are "
                              f"{gap:.3f} m apart, below d_boom = {spec.d_boom} m")
    return rig

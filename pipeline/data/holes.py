"""Hole sets of docs/reference.md section 3: Omega_unsup, Omega_sup and the test groups.

Everything is drawn on the CPU in float64 from a seeded ``torch.Generator``, so
the same seed gives the same holes on any machine with the same torch build.
Sampling is vectorised: batches of candidates are drawn and filtered, and only
the (few) batches are looped over, never the holes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import SafetyModel
from pipeline.geometry.tunnel import Tunnel

DTYPE = torch.float64


@dataclass(frozen=True)
class HoleSampling:
    """How holes are drawn: face x range (m), cone half-angle (deg), profile inset (m)."""

    face_x: tuple[float, float] = (6.0, 7.0)
    cone_deg: float = 15.0
    inset: float = 0.2

    def __post_init__(self):
        lo, hi = self.face_x
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ConfigError(f"holes.face_x = {list(self.face_x)!r}: expected [lower, upper] with lower < upper")
        if not 0 < self.cone_deg < 90:
            raise ConfigError(f"holes.cone_deg = {self.cone_deg!r}: expected an angle in (0, 90) degrees")
        if not 0 <= self.inset:
            raise ConfigError(f"holes.inset = {self.inset!r}: expected a non-negative inset (m)")


def _batch(n: int) -> int:
    return max(256, int(1.6 * n))


def sample_collars(n: int, tunnel: Tunnel, sampling: HoleSampling, gen: torch.Generator) -> torch.Tensor:
    """``(n, 3)`` collars: (y, z) uniform in the profile less the inset, x uniform in face_x."""
    inset = sampling.inset
    out, have = [], 0
    while have < n:
        m = _batch(n - have)
        y, z = tunnel.sample_yz(m, inset, gen)
        keep = tunnel.contains(y, z, inset)
        out.append(torch.stack([y[keep], z[keep]], dim=-1))
        have += int(keep.sum())
    yz = torch.cat(out)[:n]
    lo, hi = sampling.face_x
    x = lo + torch.rand(n, generator=gen, dtype=DTYPE) * (hi - lo)
    return torch.cat([x.unsqueeze(-1), yz], dim=-1)


def sample_cone(n: int, cone_deg: float, gen: torch.Generator) -> torch.Tensor:
    """``(n, 3)`` unit vectors uniform by solid angle in a cone of half-angle ``cone_deg`` around +x."""
    cos_max = math.cos(math.radians(cone_deg))
    cos_t = 1 - torch.rand(n, generator=gen, dtype=DTYPE) * (1 - cos_max)
    sin_t = torch.sqrt((1 - cos_t * cos_t).clamp_min(0))
    phi = torch.rand(n, generator=gen, dtype=DTYPE) * (2 * math.pi)
    return torch.stack([cos_t, sin_t * torch.cos(phi), sin_t * torch.sin(phi)], dim=-1)


def sample_holes(
    n: int, safety: SafetyModel, sampling: HoleSampling, seed: int | torch.Generator
) -> tuple[torch.Tensor, dict]:
    """Draw ``n`` drillable holes like Omega_unsup; return poses ``(n, 6)`` and rejection stats.

    A candidate whose feed beam alone (front part excepted) violates a tunnel safety
    distance cannot be drilled by any joint solution: it is rejected and redrawn.
    """
    if n <= 0:
        raise ConfigError(f"hole count = {n!r}: expected a positive integer")
    depth = safety.boom.preview_depth
    gen = seed if isinstance(seed, torch.Generator) else torch.Generator().manual_seed(int(seed))
    poses, have = [], 0
    drawn = 0
    rejected = {"wall": 0, "ground": 0, "arch": 0}
    any_rejected = 0
    while have < n:
        m = _batch(n - have)
        p = sample_collars(m, safety.tunnel, sampling, gen)
        z = sample_cone(m, sampling.cone_deg, gen)
        bad = {k: c < 0 for k, c in safety.tool_body_clearances(p, z).items()}
        reject = bad["wall"] | bad["ground"] | bad["arch"]
        # Count only the candidates that the accepted set actually consumed, so the
        # rate does not depend on the batch size.
        keep_idx = torch.nonzero(~reject).squeeze(-1)
        need = n - have
        last = int(keep_idx[need - 1]) + 1 if keep_idx.numel() >= need else m
        drawn += last
        any_rejected += int(reject[:last].sum())
        for k in rejected:
            rejected[k] += int(bad[k][:last].sum())
        sel = keep_idx[keep_idx < last]
        poses.append(torch.cat([p[sel], p[sel] + depth * z[sel]], dim=-1))
        have += sel.numel()
    stats = {
        "drawn": drawn,
        "rejected": any_rejected,
        "rejection_rate": any_rejected / drawn,
        "rejected_by": rejected,
    }
    return torch.cat(poses)[:n], stats


def joint_box(boom, box: Mapping | None, where: str = "holes.sup.box") -> tuple[torch.Tensor, torch.Tensor]:
    """Lower and upper bounds ``(n_joints,)`` in SI units of a working box given per joint in degrees
    (revolute) or metres (prismatic); joints it leaves out, and ``box=None``, keep their full range.
    A box must lie within the joint limits and have positive width."""
    lo, hi = (b.clone() for b in boom.limits(DTYPE))
    if box is None:
        return lo, hi
    unknown = sorted(set(box) - set(boom.joint_names))
    if unknown:
        raise ConfigError(f"{where}: unknown joint(s) {unknown}; boom '{boom.name}' has {boom.joint_names}")
    for name, bounds in box.items():
        i = boom.joint_names.index(name)
        joint = boom.joints[i]
        unit = "deg" if joint.revolute else "m"
        if (isinstance(bounds, (str, bytes)) or not isinstance(bounds, Sequence) or len(bounds) != 2
                or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in bounds)):
            raise ConfigError(f"{where}.{name} = {bounds!r}: expected [lower, upper] in {unit}")
        scale = math.pi / 180 if joint.revolute else 1.0
        b_lo, b_hi = bounds[0] * scale, bounds[1] * scale
        if not b_lo < b_hi:
            raise ConfigError(f"{where}.{name} = {list(bounds)!r}: empty box (lower must be below upper)")
        tol = 1e-9
        if joint.locked is not None or b_lo < lo[i] - tol or b_hi > hi[i] + tol:
            limits = [round(float(lo[i]) / scale, 6), round(float(hi[i]) / scale, 6)]
            raise ConfigError(f"{where}.{name} = {list(bounds)!r} {unit}: outside the joint's range {limits}"
                              + (" (the joint is locked)" if joint.locked is not None else ""))
        lo[i], hi[i] = max(b_lo, float(lo[i])), min(b_hi, float(hi[i]))
    return lo, hi


def sample_joints(n: int, boom, seed: int, box: Mapping | None = None) -> torch.Tensor:
    """``(n, n_joints)`` joints uniform within ``box`` (:func:`joint_box`; default: the full ranges,
    locked joints at their lock)."""
    if n <= 0:
        raise ConfigError(f"hole count = {n!r}: expected a positive integer")
    gen = torch.Generator().manual_seed(int(seed))
    lo, hi = joint_box(boom, box)
    return lo + torch.rand(n, boom.n_joints, generator=gen, dtype=DTYPE) * (hi - lo)


def in_face_window(pose: torch.Tensor, tunnel: Tunnel, x_range=(5.5, 7.5), max_angle_deg: float = 30.0):
    """Boolean ``(n,)``: the collar lies in the face window (x in ``x_range``, inside the profile) and
    the hole points within ``max_angle_deg`` of +x (the reference's measure of a face-like pose)."""
    p, d = pose[:, :3], pose[:, 3:] - pose[:, :3]
    cos = d[:, 0] / d.norm(dim=-1).clamp_min(1e-12)
    return ((p[:, 0] >= x_range[0]) & (p[:, 0] <= x_range[1]) & tunnel.contains(p[:, 1], p[:, 2])
            & (cos >= math.cos(math.radians(max_angle_deg))))

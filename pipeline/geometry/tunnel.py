"""The horseshoe tunnel profile (docs/reference.md, section 2): signed distances to its surfaces.

Cross-section in the base frame's (y, z) plane: floor z = 0, vertical walls at
|y| = width/2 up to ``wall_height``, and a semicircular arch of radius width/2
centred at (0, wall_height). All functions are batched over any leading shape and
differentiable; a distance is positive inside the tunnel and negative beyond the
surface it belongs to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.rotations import safe_hypot

SURFACES = ("wall", "ground", "arch")


class Tunnel(Protocol):
    """What the safety model, the hole sampler, the face designer and the figures ask of a drift: the
    :class:`Horseshoe` here, or any cross-section (:class:`pipeline.geometry.profile.Profile`). ``kind``
    picks how capsules are measured (:meth:`pipeline.geometry.collision.SafetyModel._tunnel`)."""

    kind: str
    y_range: tuple[float, float]
    z_range: tuple[float, float]
    width: float
    crown: float

    def surface_distances(self, y: torch.Tensor, z: torch.Tensor) -> dict[str, torch.Tensor]: ...

    def surface_gradients(self, y: torch.Tensor, z: torch.Tensor) -> dict[str, tuple[torch.Tensor, torch.Tensor]]: ...

    def contains(self, y: torch.Tensor, z: torch.Tensor, inset: float = 0.0) -> torch.Tensor: ...

    def sample_yz(self, m: int, inset: float, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]: ...

    def profile_polyline(self) -> tuple[list[float], list[float]]: ...

    def describe(self) -> str: ...


@dataclass(frozen=True)
class Horseshoe:
    width: float = 5.0
    wall_height: float = 3.2
    kind = "horseshoe"  # the other kind: pipeline.geometry.profile.Profile

    @classmethod
    def from_config(cls, cfg) -> Horseshoe:
        for key in ("width", "wall_height"):
            if key not in cfg:
                raise ConfigError(f"tunnel: missing required field '{key}'")
            v = cfg[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"tunnel.{key} = {v!r}: expected a positive number (metres)")
        return cls(float(cfg["width"]), float(cfg["wall_height"]))

    @property
    def half_width(self) -> float:
        return 0.5 * self.width

    @property
    def y_range(self) -> tuple[float, float]:
        return -self.half_width, self.half_width

    @property
    def z_range(self) -> tuple[float, float]:
        return 0.0, self.crown

    def describe(self) -> str:
        return f"horseshoe {self.width:g} x {self.crown:g} m"

    def sample_yz(self, m: int, inset: float, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """``m`` candidate points uniform in the profile's bounding box less ``inset`` (the caller keeps
        those :meth:`contains` accepts)."""
        r = self.half_width - inset
        if r <= 0 or self.crown - inset <= inset:
            raise ConfigError(f"holes.inset = {inset!r} leaves no area inside the tunnel profile")
        y = (torch.rand(m, generator=gen, dtype=torch.float64) * 2 - 1) * r
        z = inset + torch.rand(m, generator=gen, dtype=torch.float64) * (self.crown - 2 * inset)
        return y, z

    @property
    def crown(self) -> float:
        return self.wall_height + self.half_width

    def surface_distances(self, y: torch.Tensor, z: torch.Tensor) -> dict[str, torch.Tensor]:
        """Signed distance of points (y, z) to the wall, the ground and the arch.

        Wall: the two vertical segments; above ``wall_height`` the nearest wall point
        is the segment's top end. Arch: the upper semicircle; below its springing
        line the nearest arch point is one of its ends. Both expressions are
        continuous at ``z = wall_height``.
        """
        r, h = self.half_width, self.wall_height
        inward = r - y.abs()  # horizontal distance to the nearer wall line
        above = z > h
        # The signed distance to the corner (side * r, h) is the wall's above it and the arch's below.
        # ``z - h`` is taken once per use, in this order, so that autograd adds the gradients reaching
        # ``z`` in the same order, and to the same bits, as when each norm had its own stacked input.
        corner = safe_hypot(inward, z - h)
        corner = torch.where(inward < 0, -corner, corner)
        wall = torch.where(above, corner, inward)
        arch = torch.where(above, r - safe_hypot(y, z - h), corner)
        return {"wall": wall, "ground": z, "arch": arch}

    def surface_gradients(self, y: torch.Tensor, z: torch.Tensor) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
        """``(d/dy, d/dz)`` of each distance of :meth:`surface_distances`, in closed form.

        Each distance is the exact distance to one part of the outline (a segment, a line, a
        semicircle, a point), so its gradient is the unit vector from the nearest point of that part
        to (y, z), signed like the distance. Used by the solvers' clearance Jacobians."""
        r, h = self.half_width, self.wall_height
        side = torch.where(y < 0, -1.0, 1.0).to(y.dtype)
        inward = r - y.abs()
        above = z > h
        zero, one = torch.zeros_like(y), torch.ones_like(y)
        # distance to the wall's (or arch's) end point (side * r, h): signed hypot of (inward, z - h)
        corner = safe_hypot(inward, z - h).clamp_min(1e-12)
        sign = torch.where(inward < 0, -1.0, 1.0).to(y.dtype)
        corner_dy, corner_dz = -side * inward * sign / corner, (z - h) * sign / corner
        radial = safe_hypot(y, z - h).clamp_min(1e-12)
        wall = (torch.where(above, corner_dy, -side), torch.where(above, corner_dz, zero))
        arch = (torch.where(above, -y / radial, corner_dy), torch.where(above, -(z - h) / radial, corner_dz))
        return {"wall": wall, "ground": (zero, one), "arch": arch}

    def contains(self, y: torch.Tensor, z: torch.Tensor, inset: float = 0.0) -> torch.Tensor:
        """Boolean: (y, z) lies inside the profile shrunk by ``inset``."""
        d = self.surface_distances(y, z)
        return (d["wall"] >= inset) & (d["ground"] >= inset) & (d["arch"] >= inset)

    def profile_polyline(self, n_arc: int = 64) -> tuple[list[float], list[float]]:
        """Outline (y, z) for plots, counter-clockwise from the right floor corner."""
        r, h = self.half_width, self.wall_height
        ang = [math.pi * k / (n_arc - 1) for k in range(n_arc)]
        ys = [r, *(r * math.cos(a) for a in ang), -r, r]
        zs = [0.0, *(h + r * math.sin(a) for a in ang), 0.0, 0.0]
        return ys, zs

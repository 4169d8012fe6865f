"""Exact nearest neighbours of points among points (brute force, chunked): the pairs the label-
consistency measure looks at, and the graph a continuation walks along."""

from __future__ import annotations

import torch


def nearest_neighbours(points: torch.Tensor, query: torch.Tensor, k: int = 1,
                       chunk: int = 256) -> tuple[torch.Tensor, torch.Tensor]:
    """For each row index in ``query (m,)``, the indices of its ``k`` nearest other rows of
    ``points (n, d)``, nearest first, and the distances to them: ``(m,)`` each for ``k = 1``,
    ``(m, k)`` otherwise. Chunks of ``chunk`` queries keep memory at ``chunk x n`` distances."""
    if not 1 <= k < len(points):
        raise ValueError(f"nearest_neighbours: k = {k} needs 1 <= k < {len(points)} points")
    idx, dist = [], []
    for start in range(0, len(query), chunk):  # chunks of queries, each one batched distance matrix
        q_idx = query[start:start + chunk]
        d = torch.cdist(points[q_idx], points)
        d[torch.arange(len(q_idx)), q_idx] = torch.inf  # a point is not its own neighbour
        best, arg = d.topk(k, dim=1, largest=False)
        idx.append(arg)
        dist.append(best)
    idx, dist = torch.cat(idx), torch.cat(dist)
    return (idx[:, 0], dist[:, 0]) if k == 1 else (idx, dist)


def nearest_in(points: torch.Tensor, queries: torch.Tensor, chunk: int = 256) -> torch.Tensor:
    """For each row of ``queries (m, d)``, the index of its nearest row of ``points (n, d)``
    (another set: nothing is excluded), in chunks of ``chunk`` queries."""
    return torch.cat([torch.cdist(queries[start:start + chunk], points).argmin(dim=1)
                      for start in range(0, len(queries), chunk)])

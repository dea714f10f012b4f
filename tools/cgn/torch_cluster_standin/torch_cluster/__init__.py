"""
Plain-torch stand-ins for the torch_cluster operations that cgn-pytorch reaches: fps, radius, knn.

torch_cluster has no wheels on PyPI. torch_geometric 2.7 calls these through a module named
torch_cluster; they are written here from their documented behaviour, for CPU tensors, with batch
vectors sorted as torch_geometric makes them. knn_graph comes along because torch_geometric
imports it at start; the other names it imports at start fail with a clear error when called.
Installed into .venv-cgn only, by tools/cgn/make_venv.sh.
"""

from collections.abc import Callable, Iterator
import math

import torch
from torch import Tensor

__version__ = '0.1.0'
_CHUNK = 1024  # query rows per distance block: memory stays at _CHUNK x len(x) floats


def _segments(batch: Tensor | None, n: int) -> Iterator[tuple[int, int, int]]:
    """Yield (example id, start, stop) for each run of a sorted batch vector (one run if None)."""
    if batch is None:
        yield 0, 0, n
        return
    ids, counts = torch.unique_consecutive(batch, return_counts=True)
    stop = 0
    for example, count in zip(ids.tolist(), counts.tolist(), strict=True):
        stop += count
        yield example, stop - count, stop


def fps(
    src: Tensor,
    batch: Tensor | None = None,
    ratio: float = 0.5,
    random_start: bool = True,
    batch_size: int | None = None,
) -> Tensor:
    """
    Farthest point sampling: ceil(ratio * n) indices of each example, in the order picked.

    The start is drawn from torch's global generator when random_start (seed it to repeat a run).
    """
    picked = [torch.empty(0, dtype=torch.long)]
    for _, lo, hi in _segments(batch, src.shape[0]):
        points = src[lo:hi].reshape(hi - lo, -1).double()
        norms = (points * points).sum(1)
        # less 1e-9: a ratio written as m / n, times n, may round to just above the integer m
        count = min(hi - lo, math.ceil(ratio * (hi - lo) - 1e-9))
        order = torch.empty(count, dtype=torch.long)
        current = int(torch.randint(hi - lo, (1,))) if random_start else 0
        gap = torch.full((hi - lo,), math.inf, dtype=torch.float64)
        for i in range(count):
            order[i] = current
            # |p - c|^2 as |p|^2 - 2 p.c + |c|^2: one matrix-vector product a pick
            squared = torch.addmv(norms, points, points[current], alpha=-2.0) + norms[current]
            torch.minimum(gap, squared, out=gap)
            current = int(torch.argmax(gap))
        picked.append(order + lo)
    return torch.cat(picked)


def _squared_distances(y: Tensor, x: Tensor) -> Tensor:
    """Squared distances (len(y), len(x)) as |y|^2 + |x|^2 - 2 y.x, in single precision."""
    y, x = y.reshape(len(y), -1).float(), x.reshape(len(x), -1).float()
    squared = torch.addmm((x * x).sum(1)[None, :], y, x.T, alpha=-2.0)
    squared += (y * y).sum(1)[:, None]
    return squared.clamp_(min=0.0)


def _pairs(
    x: Tensor,
    y: Tensor,
    batch_x: Tensor | None,
    batch_y: Tensor | None,
    select: Callable[[Tensor], tuple[Tensor, Tensor]],
) -> Tensor:
    """Apply select to squared-distance blocks (y rows, x columns) per example; (2, E) indices."""
    spans = {example: (lo, hi) for example, lo, hi in _segments(batch_x, x.shape[0])}
    rows, cols = [torch.empty(0, dtype=torch.long)], [torch.empty(0, dtype=torch.long)]
    for example, lo, hi in _segments(batch_y, y.shape[0]):
        if example not in spans:
            continue
        x_lo, x_hi = spans[example]
        for start in range(lo, hi, _CHUNK):
            stop = min(hi, start + _CHUNK)
            squared = _squared_distances(y[start:stop], x[x_lo:x_hi])
            row, col = select(squared)
            rows.append(row + start)
            cols.append(col + x_lo)
    return torch.stack([torch.cat(rows), torch.cat(cols)])


def radius(
    x: Tensor,
    y: Tensor,
    r: float,
    batch_x: Tensor | None = None,
    batch_y: Tensor | None = None,
    max_num_neighbors: int = 32,
    num_workers: int = 1,
    batch_size: int | None = None,
) -> Tensor:
    """
    For each point of y, the points of x closer than r, at most max_num_neighbors of them.

    When more lie inside, the lowest x indices are kept, as torch_cluster's GPU kernel keeps them
    (the checkpoint was trained on a GPU). Returns (2, E): row 0 indexes y, row 1 indexes x.
    num_workers and batch_size are accepted for torch_geometric's calls and not needed.
    """

    def select(squared: Tensor) -> tuple[Tensor, Tensor]:
        row, col = torch.nonzero(squared < r * r, as_tuple=True)  # row-major: col ascends
        counts = torch.bincount(row, minlength=squared.shape[0])
        rank = torch.arange(len(row)) - (torch.cumsum(counts, 0) - counts)[row]
        keep = rank < max_num_neighbors
        return row[keep], col[keep]

    return _pairs(x, y, batch_x, batch_y, select)


def knn(
    x: Tensor,
    y: Tensor,
    k: int,
    batch_x: Tensor | None = None,
    batch_y: Tensor | None = None,
    cosine: bool = False,
    num_workers: int = 1,
    batch_size: int | None = None,
) -> Tensor:
    """
    For each point of y, its k nearest points of x (all of x when it has fewer), nearest first.

    Returns (2, E): row 0 indexes y, row 1 indexes x. Euclidean only; num_workers and batch_size
    are accepted for torch_geometric's calls and not needed.
    """
    if cosine:
        raise NotImplementedError('the torch_cluster stand-in has Euclidean knn only')

    def select(squared: Tensor) -> tuple[Tensor, Tensor]:
        kept = min(k, squared.shape[1])
        col = torch.topk(squared, kept, dim=1, largest=False).indices.reshape(-1)
        return torch.arange(squared.shape[0]).repeat_interleave(kept), col

    return _pairs(x, y, batch_x, batch_y, select)


def knn_graph(
    x: Tensor,
    k: int,
    batch: Tensor | None = None,
    loop: bool = False,
    flow: str = 'source_to_target',
    cosine: bool = False,
    num_workers: int = 1,
    batch_size: int | None = None,
) -> Tensor:
    """Edges from each point's k nearest neighbours to it (flow 'source_to_target'), (2, E)."""
    pairs = knn(x, x, k if loop else k + 1, batch, batch, cosine)
    if not loop:
        pairs = pairs[:, pairs[0] != pairs[1]]
    return pairs.flip(0) if flow == 'source_to_target' else pairs


def _missing(name: str) -> Callable[..., Tensor]:
    def missing(*args: object, **kwargs: object) -> Tensor:
        raise NotImplementedError(f'torch_cluster.{name} has no stand-in (only fps, radius, knn)')

    missing.__name__ = name
    return missing


graclus_cluster = _missing('graclus_cluster')
grid_cluster = _missing('grid_cluster')
nearest = _missing('nearest')
radius_graph = _missing('radius_graph')
random_walk = _missing('random_walk')

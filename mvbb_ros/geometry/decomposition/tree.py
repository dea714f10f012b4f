"""
Fit-and-split MVBB decomposition (paper Sec. III-B to III-D); no ROS import.

:func:`decompose` fits the minimum-volume bounding box (MVBB) of a point cloud, then repeatedly
cuts a box in two along its best face-parallel cut (:mod:`mvbb_ros.geometry.decomposition.split`),
fits an MVBB to each part and keeps the split when the volume gain Theta* (eq. 2) is below the gain
threshold t. The result is a :class:`Decomposition`
(:mod:`mvbb_ros.geometry.decomposition.result`): the whole tree, the leaf boxes and which points
each holds.

Known limit of the criterion (measured on the paper's GraspIt! mug, see
``benchmarks/decompose.py``): mesh vertices that lie on planar rings with empty layers between
them can be cut into flat boxes of zero volume. Each such split removes a whole slab, and as
Theta* is relative to the shrinking total leaf volume, high thresholds (t = 0.98) then keep
splitting (over 30 boxes where the paper has 5); surface samples of the same mesh give 4.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
import heapq
import math

from mvbb_ros.arrays import IndexArray
from mvbb_ros.common.workers import gather, Workers
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.boxfit.fit import fit_part, minimum_bounding_box, ROOT_SEARCH
from mvbb_ros.geometry.decomposition import split as splitting
from mvbb_ros.geometry.decomposition.result import (
    Decomposition,
    DecompositionNode,
    DecompositionSettings,
    DEFAULT_GAIN_THRESHOLD,
    DEFAULT_MIN_POINTS,
    Order,
    PartSearch,
    StopReason,
)
import numpy as np
from numpy.typing import ArrayLike, NDArray


#: With rescoring, another cut replaces the paper's best cut by theta only when its parts'
#: boxes are smaller by more than this share of the box's volume: near-ties keep the paper's
#: cut (the PCL stereo mug's handle cut against a rim slab 0.2 % smaller; docs/single_views.md).
RESCORE_MARGIN = 0.005


@dataclass
class _Draft:
    """Mutable node while the tree is built."""

    box: Box
    point_indices: IndexArray
    parent: int | None
    depth: int
    children: tuple[int, ...] = ()
    cut: splitting.Cut | None = None
    tested_cut: splitting.Cut | None = None
    theta: float | None = None
    gain: float | None = None
    dropped: bool = False
    stop_reason: StopReason | None = None


@dataclass
class _Split:
    """
    A candidate split with its two fitted child boxes.

    ``boxes`` is None when the split was refused before both parts were fitted: no child
    volumes could have passed it (``bound`` 0), or the larger part's box alone kept Theta* at t
    or above (``bound`` its volume). ``volume`` is then ``bound``, a lower bound.
    """

    cut: splitting.Cut
    parts: tuple[IndexArray, IndexArray]
    boxes: tuple[Box, Box] | None
    bound: float = 0.0

    @property
    def volume(self) -> float:
        if self.boxes is None:
            return self.bound
        return self.boxes[0].volume + self.boxes[1].volume


class _Waiting:
    """Boxes waiting to be tested, popped in the chosen order."""

    def __init__(self, order: Order) -> None:
        self._order = order
        self._heap: list[tuple[float, int]] = []
        self._queue: deque[int] = deque()

    def push_all(self, entries: list[tuple[int, float]]) -> None:
        """Add (node index, priority) entries; the priority is used by the heap orders only."""
        if self._order in ('volume', 'gain'):
            for index, priority in entries:
                heapq.heappush(self._heap, (-priority, index))
        elif self._order == 'breadth':
            self._queue.extend(index for index, _ in entries)
        else:
            # Depth first pops the last pushed: push C2 before C1 so C1's subtree comes first.
            self._queue.extend(index for index, _ in reversed(entries))

    def pop(self) -> int:
        """Remove and return the next node index."""
        if self._heap:
            return heapq.heappop(self._heap)[1]
        if self._order == 'breadth':
            return self._queue.popleft()
        return self._queue.pop()

    def __bool__(self) -> bool:
        return bool(self._heap) or bool(self._queue)


def _validated_points(points: ArrayLike) -> NDArray[np.float64]:
    try:
        pts = np.array(points, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as error:
        raise ValueError(f'decompose needs an (N, 3) array of numbers: {error}') from error
    if pts.size == 0:
        raise ValueError(
            f'decompose needs at least one point, got an empty point array (shape {pts.shape})'
        )
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f'decompose needs points of shape (N, 3), got shape {pts.shape}')
    if not np.all(np.isfinite(pts)):
        raise ValueError('decompose got non-finite coordinates (NaN or inf); remove them first')
    pts.setflags(write=False)
    return pts


def _part_box(
    points: NDArray[np.float64], indices: IndexArray, settings: DecompositionSettings
) -> Box:
    """Return the box of one part of a cut: the settings' seed and part search."""
    part = np.take(points, indices, axis=0)
    return fit_part(part, seed=settings.seed, full=settings.part_search == 'full')


def _best_split(
    points: NDArray[np.float64],
    draft: _Draft,
    settings: DecompositionSettings,
    fit_parts: bool,
    others: float | None = None,
    pool: Workers | None = None,
) -> _Split | None:
    """
    Find the split of a node: the paper's theta*, or the best of k real fits (rescoring).

    The part with more points of each cut is fitted first. A cut whose larger part's box alone
    is no smaller than the best split so far (less the margin when that is the paper's cut)
    cannot win, and its other part is not fitted.

    :param fit_parts: fit the parts' boxes; False returns the best cut by theta unfitted (for a
        split that no child volumes could pass).
    :param others: V(A minus P) when the split is tested at once (eq. 2): when every cut's
        larger part alone keeps Theta* at t or above, the cut with the smallest such box is
        returned with only that bound (no other part's box can lower Theta*). None fits the
        parts needed to rank the cuts (the ``'gain'`` order ranks splits before A is known).
    :param pool: workers that fit every candidate's parts at once (the larger parts, then the
        others ahead of need; the split is the same), or None to fit on this thread as needed.
    """
    if pool is not None and pool.parallel and fit_parts:
        return _best_split_parallel(points, draft, settings, others, pool)
    box = draft.box
    scores = _cut_scores(points, draft, settings)
    limit = max(1, settings.rescore_cuts) if fit_parts else 1
    candidates: list[tuple[splitting.Cut, tuple[IndexArray, IndexArray], int, Box]] = []
    for cut in splitting.candidate_cuts(scores, draft.box, limit=limit):
        upper = splitting.cut_mask(scores, cut)
        parts = (draft.point_indices[~upper], draft.point_indices[upper])
        if not fit_parts:
            return _Split(cut=cut, parts=parts, boxes=None)
        larger = 0 if len(parts[0]) >= len(parts[1]) else 1
        first = _part_box(points, parts[larger], settings)
        candidates.append((cut, parts, larger, first))
    if not candidates:
        return None
    if others is not None and not any(
        _theta_star(draft, first.volume, others) < settings.gain_threshold
        for *_, first in candidates
    ):
        cut, parts, _, first = min(candidates, key=lambda candidate: candidate[3].volume)
        return _Split(cut=cut, parts=parts, boxes=None, bound=first.volume)
    paper_cut = candidates[0][0]
    best: _Split | None = None
    for cut, parts, larger, first in candidates:
        # The paper's cut (the first) yields only to a clearly smaller pair of boxes.
        margin = RESCORE_MARGIN * box.volume if best is not None and best.cut is paper_cut else 0.0
        if best is not None and not first.volume < best.volume - margin:
            continue
        second = _part_box(points, parts[1 - larger], settings)
        boxes = (first, second) if larger == 0 else (second, first)
        split = _Split(cut=cut, parts=parts, boxes=boxes)
        if best is None or split.volume < best.volume - margin:
            best = split
    return best


def _cut_scores(
    points: NDArray[np.float64], draft: _Draft, settings: DecompositionSettings
) -> splitting.CutScores:
    """Return the split measure's scores of every cut of `draft`'s box (its own frame)."""
    box = draft.box
    local = splitting.frame_points_kernel(points, draft.point_indices, box.center, box.rotation)
    return splitting.score_cuts(
        local,
        cells=settings.grid_cells,
        measure=settings.split_measure,
        min_thickness=settings.min_thickness,
    )


def _best_split_parallel(
    points: NDArray[np.float64],
    draft: _Draft,
    settings: DecompositionSettings,
    others: float | None,
    pool: Workers,
) -> _Split | None:
    """
    Return :func:`_best_split` with fitted parts, its box fits spread over `pool`.

    The same cuts, fits and choices as the serial path: every fit is a pure function of its
    points and the seed. The larger parts are fitted first, the other parts are started at once
    too, ahead of need; the fits the serial path would skip are cancelled when not yet started.
    """
    box = draft.box
    scores = _cut_scores(points, draft, settings)
    limit = max(1, settings.rescore_cuts)
    cuts = []
    for cut in splitting.candidate_cuts(scores, draft.box, limit=limit):
        upper = splitting.cut_mask(scores, cut)
        parts = (draft.point_indices[~upper], draft.point_indices[upper])
        larger = 0 if len(parts[0]) >= len(parts[1]) else 1
        cuts.append((cut, parts, larger))
    if not cuts:
        return None

    def fit(indices: IndexArray) -> Callable[[], Box]:
        return lambda: _part_box(points, indices, settings)

    first_fits = [pool.submit(fit(parts[larger])) for _, parts, larger in cuts]
    second_fits = [pool.submit(fit(parts[1 - larger])) for _, parts, larger in cuts]
    try:
        firsts = gather(first_fits)
        candidates = [
            (cut, parts, larger, first)
            for (cut, parts, larger), first in zip(cuts, firsts, strict=True)
        ]
        if others is not None and not any(
            _theta_star(draft, first.volume, others) < settings.gain_threshold for first in firsts
        ):
            cut, parts, _, first = min(candidates, key=lambda candidate: candidate[3].volume)
            return _Split(cut=cut, parts=parts, boxes=None, bound=first.volume)
        paper_cut = candidates[0][0]
        best: _Split | None = None
        for (cut, parts, larger, first), second_fit in zip(candidates, second_fits, strict=True):
            margin = (
                RESCORE_MARGIN * box.volume if best is not None and best.cut is paper_cut else 0.0
            )
            if best is not None and not first.volume < best.volume - margin:
                continue
            second_fit.run_if_waiting()
            for ahead in reversed(second_fits):
                if second_fit.done():
                    break
                # While a helper fits this part, this thread fits the others ahead of need
                # (most are needed; each is fitted once either way).
                ahead.run_if_waiting()
            second = second_fit.result()
            boxes = (first, second) if larger == 0 else (second, first)
            split = _Split(cut=cut, parts=parts, boxes=boxes)
            if best is None or split.volume < best.volume - margin:
                best = split
        return best
    finally:
        for task in (*first_fits, *second_fits):
            task.cancel()


def _others(index: int, leaf_volumes: dict[int, float]) -> float:
    """Return V(A minus P): the summed volume of the current leaves other than `index`."""
    return math.fsum(volume for i, volume in leaf_volumes.items() if i != index)


def _may_pass(draft: _Draft, others: float, threshold: float) -> bool:
    """
    Tell whether some child volumes could bring Theta* (eq. 2) of the node below `threshold`.

    Theta* is smallest when both children have no volume: others / (V(P) + others)
    (:func:`_theta_star`; the real Theta* is never below it). When that is not below t, the
    split is refused whatever the fits would give: the largest box first, a small box is
    refused once V(P) <= (1 - t) / t of the others' volume.
    """
    return _theta_star(draft, 0.0, others) < threshold


def _reduction(draft: _Draft, split: _Split | None) -> float:
    """Return the volume a split removes, V(P) - V(C1) - V(C2) (-inf without a split)."""
    return -math.inf if split is None else draft.box.volume - split.volume


def _theta_star(draft: _Draft, children: float, others: float) -> float:
    """
    Return Theta* (eq. 2) of splitting `draft` into boxes of `children` volume in all.

    Rounding is monotone: a lower bound on `children` gives a lower bound on Theta*.
    """
    denominator = draft.box.volume + others
    return (children + others) / denominator if denominator > 0.0 else 1.0


def _record_gain(draft: _Draft, split: _Split, others: float) -> float:
    """Compute Theta* (eq. 2) of `split` (``others``: V(A minus P)) and record it on `draft`."""
    gain = _theta_star(draft, split.volume, others)
    draft.tested_cut = split.cut
    draft.theta = split.cut.theta
    draft.gain = float(gain)
    return gain


def decompose(
    points: ArrayLike,
    *,
    pool: Workers | None = None,
    gain_threshold: float = DEFAULT_GAIN_THRESHOLD,
    min_points: int = DEFAULT_MIN_POINTS,
    split_measure: splitting.SplitMeasure = 'area',
    rescore_cuts: int = 0,
    max_boxes: int | None = None,
    seed: int = 0,
    grid_cells: int = splitting.DEFAULT_GRID_CELLS,
    order: Order = 'volume',
    min_thickness: float = 0.0,
    part_search: PartSearch = 'light',
) -> Decomposition:
    """
    Decompose a point cloud into minimum-volume bounding boxes by fit-and-split.

    The defaults are the paper's algorithm. The root is the MVBB of all points. A box P is cut
    at the best of its six families of face-parallel grid cuts by the 2D split measure theta
    (eq. 1, :mod:`mvbb_ros.geometry.decomposition.split`); each part gets its own MVBB (C1 below
    the cut, C2 above); the split is kept when the volume gain

        Theta* = (V(C1) + V(C2) + V(A minus P)) / (V(P) + V(A minus P))

    is below `gain_threshold` (eq. 2; A is the set of current leaf boxes, P included).
    Theta* < 1 exactly when the children's volume is below the parent's, so with t <= 1 every
    kept split lowers the total leaf volume. A box whose split is refused is final: it is not
    tested again when A shrinks later. When the denominator is zero (every current box is flat)
    Theta* is taken as 1: there is no volume to gain.

    Processing order (Theta* depends on A, so the order matters; the paper does not say):
    by default the largest box waiting to be tested goes first (``order='volume'``, ties by
    node index), so the splits that can gain most are tested while A is largest, and the
    result does not depend on which side of a cut is called lower (an arbitrary sign of a box
    axis), as it does for ``'breadth'`` (first in, first out: level by level) and ``'depth'``
    (last in, first out: C1's subtree before C2's). ``'gain'`` is best first: every leaf's best
    split is fitted when the leaf is made, the one that removes the most volume is tested next,
    and the first refusal ends the decomposition (every other split would gain less); so no
    leaf is left whose split would pass against the final A. ``benchmarks/decompose.py
    --sweep order`` compares them: they agree at t = 0.90 and 0.94 on the paper's models.

    Noise: a box with fewer than `min_points` points is not kept. When an accepted split makes
    a part below `min_points`, that child stays in the tree with ``dropped=True``, its points
    leave the kept set and are reported in :attr:`Decomposition.dropped_point_indices`, and its
    volume leaves A; the other child is kept. The split is still tested by eq. 2 with both
    fitted children, as the paper does. A split whose parts are both below `min_points` is
    refused (``stop_reason='noise'``): a kept box is never dropped by its own split. A cloud
    of fewer than `min_points` points gives a dropped root, no leaves and every point dropped.
    So the leaves' point sets partition the kept points, and kept plus dropped are all points.

    Fits skipped: with the volume of the other leaves, some splits could not pass eq. 2 even
    with children of no volume (others / (V(P) + others) >= t: at t = 0.94 a box of less than
    6.4 % of the others' volume). Such a split is refused as eq. 2 would refuse it, its best cut
    recorded, but its parts are not fitted (its ``gain`` is that lower bound). Otherwise the
    part with more points is fitted first, and when its box alone keeps Theta* at t or above
    the split is refused without fitting the other part (its ``gain`` is Theta* with the other
    child of no volume; about half of the refused splits on the shared scans). The result is
    the same as with every fit made (the ``'gain'`` order and rescoring fit every split they
    rank).

    Box fits: the root gets the default search (:func:`mvbb_ros.geometry.boxfit.fit.fit_box`,
    hulled on its grid coreset from 16,384 points on:
    :data:`~mvbb_ros.geometry.boxfit.fit.ROOT_SEARCH`); each part the light
    :data:`~mvbb_ros.geometry.boxfit.fit.PART_SEARCH` (fewer candidate axes and starts, a short
    walk, parts of 1,000 points or more hulled on a grid coreset) or, with ``part_search:
    'full'``, the default search (:data:`~mvbb_ros.geometry.boxfit.fit.FULL_PART_SEARCH`). The
    light search misses the best box by more than 1 % on about one part in 200, the full one
    on none of 30,000 varied clouds, at about twice the light one's time
    (``docs/performance.md``).

    :param points: (N, 3) points, N >= 1, finite, in any units (metres for sensor data); boxes
        and volumes come out in those units. Every criterion is scale-free: theta and Theta*
        are ratios, the grid is relative to each box and `min_points` is a count.
    :param gain_threshold: the paper's t in [0, 1]; a split is kept when Theta* < t. Lower
        means fewer boxes (0 never splits, 1 keeps every split that lowers the volume). The
        paper shows 0.90, 0.94 and 0.98.
    :param min_points: smallest number of points of a kept box (>= 1); see Noise above.
    :param split_measure: ``'area'`` (paper: areas of the parts' rectangles in the six 2D
        projections) or ``'volume'`` (option: volumes of the parts' boxes in P's frame, three
        families, same cost).
    :param rescore_cuts: 0 is the paper (the single best cut by theta). k > 0 fits both
        children's MVBBs for the k best distinct cuts (local minima of theta) and keeps the one
        with the smallest summed child volume, the paper's cut unless another is smaller by
        more than :data:`RESCORE_MARGIN` of the box: 2k box fits per tested box instead of 2,
        to find cuts that the projection measure ranks lower (the paper's bunny ear).
    :param max_boxes: cap on the number of leaves, or None. A split that would take the number
        of kept leaves above it is refused (``stop_reason='max_boxes'``); a split that only cuts
        off noise does not add a leaf and is still allowed.
    :param seed: passed to every MVBB fit, so the same input and seed give the same result.
    :param grid_cells: grid cells per box axis for the cut positions (>= 2); see
        :data:`mvbb_ros.geometry.decomposition.split.DEFAULT_GRID_CELLS`.
    :param order: ``'volume'`` (default), ``'gain'``, ``'breadth'`` or ``'depth'``; see Processing
        order.
    :param min_thickness: a floor on the thickness of the boxes a split may make, in the
        points' units; 0 (the paper) has none. Cuts that leave a part thinner than it along the
        cut axis are not candidates, and a split whose fitted child box would still be thinner
        than it is refused (``stop_reason='thin'``). On single sensor views the paper's gain
        peels plates of sensor thickness off a surface; the floor keeps boxes at least as thick
        as the sensor can resolve (``docs/single_views.md``).
    :param part_search: ``'light'`` (default) or ``'full'``: how the parts' boxes are searched
        (Box fits above).
    :return: the decomposition: the tree (``nodes``, ``root``), the leaves in node order with
        their point indices, the dropped points and the settings.
    :param pool: workers that fit the candidate cuts' parts at once (:func:`_best_split`);
        the decomposition is the same with any, and with None (every fit on this thread).
    :raises ValueError: for an empty point array, a shape other than (N, 3), non-finite
        coordinates or an invalid setting; the message says which.
    """
    settings = DecompositionSettings(
        gain_threshold=gain_threshold,
        min_points=min_points,
        split_measure=split_measure,
        rescore_cuts=rescore_cuts,
        max_boxes=max_boxes,
        seed=seed,
        grid_cells=grid_cells,
        order=order,
        min_thickness=min_thickness,
        part_search=part_search,
    )
    pts = _validated_points(points)
    root = _Draft(
        box=minimum_bounding_box(pts, seed=settings.seed, **ROOT_SEARCH),
        point_indices=np.arange(len(pts), dtype=np.intp),
        parent=None,
        depth=0,
    )
    drafts = [root]
    if len(pts) < settings.min_points:
        root.dropped = True
        root.stop_reason = 'dropped'
        return _finish(pts, drafts, settings)

    leaf_volumes: dict[int, float] = {0: root.box.volume}
    splits: dict[int, _Split | None] = {}
    waiting = _Waiting(settings.order)

    def enqueue(indices: list[int]) -> None:
        entries = []
        for i in indices:
            if settings.order == 'gain':
                # Best first needs every leaf's best split up front (each is fitted once anyway).
                splits[i] = _best_split(pts, drafts[i], settings, fit_parts=True, pool=pool)
                priority = _reduction(drafts[i], splits[i])
            else:
                priority = drafts[i].box.volume
            entries.append((i, priority))
        waiting.push_all(entries)

    enqueue([0])
    while waiting:
        index = waiting.pop()
        draft = drafts[index]
        others = _others(index, leaf_volumes)
        if index in splits:
            split = splits.pop(index)
        else:
            may_pass = _may_pass(draft, others, settings.gain_threshold)
            split = _best_split(pts, draft, settings, fit_parts=may_pass, others=others, pool=pool)
        if split is None:
            draft.stop_reason = 'no_cut'
            continue
        gain = _record_gain(draft, split, others)
        kept = [len(part) >= settings.min_points for part in split.parts]
        if not gain < settings.gain_threshold:
            draft.stop_reason = 'gain'
            if settings.order == 'gain':
                # Best first: every other waiting split gains less, so each is refused too.
                while waiting:
                    other = waiting.pop()
                    other_split = splits[other]
                    if other_split is None:
                        drafts[other].stop_reason = 'no_cut'
                    else:
                        _record_gain(drafts[other], other_split, _others(other, leaf_volumes))
                        drafts[other].stop_reason = 'gain'
            continue
        if not any(kept):
            draft.stop_reason = 'noise'
            continue
        assert split.boxes is not None, 'a split that passes eq. 2 has fitted parts'
        if any(
            keep and float(np.min(box.extents)) < settings.min_thickness
            for keep, box in zip(kept, split.boxes, strict=True)
        ):
            draft.stop_reason = 'thin'
            continue
        leaves_after = len(leaf_volumes) - 1 + sum(kept)
        if settings.max_boxes is not None and leaves_after > settings.max_boxes:
            draft.stop_reason = 'max_boxes'
            continue
        draft.cut = split.cut
        del leaf_volumes[index]
        children = []
        for part, box, keep in zip(split.parts, split.boxes, kept, strict=True):
            child = _Draft(box=box, point_indices=part, parent=index, depth=draft.depth + 1)
            children.append(len(drafts))
            drafts.append(child)
            if keep:
                leaf_volumes[children[-1]] = box.volume
            else:
                child.dropped = True
                child.stop_reason = 'dropped'
        draft.children = tuple(children)
        enqueue([i for i in children if i in leaf_volumes])
    return _finish(pts, drafts, settings)


def _finish(
    points: NDArray[np.float64], drafts: list[_Draft], settings: DecompositionSettings
) -> Decomposition:
    """Freeze the drafts into the result."""
    nodes = []
    for index, draft in enumerate(drafts):
        indices = np.array(draft.point_indices, dtype=np.intp)
        indices.setflags(write=False)
        nodes.append(
            DecompositionNode(
                index=index,
                box=draft.box,
                point_indices=indices,
                parent=draft.parent,
                children=draft.children,
                cut=draft.cut,
                tested_cut=draft.tested_cut,
                theta=draft.theta,
                gain=draft.gain,
                depth=draft.depth,
                dropped=draft.dropped,
                stop_reason=draft.stop_reason,
            )
        )
    return Decomposition(points=points, nodes=tuple(nodes), settings=settings)

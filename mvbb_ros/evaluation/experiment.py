"""
The Figure 6 experiment on one object: box-face grasps against the spherical baseline.

:func:`compare_grasp_sets` scores, with one gripper and contact model, the spherical grasps, the
24 grasps of the root box (:func:`~mvbb_ros.geometry.boxfit.fit.minimum_bounding_box`) and the
hypotheses (:func:`~mvbb_ros.geometry.grasping.hypotheses.grasp_hypotheses`) of decompositions
(:func:`~mvbb_ros.geometry.decomposition.tree.decompose`) at several gain thresholds, and tests the
paper's claim: the best box grasp reaches 90 % of the best spherical epsilon with at most 1 % of
the candidates. The protocol is in ``docs/evaluation_protocol.md``;
:mod:`mvbb_ros.evaluation.report` makes the table and the plot.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
import time
from typing import Any

from mvbb_ros.evaluation.gripper import ParallelJawGripper
from mvbb_ros.evaluation.mesh import GraspTarget
from mvbb_ros.evaluation.simulation import evaluate_grasps, GraspEvaluation
from mvbb_ros.evaluation.spherical import (
    DEFAULT_SPHERICAL_STEP_DEG,
    expected_best_of,
    spherical_grasps,
)
from mvbb_ros.evaluation.wrench import DEFAULT_CONE_EDGES, DEFAULT_FRICTION
from mvbb_ros.geometry.boxfit.fit import minimum_bounding_box
from mvbb_ros.geometry.decomposition.tree import decompose
from mvbb_ros.geometry.grasping.hypotheses import Grasp, grasp_hypotheses
from mvbb_ros.geometry.grasping.refine import refine_grasps
from mvbb_ros.geometry.grasping.refinement_settings import GraspView, RefinementSettings
from mvbb_ros.geometry.grasping.surface import surface_model
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

#: Gain thresholds of the paper's decompositions (Table I, Fig. 5 and 6).
PAPER_THRESHOLDS: tuple[float, ...] = (0.90, 0.94, 0.98)
#: The claim under test: the best box grasp reaches this fraction of the best spherical
#: epsilon ...
CLAIM_QUALITY_FRACTION = 0.90
#: ... with at most this fraction of the spherical grasps' count.
CLAIM_CANDIDATE_FRACTION = 0.01


@dataclass
class GraspSetResult:
    """
    One family of candidates on one object and their qualities.

    :ivar name: ``'spherical'``, ``'root box'`` or ``'t=0.94'`` style.
    :ivar evaluation: the qualities, in the candidates' order (box grasps: ranked best first).
    :ivar boxes: number of boxes the candidates came from (None for spherical).
    :ivar generate_seconds: time to make the candidates (box fit, decomposition, hypotheses).
    :ivar gain_threshold: the decomposition's t (None otherwise).
    """

    name: str
    evaluation: GraspEvaluation
    boxes: int | None = None
    generate_seconds: float = 0.0
    gain_threshold: float | None = None

    @property
    def candidates(self) -> int:
        """Return the number of grasps evaluated."""
        return len(self.evaluation)

    @property
    def seconds(self) -> float:
        """Return the generation plus evaluation time, seconds."""
        return self.generate_seconds + self.evaluation.seconds

    @property
    def best_index(self) -> int | None:
        """Index of the first grasp with the largest epsilon (None when none is FC)."""
        eps = self.evaluation.epsilon
        if not len(eps) or not eps.max() > 0.0:
            return None
        return int(np.argmax(eps))

    def best_epsilon(self) -> float:
        """Largest epsilon (0 without force-closure grasps)."""
        return float(self.evaluation.epsilon.max()) if self.candidates else 0.0

    def median_epsilon(self, *, force_closure_only: bool = False) -> float:
        """Median epsilon over all candidates (failures count 0), or over the FC ones only."""
        eps = self.evaluation.epsilon
        if force_closure_only:
            eps = eps[eps > 0.0]
        return float(np.median(eps)) if len(eps) else 0.0

    def force_closure_rate(self) -> float:
        """Fraction of candidates that are force-closure."""
        return float(self.evaluation.force_closure.mean()) if self.candidates else 0.0

    def first_reaching(self, epsilon: float) -> int | None:
        """1-based rank of the first candidate (in order) with epsilon >= `epsilon`, or None."""
        hits = np.flatnonzero(self.evaluation.epsilon >= epsilon)
        return int(hits[0]) + 1 if len(hits) else None


@dataclass
class QualityComparison:
    """
    The Figure 6 experiment on one object: spherical grasps against box grasps.

    :ivar name: the object's name.
    :ivar target: the prepared mesh.
    :ivar gripper: the gripper used for every set.
    :ivar sets: spherical first (when run), then the root box, then each threshold.
    :ivar settings: friction, cone edges, contact radius, spherical step, standoff.
    """

    name: str
    target: GraspTarget
    gripper: ParallelJawGripper
    sets: list[GraspSetResult] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def spherical(self) -> GraspSetResult | None:
        """Return the spherical baseline (None when it was not run)."""
        return next((s for s in self.sets if s.name == 'spherical'), None)

    @property
    def box_sets(self) -> list[GraspSetResult]:
        """Return the root box and decomposition sets."""
        return [s for s in self.sets if s.name != 'spherical']

    def claim(self, result: GraspSetResult) -> dict[str, Any]:
        """
        Test the claim on one box set.

        The claim: its best epsilon reaches 90 % of the best spherical epsilon with at most 1 %
        of the spherical candidates.

        :param result: a box set of this comparison.
        :return: ``quality_ratio``, ``candidate_ratio``, ``holds`` (None without a spherical
            baseline or when no spherical grasp is force-closure).
        """
        spherical = self.spherical
        if spherical is None or not spherical.best_epsilon() > 0.0:
            return {'quality_ratio': None, 'candidate_ratio': None, 'holds': None}
        ratio = result.best_epsilon() / spherical.best_epsilon()
        candidates = result.candidates / spherical.candidates
        return {
            'quality_ratio': ratio,
            'candidate_ratio': candidates,
            'holds': bool(
                ratio >= CLAIM_QUALITY_FRACTION - 1e-12
                and candidates <= CLAIM_CANDIDATE_FRACTION + 1e-12
            ),
        }

    def describe(self) -> str:
        """Return a few lines on the object, the gripper and the contact model."""
        target, hand, settings = self.target, self.gripper, self.settings
        size = target.diameter
        com = ', '.join(f'{v:.4g}' for v in target.center_of_mass)
        return '\n'.join(
            [
                f'{self.name}: {len(target.vertices)} vertices, {len(target.triangles)} '
                f'triangles, diameter D = {size:.4g} (mesh units), '
                f'{"closed" if target.closed else "open"} mesh',
                f'centre of mass ({target.com_method}) = ({com}); torque scale rho = '
                f'{target.radius:.4g}',
                f'gripper: opening {hand.max_width:.4g} ({hand.max_width / size:.2f} D), '
                f'finger depth {hand.finger_depth:.4g} ({hand.finger_depth / size:.2f} D), '
                f'finger width {hand.finger_width:.4g}, retreat {hand.retreat:.4g}',
                f'contacts: {"soft fingers" if settings.get("contact_radius") else "hard"}, '
                f'mu = {settings.get("friction")}, '
                f'{settings.get("cone_edges")} cone edges, contact radius '
                f'{settings.get("contact_radius"):.4g}; standoff {settings.get("standoff"):.4g}; '
                f'{settings.get("points")} points for the boxes',
            ]
        )

    def to_dict(self) -> dict[str, Any]:
        """Return a JSON-ready record: object, gripper, settings and the summary rows."""
        target = self.target
        return {
            'name': self.name,
            'object': {
                'vertices': len(target.vertices),
                'triangles': len(target.triangles),
                'closed': target.closed,
                'center_of_mass': [float(v) for v in target.center_of_mass],
                'center_of_mass_method': target.com_method,
                'radius': target.radius,
                'diameter': target.diameter,
            },
            'gripper': asdict(self.gripper),
            'settings': dict(self.settings),
            'sets': self.summary(),
        }

    def grasp_geometry(self, result: GraspSetResult, index: int) -> dict[str, float]:
        """
        Describe a grasped candidate's contacts, relative to the object's radius rho.

        :param result: one of this comparison's sets.
        :param index: a candidate of that set with two contacts.
        :return: ``separation`` (contact distance / rho), ``offset`` (distance from the centre
            of mass to the contact line / rho) and ``angle_deg`` (the larger angle between a
            contact normal and the contact line: 0 is perfectly antipodal).
        """
        contacts = result.evaluation.contacts[index]
        normals = result.evaluation.normals[index]
        line = contacts[1] - contacts[0]
        length = float(np.linalg.norm(line))
        unit = line / length if length > 0.0 else line
        arm = self.target.center_of_mass - contacts[0]
        offset = float(np.linalg.norm(arm - (arm @ unit) * unit))
        cosines = np.clip([normals[0] @ unit, -(normals[1] @ unit)], -1.0, 1.0)
        return {
            'separation': length / self.target.radius,
            'offset': offset / self.target.radius,
            'angle_deg': float(np.degrees(np.arccos(cosines.min()))),
        }

    def summary(self) -> list[dict[str, Any]]:
        """Return one JSON-ready row per set (what the table shows, and more)."""
        spherical = self.spherical
        target_eps = (
            CLAIM_QUALITY_FRACTION * spherical.best_epsilon()
            if spherical is not None and spherical.best_epsilon() > 0.0
            else None
        )
        rows = []
        for result in self.sets:
            best = result.best_index
            row: dict[str, Any] = {
                'set': result.name,
                'boxes': result.boxes,
                'candidates': result.candidates,
                'force_closure': int(result.evaluation.force_closure.sum()),
                'force_closure_rate': result.force_closure_rate(),
                'best_epsilon': result.best_epsilon(),
                'best_volume': None if best is None else float(result.evaluation.volume[best]),
                'median_epsilon': result.median_epsilon(),
                'median_epsilon_fc': result.median_epsilon(force_closure_only=True),
                'generate_seconds': result.generate_seconds,
                'evaluate_seconds': result.evaluation.seconds,
                'status': result.evaluation.status_counts(),
                'best_grasp': None if best is None else self.grasp_geometry(result, best),
            }
            if target_eps is not None:
                if result.name == 'spherical':
                    # Expected draws, in random order without replacement, to the first success.
                    hits = int(np.count_nonzero(result.evaluation.epsilon >= target_eps))
                    row['to_90'] = (result.candidates + 1) / (hits + 1)
                else:
                    row['to_90'] = result.first_reaching(target_eps)
                    row.update(self.claim(result))
            if spherical is not None and result is not spherical:
                row['spherical_same_budget'] = expected_best_of(
                    spherical.evaluation.epsilon, result.candidates
                )
            rows.append(row)
        return rows


def compare_grasp_sets(
    mesh: Any,
    points: ArrayLike | None = None,
    *,
    name: str = 'object',
    gripper: ParallelJawGripper | None = None,
    thresholds: Sequence[float] = PAPER_THRESHOLDS,
    spherical_step: float | None = DEFAULT_SPHERICAL_STEP_DEG,
    friction: float = DEFAULT_FRICTION,
    cone_edges: int = DEFAULT_CONE_EDGES,
    contact_radius: float | None = None,
    standoff: float | None = None,
    min_points: int | None = None,
    seed: int = 0,
    closure_prefilter: bool = True,
    refine: bool = False,
    surface: ArrayLike | None = None,
    progress: Any = None,
) -> QualityComparison:
    """
    Run the Figure 6 experiment on one object.

    Candidates: the spherical grasps (sphere radius = the object's radius plus `standoff`), the
    24 face grasps of the root box of `points`, and the face grasps of the decomposition of
    `points` at each threshold (occluded faces removed; no width filter bites, the gripper
    spans the object). Every set is scored with the same gripper and contact model.

    :param mesh: the object's mesh (anything :meth:`GraspTarget.from_mesh` accepts).
    :param points: (N, 3) points to fit boxes to (default the mesh's vertices; the paper used
        the model vertices).
    :param name: the object's name for reports.
    :param gripper: default :meth:`ParallelJawGripper.for_object` of the mesh's diameter.
    :param thresholds: gain thresholds t of the decompositions.
    :param spherical_step: spherical grid step in degrees; None skips the baseline.
    :param friction: Coulomb friction coefficient.
    :param cone_edges: friction cone edges.
    :param contact_radius: soft-contact radius (default a quarter finger width).
    :param standoff: pre-grasp distance off the faces and the sphere (default 5 % of the
        object's diameter).
    :param min_points: the decomposition's ``min_points`` (default its own default).
    :param seed: the box fit's random seed.
    :param closure_prefilter: skip the hulls of grasps proven not force-closure (their V is
        NaN; see :func:`~mvbb_ros.evaluation.simulation.evaluate_grasps`), default True.
    :param refine: also score each decomposition's hypotheses refined on `points`
        (:func:`refined_hypotheses`) on `surface`, as the sets ``refined t=...``.
    :param surface: (M, 3) an even sample of the object's surface for the refinement (a
        complete scan; the model vertices are too uneven: the GraspIt! models are rings up to a
        tenth of their size apart); default `points`.
    :param progress: optional callable taking a message string.
    :return: the comparison.
    """

    def say(message: str) -> None:
        if progress is not None:
            progress(message)

    target = GraspTarget.from_mesh(mesh)
    hand = gripper or ParallelJawGripper.for_object(target.diameter)
    cloud = target.vertices if points is None else np.asarray(points, dtype=np.float64)
    off = 0.05 * target.diameter if standoff is None else float(standoff)
    quality: dict[str, Any] = {
        'friction': friction,
        'cone_edges': cone_edges,
        'contact_radius': contact_radius,
        'closure_prefilter': closure_prefilter,
    }
    comparison = QualityComparison(
        name=name,
        target=target,
        gripper=hand,
        settings={
            **quality,
            'contact_radius': (
                hand.default_contact_radius() if contact_radius is None else contact_radius
            ),
            'spherical_step': spherical_step,
            'standoff': off,
            'points': len(cloud),
        },
    )
    hypothesis_options: dict[str, Any] = {'gripper_max_width': hand.max_width, 'standoff': off}

    if spherical_step is not None:
        started = time.perf_counter()
        sphere = spherical_grasps(target.center_of_mass, target.radius + off, spherical_step)
        generated = time.perf_counter() - started
        say(f'{name}: {len(sphere)} spherical grasps ...')
        evaluation = evaluate_grasps(target, sphere.arrays(), gripper=hand, **quality)
        comparison.sets.append(GraspSetResult('spherical', evaluation, None, generated))

    started = time.perf_counter()
    root = minimum_bounding_box(cloud, seed=seed)
    grasps = grasp_hypotheses([root], **hypothesis_options)
    generated = time.perf_counter() - started
    say(f'{name}: root box, {len(grasps)} grasps ...')
    evaluation = evaluate_grasps(target, grasps, gripper=hand, **quality)
    comparison.sets.append(GraspSetResult('root box', evaluation, 1, generated))

    for threshold in thresholds:
        started = time.perf_counter()
        options: dict[str, Any] = {'gain_threshold': float(threshold), 'seed': seed}
        if min_points is not None:
            options['min_points'] = min_points
        decomposition = decompose(cloud, **options)
        grasps = grasp_hypotheses(decomposition, **hypothesis_options)
        generated = time.perf_counter() - started
        say(f'{name}: t = {threshold:g}, {len(decomposition.leaves)} boxes, {len(grasps)} grasps')
        evaluation = evaluate_grasps(target, grasps, gripper=hand, **quality)
        comparison.sets.append(
            GraspSetResult(
                f't={threshold:.2f}',
                evaluation,
                len(decomposition.leaves),
                generated,
                gain_threshold=float(threshold),
            )
        )
        if refine:
            started = time.perf_counter()
            scan = cloud if surface is None else np.asarray(surface, dtype=np.float64)
            refined = refined_hypotheses(scan, decomposition.leaves, grasps, hand, off, friction)
            generated += time.perf_counter() - started
            say(f'{name}: t = {threshold:g}, {len(refined)} refined grasps')
            evaluation = evaluate_grasps(target, refined, gripper=hand, **quality)
            comparison.sets.append(
                GraspSetResult(
                    f'refined t={threshold:.2f}',
                    evaluation,
                    len(decomposition.leaves),
                    generated,
                    gain_threshold=float(threshold),
                )
            )
    return comparison


#: Refined Figure 6 sets keep at most this many grasps (under 1 % of the 22104 spherical ones).
REFINED_MAX_GRASPS = 200


def refined_hypotheses(
    points: ArrayLike,
    boxes: Sequence[Any],
    seeds: Sequence[Grasp],
    gripper: ParallelJawGripper,
    standoff: float,
    friction: float = DEFAULT_FRICTION,
    max_grasps: int = REFINED_MAX_GRASPS,
) -> list[Grasp]:
    """
    Return the hypotheses refined on a whole object's points with this experiment's gripper.

    :func:`~mvbb_ros.geometry.grasping.refine.refine_grasps` on the surface of `points` (cells of
    their median neighbour spacing), with the simulator's hand: pads as wide as its fingers,
    closing where it closes (half the finger depth past the palm's contact, less the retreat), the
    opening of the gripper, no support and no viewpoint (the points are the whole object).

    :param points: (N, 3) an even sample of the object's surface.
    :param boxes: the decomposition's leaves.
    :param seeds: their hypotheses (:func:`grasp_hypotheses`).
    :param gripper: the experiment's gripper.
    :param standoff: the pre-grasp distance.
    :param friction: mu.
    :param max_grasps: at most this many, best first.
    :return: the refined grasps, best first.
    """
    cloud = np.asarray(points, dtype=np.float64)
    distances, _ = cKDTree(cloud).query(cloud, k=2)
    cell = float(np.median(distances[:, 1]))
    model = surface_model(cloud, cell=cell)
    close_at = gripper.finger_depth / 2.0 - gripper.retreat
    settings = RefinementSettings(
        enabled=True,
        friction=friction,
        pad_size=max(gripper.finger_width, 2.0 * cell),
        finger_depth=close_at,
        depth_fractions=(1.0,),
        width_margin=0.0,
    )
    view = GraspView(gripper_max_width=gripper.max_width, standoff=standoff, max_grasps=max_grasps)
    return refine_grasps(seeds, list(boxes), [0] * len(boxes), [model], settings, view).grasps

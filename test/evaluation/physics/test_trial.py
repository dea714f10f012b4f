"""
The physics trial's known answers (issue 36): a held box lifts, misses and collisions are named.

A handful of objects, each trial a fraction of a second in MuJoCo: boxes with known sizes, an
L-shaped block for the convex decomposition, and a few of pybullet_data's random objects.
"""

from __future__ import annotations

from dataclasses import replace
import math

import mujoco
from mvbb_ros.evaluation.physics import (
    convex_parts,
    FRANKA,
    Hand,
    mesh_folder_objects,
    PhysicsObject,
    random_object,
    random_object_split,
    settle,
    STAGES,
    try_grasp,
    try_grasps,
    WIDE,
)
from mvbb_ros.evaluation.physics.grasps import footprint_rectangle, top_down_grasp
from mvbb_ros.evaluation.physics.model import build_scene
from mvbb_ros.evaluation.physics.objects import (
    hull_of,
    mesh_volume,
    RANDOM_LENGTH_RANGE,
    random_scale,
    union_volume,
)
from mvbb_ros.evaluation.physics.trial import DEFAULT_SETTINGS, place_object, TrialSettings
import numpy as np
import pytest


def _box(size: tuple[float, float, float], name: str = 'box') -> PhysicsObject:
    corners = np.array(
        [[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float
    ) * (np.asarray(size) / 2.0)
    vertices, triangles = hull_of(corners)
    return PhysicsObject(name, vertices, triangles, ((vertices, triangles),))


def _standing(obj: PhysicsObject) -> np.ndarray:
    """Return the object's pose with its own axes, resting on the table (bottom at z = 0)."""
    pose = np.eye(4)
    pose[2, 3] = -float(obj.vertices[:, 2].min())
    return pose


def _grasp(approach, closing, origin) -> np.ndarray:
    """Return a grasp pose from its approach (z) and closing (y) directions and its origin."""
    z = np.asarray(approach, dtype=float)
    y = np.asarray(closing, dtype=float)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    pose[:3, 3] = origin
    return pose


BOX = _box((0.06, 0.06, 0.10))
#: Fingertips 2 cm below the top of the box, closing across x; and from the side at mid height.
TOP_DOWN = _grasp([0, 0, -1], [1, 0, 0], [0.0, 0.0, 0.08])
FROM_SIDE = _grasp([1, 0, 0], [0, 1, 0], [0.0, 0.0, 0.05])


def test_a_box_grasped_across_two_faces_lifts_from_above_and_from_the_side():
    results = try_grasps(BOX, _standing(BOX), np.stack([TOP_DOWN, FROM_SIDE]), FRANKA)
    for result in results:
        assert result.success and result.stage == 'lifted', result
        # The pads closed on the 6 cm faces and the box rose with the hand.
        assert result.gap == pytest.approx(0.06, abs=0.003)
        assert result.rise == pytest.approx(DEFAULT_SETTINGS.lift_height, abs=0.01)
        assert result.displacement < 0.002


def test_a_light_object_in_the_full_grip_keeps_the_pads_out_and_is_lifted():
    # 4 x 4 x 1.5 cm at the default density: 12 g under the hand's 70 N a finger.
    light = _box((0.04, 0.04, 0.015), 'light')
    assert light.mass < 0.015
    grasp = _grasp([0, 0, -1], [1, 0, 0], [0.0, 0.0, 0.008])
    result = try_grasp(light, _standing(light), grasp, FRANKA)
    assert result.success, result
    assert 0.0 < result.penetration < 0.0005, result
    # A heavy box's pads sink no deeper: the contact's rigidity does not hang on the mass.
    heavy = try_grasp(BOX, _standing(BOX), TOP_DOWN, FRANKA)
    assert 0.0 < heavy.penetration < 0.0005, heavy
    # The engine's step sets it: at 2 ms the same grip sinks the pads millimetres deep.
    coarse = try_grasp(
        light, _standing(light), grasp, FRANKA, replace(DEFAULT_SETTINGS, timestep=0.002)
    )
    assert coarse.penetration > 0.001, coarse


def test_the_no_slip_pass_keeps_a_held_box_still_and_lets_a_slippery_one_slide_out():
    # The 180 g box in the full grip, friction 0.75: it rides with the hand, not creeping.
    held = try_grasp(BOX, _standing(BOX), TOP_DOWN, FRANKA)
    assert held.success and held.rise == pytest.approx(DEFAULT_SETTINGS.lift_height, abs=0.002)
    # Friction 0.005: two pads carry at most 0.7 N of its 1.8 N weight; it slides out.
    slippery = replace(DEFAULT_SETTINGS, friction=0.005)
    result = try_grasp(BOX, _standing(BOX), TOP_DOWN, FRANKA, slippery)
    assert result.stage == 'slipped' and result.rise < 0.02, result


def test_the_same_grasp_5_cm_beside_the_box_misses():
    beside = TOP_DOWN.copy()
    beside[:3, 3] += 0.05 * TOP_DOWN[:3, 0]  # along the pads' width: they close on air
    result = try_grasp(BOX, _standing(BOX), beside, FRANKA)
    assert not result.success and result.stage == 'missed', result
    assert result.gap < 0.005 and abs(result.rise) < 0.002
    # 5 cm along the closing direction a finger comes down on the top of the box.
    across = TOP_DOWN.copy()
    across[:3, 3] += 0.05 * TOP_DOWN[:3, 1]
    assert try_grasp(BOX, _standing(BOX), across, FRANKA).stage == 'collision'


def test_fingers_driven_through_the_table_collide():
    flat = _box((0.06, 0.06, 0.03), 'flat')
    # Fingertips aimed 1 cm under the table top: they pass the box and meet the table.
    below = _grasp([0, 0, -1], [1, 0, 0], [0.0, 0.0, -0.01])
    result = try_grasp(flat, _standing(flat), below, FRANKA)
    assert result.stage == 'collision' and 'table' in result.detail, result
    # A side grasp whose fingers start under the table top fails before it moves.
    low_side = _grasp([1, 0, 0], [0, 1, 0], [0.0, 0.0, 0.002])
    result = try_grasp(flat, _standing(flat), low_side, FRANKA)
    assert result.stage == 'collision' and 'table' in result.detail, result


def test_an_object_wider_than_the_opening_fails_and_lifts_with_the_wide_hand():
    wide = _box((0.10, 0.10, 0.10), 'cube')
    grasp = _grasp([0, 0, -1], [1, 0, 0], [0.0, 0.0, 0.08])
    narrow = try_grasp(wide, _standing(wide), grasp, FRANKA)
    assert not narrow.success and narrow.stage == 'collision', narrow
    held = try_grasp(wide, _standing(wide), grasp, WIDE)
    assert held.success, held
    # An opening narrower than the box (the width argument) also stops on its top.
    assert try_grasp(BOX, _standing(BOX), TOP_DOWN, FRANKA, width=0.05).stage == 'collision'


def test_a_hand_inside_the_object_at_the_pre_grasp_pose_collides():
    deep = _grasp([0, 0, -1], [1, 0, 0], [0.0, 0.0, 0.0])
    shallow_standoff = TrialSettings(standoff=0.02)
    result = try_grasp(BOX, _standing(BOX), deep, FRANKA, shallow_standoff)
    assert result.stage == 'collision' and 'pre-grasp' in result.detail, result


UNTIL_CONTACT = TrialSettings(approach='until_contact')


def test_until_contact_closes_where_the_paper_hand_stopped_and_to_pose_where_it_was_sent():
    # The paper's face-centre pose: fingertips at the centre of the box's top face.
    face = _grasp([0, 0, -1], [1, 0, 0], [0.0, 0.0, 0.10])
    sent = try_grasp(BOX, _standing(BOX), face, FRANKA)
    assert sent.stage == 'missed' and sent.advance == 0.0, sent
    # Until contact: the 6 cm box passes between the open fingers, the palm meets its top, the
    # hand backs off `contact_retreat` and the fingers close finger_depth - retreat below it.
    guarded = try_grasp(BOX, _standing(BOX), face, FRANKA, UNTIL_CONTACT)
    assert guarded.success, guarded
    expected = FRANKA.finger_depth - UNTIL_CONTACT.contact_retreat
    assert guarded.advance == pytest.approx(expected, abs=0.002)
    assert guarded.gap == pytest.approx(0.06, abs=0.003)
    # A 10 cm cube is wider than the 8 cm opening: a fingertip meets its top, the hand backs
    # off and the pads close on air above it.
    cube = _box((0.10, 0.10, 0.10), 'cube')
    stopped = try_grasp(cube, _standing(cube), face, FRANKA, UNTIL_CONTACT)
    assert stopped.stage == 'missed', stopped
    assert stopped.advance == pytest.approx(-UNTIL_CONTACT.contact_retreat, abs=0.002)
    # The table still stops a hand that meets it before the object.
    flat = _box((0.06, 0.06, 0.03), 'flat')
    low_side = _grasp([1, 0, 0], [0, 1, 0], [-0.03, 0.0, 0.008])
    result = try_grasp(flat, _standing(flat), low_side, FRANKA, UNTIL_CONTACT)
    assert result.stage == 'collision' and 'table' in result.detail, result
    with pytest.raises(ValueError, match='approach'):
        TrialSettings(approach='sideways')  # type: ignore[arg-type]


def test_same_inputs_same_verdicts_and_batch_equals_one_at_a_time():
    obj = random_object(5)
    pose = settle(obj, seed=3)
    grasp = top_down_grasp(obj, pose)
    grasps = np.stack([grasp, TOP_DOWN, FROM_SIDE])
    first = try_grasps(obj, pose, grasps)
    second = try_grasps(obj, pose, grasps)
    alone = [try_grasp(obj, pose, g) for g in grasps]
    for a, b, c in zip(first, second, alone, strict=True):
        assert a.stage in STAGES
        assert (a.stage, a.gap, a.rise, a.displacement) == (b.stage, b.gap, b.rise, b.displacement)
        assert (a.stage, a.rise) == (c.stage, c.rise)


def test_settle_leaves_the_object_at_rest_on_the_table_and_repeats_for_a_seed():
    obj = random_object(17)
    pose = settle(obj, seed=1)
    assert np.array_equal(pose, settle(obj, seed=1))
    assert not np.allclose(pose[:3, :3], settle(obj, seed=2)[:3, :3])
    world = obj.vertices @ pose[:3, :3].T + pose[:3, 3]
    assert abs(world[:, 2].min()) < 0.001  # lowest point on the table top
    centre = (world.min(axis=0) + world.max(axis=0)) / 2.0
    assert np.allclose(centre[:2], 0.0, atol=1e-9)
    # Let go there again: it stays put and still.
    scene = build_scene(obj, None, DEFAULT_SETTINGS.options)
    place_object(scene, pose)
    for _ in range(250):
        mujoco.mj_step(scene.model, scene.data)
    assert np.linalg.norm(scene.data.xpos[scene.object_body] - pose[:3, 3]) < 0.002
    speed = scene.data.cvel[scene.object_body][3:]
    assert np.linalg.norm(speed) < 0.01


def _l_block(height: float = 0.03) -> tuple[np.ndarray, np.ndarray]:
    """Return a closed, outward L-shaped prism: 8 x 2 cm and 2 x 4 cm legs, `height` tall."""
    outline = np.array([(0, 0), (8, 0), (8, 2), (2, 2), (2, 6), (0, 6)], dtype=float) * 0.01
    count = len(outline)
    vertices = np.vstack([np.c_[outline, np.zeros(count)], np.c_[outline, np.full(count, height)]])
    fan = [(3, 4, 5), (3, 5, 0), (3, 0, 1), (3, 1, 2)]  # from the reflex corner, counter-clockwise
    triangles = [(a, c, b) for a, b, c in fan] + [
        (a + count, b + count, c + count) for a, b, c in fan
    ]
    for i in range(count):
        j = (i + 1) % count
        triangles += [(i, j, j + count), (i, j + count, i + count)]
    return vertices, np.array(triangles)


def test_convex_parts_of_an_l_block_fill_it_and_come_back_from_the_cache(tmp_path):
    vertices, triangles = _l_block()
    volume = mesh_volume(vertices, triangles)
    assert volume == pytest.approx((8 * 2 + 2 * 4) * 1e-4 * 0.03)
    parts = convex_parts(vertices, triangles, tmp_path)
    assert len(parts) >= 2
    # The union of the parts is the L (its hull would be a third bigger).
    assert union_volume(parts) == pytest.approx(volume, rel=0.05)
    assert union_volume((hull_of(vertices),)) > 1.3 * volume
    cached = list(tmp_path.glob('*.npz'))
    assert len(cached) == 1
    again = convex_parts(vertices, triangles, tmp_path)
    assert len(again) == len(parts)
    for (v1, t1), (v2, t2) in zip(parts, again, strict=True):
        assert np.array_equal(v1, v2) and np.array_equal(t1, t2)
    # A convex mesh is its own hull and needs no cache entry.
    box = convex_parts(BOX.vertices, BOX.triangles, tmp_path / 'convex')
    assert len(box) == 1 and not (tmp_path / 'convex').exists()


def test_random_objects_span_household_sizes_and_split_by_number():
    assert [random_object_split(i) for i in (0, 499, 500, 999)] == [
        'development',
        'development',
        'validation',
        'validation',
    ]
    for wrong in (-1, 1000):
        with pytest.raises(ValueError):
            random_object_split(wrong)
    low, high = RANDOM_LENGTH_RANGE
    lengths = np.array([random_scale(i) for i in range(1000)])
    assert low <= lengths.min() and lengths.max() <= high
    # Uniform: each quarter of the range holds about a quarter of the objects.
    counts = np.histogram(lengths, bins=4, range=(low, high))[0]
    assert np.all(np.abs(counts - 250) < 60), counts
    for index in (0, 123, 777):
        obj = random_object(index)
        assert obj.extent.max() == pytest.approx(random_scale(index))
        assert obj.name == f'random_{index:03d}' and len(obj.parts) >= 1
        assert 0.0 < obj.volume <= np.prod(obj.extent)
    assert random_object(3, seed=1).extent.max() != pytest.approx(random_object(3).extent.max())


def test_a_mesh_folder_in_millimetres_gives_objects_in_metres(tmp_path):
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(BOX.vertices * 1000.0),
        o3d.utility.Vector3iVector(BOX.triangles.astype(np.int32)),
    )
    o3d.io.write_triangle_mesh(str(tmp_path / 'box.stl'), mesh.compute_triangle_normals())
    (tmp_path / 'notes.txt').write_text('not a mesh')
    objects = mesh_folder_objects(tmp_path, 'mm', cache_dir=tmp_path / 'cache')
    assert [obj.name for obj in objects] == ['box']
    assert np.allclose(objects[0].extent, [0.06, 0.06, 0.10])
    assert objects[0].mass == pytest.approx(0.06 * 0.06 * 0.10 * objects[0].density, rel=0.02)
    with pytest.raises(ValueError):
        mesh_folder_objects(tmp_path, 'inch')  # type: ignore[arg-type]


def test_the_footprint_rectangle_and_the_top_down_grasp_close_across_the_narrow_side():
    angle = math.radians(30.0)
    axes = np.array([[math.cos(angle), math.sin(angle)], [-math.sin(angle), math.cos(angle)]])
    corners = np.array([[x, y] for x in (-0.05, 0.05) for y in (-0.02, 0.02)]) @ axes + [0.1, 0.2]
    centre, found, sizes = footprint_rectangle(corners)
    assert np.allclose(centre, [0.1, 0.2]) and np.allclose(sizes, [0.04, 0.10])
    assert abs(found[0] @ axes[1]) == pytest.approx(1.0)
    slab = _box((0.10, 0.04, 0.05), 'slab')
    grasp = top_down_grasp(slab, _standing(slab))
    assert abs(grasp[:3, 1] @ [0, 1, 0]) == pytest.approx(1.0)  # closes across the 4 cm side
    assert np.allclose(grasp[:3, 2], [0, 0, -1])
    assert try_grasp(slab, _standing(slab), grasp).success


def test_hands_are_checked():
    assert WIDE.max_opening == pytest.approx(0.14) and FRANKA.max_opening == pytest.approx(0.08)
    with pytest.raises(ValueError):
        Hand(max_opening=0.3)  # wider than the palm
    with pytest.raises(ValueError):
        try_grasp(BOX, np.eye(3), TOP_DOWN)
    with pytest.raises(ValueError, match='units'):
        settle(_box((1.0, 0.06, 0.06), 'metres given as millimetres'), seed=0)

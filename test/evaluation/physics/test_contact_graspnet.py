"""
The Contact-GraspNet contender: its pose conversion, its failures, and the real network end to end.

The conversion and the error tests need no torch. The end-to-end tests run the real server in
``.venv-cgn`` and skip, saying how to make it, when that environment is absent (CI does not build
it: tools/cgn/make_venv.sh).
"""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

from hypothesis import given, settings
from hypothesis import strategies as st
from mvbb_ros.evaluation.physics.contact_graspnet import (
    cgn_to_grasp_pose,
    CONTACT_DEPTH_M,
    ContactGraspNet,
    ContactGraspNetUnavailable,
    DEFAULT_PYTHON,
    grasp_pose_to_cgn,
    Proposal,
)
import numpy as np
import pytest
from support.data import REPO_ROOT

CGN_PYTHON = REPO_ROOT / '.venv-cgn' / 'bin' / 'python'
needs_venv = pytest.mark.skipif(
    not CGN_PYTHON.exists(),
    reason='no .venv-cgn: run tools/cgn/make_venv.sh to test Contact-GraspNet end to end',
)


def cgn_transform(contact, baseline, approach, width):
    """Build a grasp transform the way cgn-pytorch does (build_6d_grasps), from its parts."""
    b = np.asarray(baseline, float) / np.linalg.norm(baseline)
    a = np.asarray(approach, float)
    a = a - np.dot(a, b) * b
    a /= np.linalg.norm(a)
    transform = np.eye(4)
    transform[:3, 0], transform[:3, 1], transform[:3, 2] = b, np.cross(a, b), a
    transform[:3, 3] = np.asarray(contact, float) + width / 2 * b - CONTACT_DEPTH_M * a
    return transform


def test_a_top_down_cgn_grasp_converts_to_the_expected_pose():
    # contact on the -x finger at (0.1, 0.2, 0.05), fingers closing along +x, hand coming down,
    # 4 cm wide: the fingertip centre is 2 cm along +x from the contact.
    transform = cgn_transform((0.1, 0.2, 0.05), (1, 0, 0), (0, 0, -1), 0.04)
    pose = cgn_to_grasp_pose(transform)
    np.testing.assert_allclose(pose[:3, 3], [0.12, 0.2, 0.05], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 2], [0, 0, -1], atol=1e-12)  # approach: downwards
    np.testing.assert_allclose(pose[:3, 1], [1, 0, 0], atol=1e-12)  # closing: along x
    np.testing.assert_allclose(pose[:3, 0], [0, 1, 0], atol=1e-12)  # x = y cross z
    np.testing.assert_allclose(pose[3], [0, 0, 0, 1])


def test_the_conversion_takes_batches_and_refuses_other_shapes():
    transforms = np.stack([cgn_transform((0, 0, k), (0, 1, 0), (1, 0, 0), 0.01) for k in range(3)])
    poses = cgn_to_grasp_pose(transforms)
    assert poses.shape == (3, 4, 4)
    np.testing.assert_allclose(poses[:, 2, 3], [0, 1, 2])
    with pytest.raises(ValueError, match=r'\(\.\.\., 4, 4\)'):
        cgn_to_grasp_pose(np.eye(3))
    with pytest.raises(ValueError, match=r'\(\.\.\., 4, 4\)'):
        grasp_pose_to_cgn(np.zeros((2, 4, 3)))


unit = st.floats(-1.0, 1.0, allow_nan=False)
vectors = st.tuples(unit, unit, unit).filter(lambda v: np.linalg.norm(v) > 0.1)


@settings(max_examples=200, deadline=None)
@given(
    contact=st.tuples(unit, unit, unit),
    baseline=vectors,
    approach=vectors,
    width=st.floats(0.0, 0.08),
)
def test_a_cgn_grasp_becomes_a_right_handed_pose_between_the_fingertips(
    contact, baseline, approach, width
):
    b = np.asarray(baseline) / np.linalg.norm(baseline)
    a = np.asarray(approach, float)
    if np.linalg.norm(a - np.dot(a, b) * b) < 0.1:
        return  # approach (nearly) along the baseline: no grasp frame
    transform = cgn_transform(contact, baseline, approach, width)
    pose = cgn_to_grasp_pose(transform)
    rotation = pose[:3, :3]
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-9)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(pose[:3, 2], transform[:3, 2], atol=1e-12)  # approach kept
    np.testing.assert_allclose(pose[:3, 1], b, atol=1e-9)  # closes along the baseline
    np.testing.assert_allclose(np.cross(pose[:3, 1], pose[:3, 2]), pose[:3, 0], atol=1e-9)
    # the origin: the contact plus half the width along the closing direction
    np.testing.assert_allclose(pose[:3, 3], np.asarray(contact) + width / 2 * b, atol=1e-9)
    np.testing.assert_allclose(grasp_pose_to_cgn(pose), transform, atol=1e-9)


quaternions = st.tuples(unit, unit, unit, unit).filter(lambda q: np.linalg.norm(q) > 0.1)


@settings(max_examples=200, deadline=None)
@given(q=quaternions, t=st.tuples(unit, unit, unit))
def test_our_pose_survives_a_round_trip_through_cgns_convention(q, t):
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, t
    transform = grasp_pose_to_cgn(pose)
    # cgn's frame: fingers close along its x (our y), its origin 0.1034 m back along the approach
    np.testing.assert_allclose(transform[:3, 0], pose[:3, 1], atol=1e-12)
    np.testing.assert_allclose(transform[:3, 3] + CONTACT_DEPTH_M * pose[:3, 2], t, atol=1e-12)
    np.testing.assert_allclose(cgn_to_grasp_pose(transform), pose, atol=1e-12)


def test_a_missing_environment_says_how_to_make_it(tmp_path):
    with pytest.raises(ContactGraspNetUnavailable, match=r'run tools/cgn/make_venv\.sh'):
        ContactGraspNet(tmp_path / 'no-venv' / 'bin' / 'python')
    assert DEFAULT_PYTHON == CGN_PYTHON


def test_a_python_without_torch_fails_at_start_with_the_servers_own_words():
    """The project's Python has no torch: the server dies, and the error quotes its log."""
    cgn = ContactGraspNet(Path(sys.executable), start_timeout_s=120)
    with pytest.raises(ContactGraspNetUnavailable, match='exited at start') as caught:
        cgn.start()
    assert "No module named 'torch'" in str(caught.value)
    cgn.close()


def test_bad_points_are_refused_before_any_server_starts():
    cgn = ContactGraspNet(Path(sys.executable))
    with pytest.raises(ValueError, match=r'scene_points must be \(N, 3\)'):
        cgn.grasps(np.zeros((10, 2)))
    with pytest.raises(ValueError, match='object_points holds non-finite'):
        cgn.grasps(np.zeros((10, 3)), np.full((4, 3), np.nan))
    assert cgn._process is None


@pytest.mark.slow
def test_the_adapter_keeps_torch_out_of_the_package():
    probe = (
        'import sys, mvbb_ros.evaluation.physics.contact_graspnet; '
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'cgn_pytorch')))"
    )
    result = subprocess.run(
        [sys.executable, '-c', probe], cwd=REPO_ROOT, capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == '[]'
    for name in ('requirements.txt', 'constraints.txt'):
        lines = (REPO_ROOT / name).read_text().lower().splitlines()
        assert not [line for line in lines if line.startswith(('torch', 'cgn'))], name


def example_scene() -> tuple[np.ndarray, np.ndarray]:
    """Return the first cloud of cgn-pytorch's scene 005274 (z-up, centred), its object."""
    found = sorted(CGN_PYTHON.parents[1].glob('lib/python*/site-packages/cgn_pytorch/scenes'))
    assert found, 'cgn_pytorch in .venv-cgn ships no scenes folder'
    with np.load(found[0] / '005274.npz') as data:
        cloud = data['arr_0'][0].astype(np.float64)
        mask = data['arr_2'][:, 0].astype(bool)
    return cloud, cloud[mask]


@pytest.mark.slow
@needs_venv
def test_the_network_grasps_the_object_of_its_own_example_scene_the_same_way_twice():
    cloud, target = example_scene()
    cloud_before, target_before = cloud.copy(), target.copy()
    with ContactGraspNet(threads=1) as cgn:
        first = cgn.grasps(cloud, target, max_grasps=5)
        again = cgn.grasps(cloud, target, max_grasps=5)
        anywhere = cgn.grasps(cloud, max_grasps=3)
    assert len(first) == 5 and all(isinstance(p, Proposal) for p in first)
    scores = [p.score for p in first]
    assert scores == sorted(scores, reverse=True) and scores[-1] > 0.5
    for proposal in first:
        rotation = proposal.pose[:3, :3]
        np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-5)
        assert 0.0 <= proposal.width <= 0.08
        # between the fingertips: within 2 cm of the object; the hand comes from above
        assert np.min(np.linalg.norm(target - proposal.pose[:3, 3], axis=1)) < 0.02
        assert proposal.pose[2, 2] < 0.0
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a.pose, b.pose)
        assert (a.width, a.score) == (b.width, b.score)
    assert 1 <= len(anywhere) <= 3
    np.testing.assert_array_equal(cloud, cloud_before)
    np.testing.assert_array_equal(target, target_before)


_STANDIN_CHECK = """
import numpy as np, torch, torch_cluster as tc
rng = np.random.default_rng(3)
x = torch.from_numpy(rng.uniform(-1, 1, (600, 3)).astype(np.float32))
y = x[:50]
d = np.linalg.norm(y.numpy()[:, None] - x.numpy()[None], axis=2)
# radius: the first max_num_neighbors x indices (ascending) closer than r, per y
row, col = tc.radius(x, y, 0.5, max_num_neighbors=7).numpy()
for i in range(50):
    want = np.flatnonzero(d[i] < 0.5)[:7]
    assert list(col[row == i]) == list(want), i
# knn: the k nearest, nearest first
row, col = tc.knn(x, y, 4).numpy()
assert list(row) == [i for i in range(50) for _ in range(4)]
assert np.array_equal(col.reshape(50, 4), np.argsort(d, axis=1, kind='stable')[:, :4])
# fps: each pick is the point farthest from those picked before it
torch.manual_seed(0)
order = tc.fps(x, torch.zeros(600, dtype=torch.long), ratio=0.1).numpy()
assert len(order) == 60 and len(set(order)) == 60
full = np.linalg.norm(x.numpy()[:, None] - x.numpy()[None], axis=2)
for k in range(1, 60):
    gaps = full[:, order[:k]].min(axis=1)
    assert gaps[order[k]] >= gaps.max() - 1e-6, k
# two examples in one batch stay apart
batch = torch.tensor([0] * 300 + [1] * 300)
row, col = tc.knn(x, x, 2, batch, batch).numpy()
assert np.all((row < 300) == (col < 300))
print('stand-ins ok')
"""


@needs_venv
def test_the_torch_cluster_stand_ins_do_what_torch_geometric_expects():
    result = subprocess.run(
        [str(CGN_PYTHON), '-c', _STANDIN_CHECK], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip() == 'stand-ins ok'

"""
The scene stage on real table-top frames and on rendered ones: objects found, table dropped.

    .venv/bin/python benchmarks/scenes.py                 # the three real scenes, 50 rendered
    .venv/bin/python benchmarks/scenes.py --frames 10     # fewer rendered frames
    .venv/bin/python benchmarks/scenes.py --view-edge 0:100 --frames 0 --no-real

Real scenes (the shared ``scenes/*.pcd``, organized 640 x 480): each is processed with the
node's defaults (``support_plane: auto``) and with ``support_plane: none``. Ground truth:
``mosd_learn33.pcd``'s own ``label`` field (1-9 table, 10 k + j a part of object k - 1; the
PCD is LZF-compressed field by field, decoded here), and for the two PCL scenes the shared
segmented scans cut from them (``pcl_kinect_laptop``/``pcl_kinect_box`` from the laptop frame,
``pcl_stereo_mug`` from the stereo scene: the scene's points that are also a scan's points).
Each observed point of a found object takes the label of its nearest raw point. An object is
found when some found object's overlap with it (intersection over union, on the voxel grid's
points) is at least 0.5. A box is on the background when most of its observed points are not
a labelled object (the table, a wall, the floor, or an unlabelled thing). The reference plane
is a strict fit of the same table: Open3D's ``segment_plane`` (5 mm, 5000 iterations) on the
raw points within 3 cm of the found plane, then least squares on its inliers.

Rendered scenes (:func:`mvbb_ros.evaluation.synthetic.table_top_frame`: 1 to 5 objects on a table,
a wall behind it and the floor; 640 x 480 with the depth camera's noise): objects found against
objects placed, the table's normal against the truth, and the share of each box's volume above the
table (sampled; a box with less than 80 % above it reaches into the table).

Objects cut by the view's edge (``--view-edge FIRST:LAST``, :mod:`mvbb_ros.pipeline.view_edge`):
on the real scenes, each object's gap to the view's outline and whether it is cut, by the
label most of its points have; on the rendered frames of those seeds, whole
(:func:`~mvbb_ros.evaluation.synthetic.table_top_frame`) and with the image cut through one
object (:func:`~mvbb_ros.evaluation.synthetic.cut_table_top_frame`), how many objects of each
kind are found cut: labelled objects whose pixels come within 3 pixels of the image's border
("at the border"), the others ("whole"), and objects of the background.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path
import re
import struct
import sys
import time
from typing import Any

from mvbb_ros.cli.cloud_io import load_cloud
from mvbb_ros.evaluation.shared_data import missing, shared_data_folder
from mvbb_ros.evaluation.synthetic import BACKGROUND, cut_table_top_frame, table_top_frame
from mvbb_ros.pipeline.filtering import filter_points
from mvbb_ros.pipeline.process import process_points
from mvbb_ros.pipeline.settings import PipelineSettings
import numpy as np
from scipy.spatial import cKDTree

SHARED_DATA = shared_data_folder()
SCENES = {
    'mosd_learn33': None,
    'pcl_kinect_laptop_box_frame': ('pcl_kinect_laptop', 'pcl_kinect_box'),
    'pcl_table_scene_mug_stereo_textured': ('pcl_stereo_mug',),
}


def lzf_decompress(data: bytes, size: int) -> bytes:
    """Return the LZF-decompressed `data` (`size` bytes out)."""
    out = bytearray()
    i = 0
    while i < len(data):
        control = data[i]
        i += 1
        if control < 32:
            stop = i + control + 1
            out += data[i:stop]
            i = stop
            continue
        length = control >> 5
        if length == 7:
            length += data[i]
            i += 1
        reference = len(out) - ((control & 0x1F) << 8) - data[i] - 1
        i += 1
        length += 2
        stop = reference + length
        if stop <= len(out):
            out += out[reference:stop]
        else:
            for k in range(length):
                out.append(out[reference + k])
    assert len(out) == size, (len(out), size)
    return bytes(out)


def read_labelled_pcd(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Return the finite points (N, 3) and their labels of a binary_compressed PCD."""
    raw = path.read_bytes()
    end = raw.index(b'DATA binary_compressed\n') + len(b'DATA binary_compressed\n')
    header = raw[:end].decode('ascii')
    fields = re.search(r'^FIELDS (.*)$', header, re.M).group(1).split()
    sizes = [int(v) for v in re.search(r'^SIZE (.*)$', header, re.M).group(1).split()]
    count = int(re.search(r'^POINTS (\d+)', header, re.M).group(1))
    start = end + 8
    compressed, size = struct.unpack('<II', raw[end:start])
    stop = start + compressed
    data = lzf_decompress(raw[start:stop], size)
    columns, offset = {}, 0
    for name, width in zip(fields, sizes, strict=True):
        kind = np.uint32 if name in ('label', 'rgba', 'rgb') else np.float32
        columns[name] = np.frombuffer(data, kind, count, offset)
        offset += width * count
    points = np.column_stack([columns['x'], columns['y'], columns['z']]).astype(np.float64)
    finite = np.all(np.isfinite(points), axis=1)
    return points[finite], columns['label'][finite].astype(np.int64)


def scene_truth(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Return a scene's finite points and labels: -1 background, k >= 0 object k."""
    path = SHARED_DATA / 'scenes' / f'{name}.pcd'
    if SCENES[name] is None:
        points, labels = read_labelled_pcd(path)
        return points, np.where(labels >= 10, labels // 10 - 1, -1)
    points = load_cloud(path)
    labels = np.full(len(points), -1)
    tree = cKDTree(points)
    for index, scan in enumerate(SCENES[name]):
        scan_points = np.load(SHARED_DATA / 'scans' / f'{scan}.npy').astype(np.float64)
        distance, nearest = tree.query(scan_points)
        labels[nearest[distance < 1e-6]] = index
    return points, labels


def reference_normal(points: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Return a strict least-squares fit of the plane near (normal, offset), same side up."""
    import open3d as o3d

    near = points[np.abs(points @ normal + offset) <= 0.03]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(near))
    o3d.utility.random.seed(0)
    _, inliers = cloud.segment_plane(0.005, 3, 5000)
    table = near[inliers]
    centred = table - table.mean(axis=0)
    reference = np.linalg.eigh(centred.T @ centred)[1][:, 0]
    return reference if reference @ normal > 0 else -reference


def angle_deg(first: np.ndarray, second: np.ndarray) -> float:
    """Return the angle between two unit vectors in degrees."""
    return float(np.degrees(np.arccos(np.clip(first @ second, -1.0, 1.0))))


def real_scenes() -> None:
    """Print the real scenes' table."""
    print(
        '| scene | support_plane | objects found | labelled objects found (IoU >= 0.5) '
        '| IoU each | boxes | boxes on background | normal vs reference (deg) | ms |'
    )
    print('|---|---|---|---|---|---|---|---|---|')
    for name in SCENES:
        points, labels = scene_truth(name)
        tree = cKDTree(points)
        voxels, _ = filter_points(points, voxel_size=0.005)
        voxel_labels = labels[tree.query(voxels)[1]]
        truth = sorted(set(labels.tolist()) - {-1})
        for mode in ('auto', 'none'):
            settings = PipelineSettings().updated({'support_plane': mode})
            start = time.perf_counter()
            result = process_points(points, settings)
            ms = (time.perf_counter() - start) * 1e3
            found_labels = []
            for item in result.objects:
                observed = item.shape.points[: item.shape.observed]
                found_labels.append(labels[tree.query(observed)[1]])
            ious = []
            for label in truth:
                total = int(np.count_nonzero(voxel_labels == label))
                best = 0.0
                for mine in found_labels:
                    common = int(np.count_nonzero(mine == label))
                    best = max(best, common / (total + len(mine) - common))
                ious.append(best)
            background = 0
            for item in result.objects:
                observed = item.shape.points[: item.shape.observed]
                for indices in item.decomposition.leaf_point_indices:
                    mine = indices[indices < item.shape.observed]
                    point_labels = labels[tree.query(observed[mine])[1]]
                    background += int(np.mean(point_labels == -1) > 0.5) if len(mine) else 0
            angle = '-'
            if result.support is not None:
                reference = reference_normal(points, result.support.normal, result.support.offset)
                angle = f'{angle_deg(result.support.normal, reference):.2f}'
            found = sum(iou >= 0.5 for iou in ious)
            print(
                f'| {name} | {mode} | {len(result.objects)} | {found} of {len(truth)} | '
                f'{" ".join(f"{v:.2f}" for v in ious)} | {len(result.leaves)} | {background} | '
                f'{angle} | {ms:.0f} |'
            )


def rendered_scenes(frames: int) -> None:
    """Print the rendered scenes' summary."""
    settings = PipelineSettings()
    matched = 0
    angles, worst_shares, rows = [], [], Counter()
    below = 0
    for seed in range(frames):
        count = 1 + seed % 5
        frame = table_top_frame(seed, count)
        cloud = frame.points.reshape(-1, 3)
        result = process_points(cloud[np.all(np.isfinite(cloud), axis=1)], settings)
        plane = frame.table_plane
        matched += len(result.objects) == count
        rows[(count, len(result.objects))] += 1
        if result.support is not None:
            angles.append(angle_deg(result.support.normal, plane[:3]))
        for box in result.leaves:
            local = np.random.default_rng(0).uniform(-0.5, 0.5, (4000, 3)) * box.extents
            share = float(np.mean(box.to_world(local) @ plane[:3] + plane[3] > 0.0))
            worst_shares.append(share)
            below += share < 0.8
    print(
        f'rendered frames: {frames}; objects found = objects placed in {matched} '
        f'({100 * matched / frames:.0f} %)'
    )
    print(
        'placed -> found (frames): '
        + ', '.join(f'{p}->{f}: {n}' for (p, f), n in sorted(rows.items()))
    )
    print(
        f'support found in {len(angles)} frames; normal error max {max(angles):.3f} deg, '
        f'median {np.median(angles):.3f} deg'
    )
    print(
        f'boxes: {len(worst_shares)}, with < 80 % of their volume above the table: {below}; '
        f'smallest share above: {min(worst_shares):.3f}'
    )


def object_owners(result: Any, points: np.ndarray, labels: np.ndarray) -> list[int]:
    """Return the label most of each object's observed points come from."""
    tree = cKDTree(points)
    owners = []
    for item in result.objects:
        nearest = tree.query(item.shape.points[: item.shape.observed])[1]
        owners.append(int(np.bincount(labels[nearest] - BACKGROUND).argmax() + BACKGROUND))
    return owners


#: A labelled object whose pixels come this close to the image's border is at the border.
BORDER_PIXELS = 3


def view_edges(first: int, last: int, real: bool) -> None:
    """Print which objects are cut by the view's edge: real scenes, rendered frames."""
    settings = PipelineSettings()
    if real:
        print("| scene | object: label, gap to the view's outline (deg), cut | top grasp on |")
        print('|---|---|---|')
        for name in SCENES:
            points, labels = scene_truth(name)
            result = process_points(points, settings)
            owners = object_owners(result, points, labels)
            cells = [
                f'{item.index}: {owner}, {item.view_edge.gap_deg:.2f}, '
                f'{"cut" if item.cut_by_view else "whole"}'
                for item, owner in zip(result.objects, owners, strict=True)
                if item.view_edge is not None
            ]
            top = result.grasps[0].object_index if result.grasps else None
            print(f'| {name} | {"; ".join(cells)} | object {top} |')
    tally: Counter[tuple[str, str, bool]] = Counter()
    for seed in range(first, last):
        count = 1 + seed % 5
        whole = table_top_frame(seed, count)
        finite = np.all(np.isfinite(whole.points), axis=-1)
        ring = np.zeros(whole.labels.shape, dtype=bool)
        ring[:BORDER_PIXELS] = ring[-BORDER_PIXELS:] = True
        ring[:, :BORDER_PIXELS] = ring[:, -BORDER_PIXELS:] = True
        cases = [('whole', whole.points[finite], whole.labels[finite], whole.labels, ring)]
        points, labels, cut = cut_table_top_frame(seed, count)
        columns = np.flatnonzero((whole.labels == cut).any(axis=0))
        middle = (int(columns.min()) + int(columns.max())) // 2
        kept = slice(middle, None) if seed % 2 else slice(None, middle)
        cut_ring = np.zeros(whole.labels[:, kept].shape, dtype=bool)
        cut_ring[:BORDER_PIXELS] = cut_ring[-BORDER_PIXELS:] = True
        cut_ring[:, :BORDER_PIXELS] = cut_ring[:, -BORDER_PIXELS:] = True
        cases.append(('cut', points, labels, whole.labels[:, kept], cut_ring))
        for frame, cloud, cloud_labels, image, border in cases:
            result = process_points(cloud, settings)
            if result.support is None:
                tally[(frame, 'frames without a support plane', False)] += 1
                continue
            tally[(frame, 'frames', False)] += 1
            at_border = set(np.unique(image[border]).tolist())
            owners = object_owners(result, cloud, cloud_labels)
            for item, owner in zip(result.objects, owners, strict=True):
                kind = 'background' if owner == BACKGROUND else 'whole'
                kind = 'at the border' if owner in at_border - {BACKGROUND} else kind
                tally[(frame, kind, item.cut_by_view)] += 1
    print(f'\nrendered frames, seeds {first}-{last - 1}: objects found cut / found')
    print('| frames | frames with a support | whole objects | at the border | background |')
    print('|---|---|---|---|---|')
    for frame in ('whole', 'cut'):
        cells = [f'{tally[(frame, "frames", False)]}']
        cells.append(str(tally[(frame, 'frames', False)]))
        for kind in ('whole', 'at the border', 'background'):
            found = tally[(frame, kind, True)] + tally[(frame, kind, False)]
            cells.append(f'{tally[(frame, kind, True)]} of {found}')
        skipped = tally[(frame, 'frames without a support plane', False)]
        cells[0] = f'{frame} ({skipped + int(cells[0])})'
        print('| ' + ' | '.join(cells) + ' |')


def plane_fits(repeats: int = 20) -> None:
    """Print the plane fit's time and normal error against Open3D's segment_plane."""
    import subprocess

    from mvbb_ros.pipeline.plane import fit_plane

    command = [
        sys.executable,
        '-c',
        'import time; t = time.perf_counter(); import open3d; print(time.perf_counter() - t)',
    ]
    imports = [
        float(subprocess.run(command, capture_output=True, text=True, check=True).stdout)
        for _ in range(3)
    ]
    import open3d as o3d

    print(f'\nimporting open3d: median {np.median(imports):.2f} s of 3 fresh interpreters')
    print(
        '| scene | points | ours ms | open3d ms (1000 iterations) | ratio '
        '| ours vs ref (deg) | open3d vs ref (deg) |'
    )
    print('|---|---|---|---|---|---|---|')
    for name in SCENES:
        points, _ = scene_truth(name)
        voxels, _ = filter_points(points, voxel_size=0.005)
        ours, theirs = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            normal, offset = fit_plane(voxels, 0.01)
            ours.append(time.perf_counter() - start)
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(voxels))
            start = time.perf_counter()
            model, _ = cloud.segment_plane(0.01, 3, 1000)
            theirs.append(time.perf_counter() - start)
        other = np.asarray(model[:3]) / np.linalg.norm(model[:3])
        reference = reference_normal(points, normal, offset)
        ours_ms, theirs_ms = np.median(ours) * 1e3, np.median(theirs) * 1e3
        print(
            f'| {name} | {len(voxels)} | {ours_ms:.1f} | {theirs_ms:.1f} | '
            f'{ours_ms / theirs_ms:.2f} | {angle_deg(normal, reference):.3f} | '
            f'{min(angle_deg(other, reference), angle_deg(-other, reference)):.3f} |'
        )


def main() -> None:
    """Run the measurements."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--frames', type=int, default=50, help='rendered frames (default 50)')
    parser.add_argument('--no-real', action='store_true', help='skip the real scenes')
    parser.add_argument('--fits', action='store_true', help='also time the plane fit')
    parser.add_argument(
        '--view-edge',
        metavar='FIRST:LAST',
        help="which objects are cut by the view's edge, on rendered seeds FIRST to LAST - 1",
    )
    args = parser.parse_args()
    if not args.no_real:
        if (reason := missing(SHARED_DATA / 'scenes')) is not None:
            sys.exit(f'{reason}; --no-real leaves the real scenes out')
        real_scenes()
    if args.fits:
        plane_fits()
    if args.frames:
        rendered_scenes(args.frames)
    if args.view_edge:
        first, last = (int(value) for value in args.view_edge.split(':'))
        view_edges(first, last, not args.no_real)


if __name__ == '__main__':
    main()

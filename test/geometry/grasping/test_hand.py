"""The described hand (fingers' length and thickness, the palm) checked on the points."""

from __future__ import annotations

from dataclasses import replace
import math

from geometry.grasping.test_refine import box_surface, CELL
from hypothesis import given, settings
from hypothesis import strategies as st
from mvbb_ros.geometry.grasping.contacts import (
    COL_CENTER,
    COL_FIRST,
    COL_TIP,
    COL_VALID,
    evaluate_lines,
)
from mvbb_ros.geometry.grasping.refinement_settings import GraspView, RefinementSettings
from mvbb_ros.geometry.grasping.surface import surface_model
import numpy as np
from scipy.spatial.transform import Rotation

#: The Franka Hand as the node describes it by default.
HAND = RefinementSettings(
    enabled=True,
    finger_length=0.054,
    finger_thickness=0.012,
    palm_width=0.204,
    palm_depth=0.063,
    palm_height=0.06,
)
UP = np.array([0.0, 0.0, 1.0])


def _top_down(center, turn):
    """One line straight down through `center`, closing along x turned by `turn` radians."""
    closing = np.array([math.cos(turn), math.sin(turn), 0.0])
    return center[None, :], -UP[None, :], closing[None, :]


@settings(max_examples=20, deadline=None)
@given(st.floats(0.06, 0.12), st.floats(0.0, math.pi), st.floats(0.02, 0.05))
def test_the_palm_stops_the_fingertips_a_finger_length_past_the_top(height, turn, width):
    """A tall block grasped from above: the tips go at most a finger length (less 4 mm) down."""
    center = np.array([0.0, 0.0, height / 2.0])
    points = box_surface((width, width, height), np.eye(3), center)
    model = surface_model(points, cell=CELL, up=UP)
    view = GraspView(gripper_max_width=0.08, standoff=0.05, up=UP)
    row = evaluate_lines(model, *_top_down(center, turn), HAND, view)[0]
    assert row[COL_VALID] > 0.0
    assert row[COL_TIP] - row[COL_FIRST] <= HAND.finger_length - 0.004 + 1e-9
    without = replace(HAND, palm_width=0.0)  # the same hand without a palm goes deeper
    deeper = evaluate_lines(model, *_top_down(center, turn), without, view)[0]
    assert deeper[COL_TIP] >= row[COL_TIP] - 1e-9


@settings(max_examples=25, deadline=None)
@given(
    st.floats(0.008, 0.03),
    st.floats(0.03, 0.07),
    st.floats(0.0, math.pi),
    st.floats(-0.3, 0.3),
    st.integers(0, 2**31 - 1),
)
def test_the_open_hand_stays_above_the_support(height, width, turn, tilt, seed):
    """Every valid line keeps the open fingers' and palm's lowest corner 5 mm above the floor."""
    rng = np.random.default_rng(seed)
    center = np.array([0.0, 0.0, height / 2.0])
    points = box_surface((width, 1.3 * width, height), np.eye(3), center)
    model = surface_model(points, cell=CELL, up=UP)
    clearance = 0.005
    view = GraspView(gripper_max_width=0.08, standoff=0.05, up=UP, support_clearance=clearance)
    origins, approaches, closings = _top_down(center, turn)
    turned = Rotation.from_rotvec(tilt * closings[0]).apply(approaches)  # approach tilted
    origins = origins + rng.normal(scale=0.005, size=(1, 3))
    row = evaluate_lines(model, origins, turned, closings, HAND, view)[0]
    if row[COL_VALID] == 0.0:
        return
    a, c = turned[0], closings[0]
    s = np.cross(a, c)
    tip = origins[0] + row[COL_TIP] * a + row[COL_CENTER] * c
    half = view.gripper_max_width / 2.0 + HAND.finger_thickness
    corners = [
        tip + y * c + x * s + u * a
        for y in (-half, half)
        for x in (-HAND.pad_size / 2.0, HAND.pad_size / 2.0)
        for u in (0.0, -HAND.finger_length)
    ]
    lowest = min(float(corner @ UP) for corner in corners)
    assert lowest >= model.floor + clearance - 1e-9


def test_a_thin_plate_lying_on_the_table_is_grasped_from_above_low_on_its_sides():
    """A 1.5 cm plate 5 cm wide: a top-down grasp whose tips go as low as the support allows."""
    height = 0.015
    center = np.array([0.0, 0.0, height / 2.0])
    points = box_surface((0.05, 0.09, height), np.eye(3), center)
    points = points[points[:, 2] > 0.001]  # the table hides the underside
    model = surface_model(points, cell=CELL, up=UP)
    view = GraspView(gripper_max_width=0.08, standoff=0.05, up=UP, support_clearance=0.003)
    row = evaluate_lines(model, *_top_down(center, 0.0), HAND, view)[0]
    assert row[COL_VALID] > 0.0
    tip = center + row[COL_TIP] * -UP + row[COL_CENTER] * np.array([1.0, 0.0, 0.0])
    assert tip[2] <= model.floor + 0.003 + 1e-3  # the clearance over the lowest point

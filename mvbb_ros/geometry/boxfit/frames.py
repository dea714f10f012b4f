"""
The 3x3 frames of the box fit in compiled code (numba): the PCA frame, a flat cloud's frame.

:mod:`mvbb_ros.geometry.boxfit.fit` starts from the PCA frame of a cloud's covariance
(:func:`symmetric_eigen`, cyclic Jacobi rotations) and, for flat clouds, from the frame of the
plane's minimum-area rectangle (:func:`planar_frame`, by
:mod:`mvbb_ros.geometry.boxfit.rectangle`); the final box's frame is the product of the PCA
frame and a searched one (:func:`matmul`). Helpers only: they are compiled into the kernels that
call them.
"""

from __future__ import annotations

import math

from mvbb_ros.geometry.boxfit.rectangle import calipers_kernel, hull_2d_kernel
import numba as nb
import numpy as np


@nb.njit
def symmetric_eigen(matrix: np.ndarray) -> np.ndarray:
    """
    Eigen-decompose a symmetric 3x3 matrix by cyclic Jacobi rotations.

    :return: a right-handed rotation (3, 3) whose columns are unit eigenvectors, largest
        eigenvalue first.
    """
    a = np.empty((3, 3))
    v = np.zeros((3, 3))
    for i in range(3):
        v[i, i] = 1.0
        for j in range(3):
            a[i, j] = matrix[i, j]
    for _ in range(64):
        off = abs(a[0, 1]) + abs(a[0, 2]) + abs(a[1, 2])
        diagonal = abs(a[0, 0]) + abs(a[1, 1]) + abs(a[2, 2])
        if off == 0.0 or off <= 1e-18 * diagonal:
            break
        for pair in range(3):
            p = 0 if pair < 2 else 1
            q = 2 if pair > 0 else 1
            if a[p, q] == 0.0:
                continue
            theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
            t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
            if theta < 0.0:
                t = -t
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):
                akp = a[k, p]
                akq = a[k, q]
                a[k, p] = c * akp - s * akq
                a[k, q] = s * akp + c * akq
            for k in range(3):
                apk = a[p, k]
                aqk = a[q, k]
                a[p, k] = c * apk - s * aqk
                a[q, k] = s * apk + c * aqk
            for k in range(3):
                vkp = v[k, p]
                vkq = v[k, q]
                v[k, p] = c * vkp - s * vkq
                v[k, q] = s * vkp + c * vkq
    # Columns by decreasing eigenvalue (a three-element sort).
    order = np.arange(3)
    for i in range(1, 3):
        j = i
        while j > 0 and a[order[j], order[j]] > a[order[j - 1], order[j - 1]]:
            order[j], order[j - 1] = order[j - 1], order[j]
            j -= 1
    vectors = np.empty((3, 3))
    for j in range(3):
        for k in range(3):
            vectors[k, j] = v[k, order[j]]
    # Right-handed: the third column is the cross product of the first two.
    vectors[0, 2] = vectors[1, 0] * vectors[2, 1] - vectors[2, 0] * vectors[1, 1]
    vectors[1, 2] = vectors[2, 0] * vectors[0, 1] - vectors[0, 0] * vectors[2, 1]
    vectors[2, 2] = vectors[0, 0] * vectors[1, 1] - vectors[1, 0] * vectors[0, 1]
    return vectors


@nb.njit
def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the 3x3 product a b (numba's @ needs BLAS through scipy)."""
    out = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            for k in range(3):
                out[i, j] += a[i, k] * b[k, j]
    return out


@nb.njit
def planar_frame(local: np.ndarray, first: int, second: int) -> np.ndarray:
    """
    Return the frame of points flat across PCA axes `first` and `second`.

    Its first two columns are the sides of the minimum-area rectangle of the points' coordinates
    along those axes, the third their cross product (the plane's normal).
    """
    count = local.shape[0]
    x = np.empty(count)
    y = np.empty(count)
    for i in range(count):
        x[i] = local[i, first]
        y[i] = local[i, second]
    order = np.arange(count)
    polygon = np.empty(count + 1, dtype=np.int64)
    corners = hull_2d_kernel(x, y, order, count, polygon)
    _, dx, dy = calipers_kernel(x, y, polygon, corners)
    frame = np.zeros((3, 3))
    frame[first, 0] = dx
    frame[second, 0] = dy
    frame[first, 1] = -dy
    frame[second, 1] = dx
    frame[0, 2] = frame[1, 0] * frame[2, 1] - frame[2, 0] * frame[1, 1]
    frame[1, 2] = frame[2, 0] * frame[0, 1] - frame[0, 0] * frame[2, 1]
    frame[2, 2] = frame[0, 0] * frame[1, 1] - frame[1, 0] * frame[0, 1]
    return frame

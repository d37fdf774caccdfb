"""Race rules as pure batched functions: gate passage, frame collision, ground and bounds.

Both backends call these, so the rules exist once. Shapes: N drones, G gates per drone.
Gate frame: x = passage direction, y = left, z = up; the opening is |y|, |z| <= size/2 at x = 0.
"""

from __future__ import annotations

import numpy as np

CRASH_REASONS = ("gate_collision", "ground", "out_of_bounds")


def to_gate_frame(points: np.ndarray, gate_pos: np.ndarray, gate_yaw: np.ndarray) -> np.ndarray:
    """Express world points in gate frames.

    Args:
        points: (N, 3) or (N, G, 3) world positions.
        gate_pos: (N, G, 3) gate centres, world.
        gate_yaw: (N, G) gate headings, radians.

    Returns:
        (N, G, 3) positions in each gate's frame.
    """
    d = (points[:, None, :] if points.ndim == 2 else points) - gate_pos
    c, s = np.cos(gate_yaw), np.sin(gate_yaw)
    x = c * d[..., 0] + s * d[..., 1]
    y = -s * d[..., 0] + c * d[..., 1]
    return np.stack((x, y, d[..., 2]), axis=-1)


def bar_distance_sq_local(
    local: np.ndarray, size: np.ndarray, frame_width: np.ndarray
) -> np.ndarray:
    """Squared distance from points in gate frame to the gate's four frame bars (0 inside a bar).

    The bars are square in section (``frame_width`` wide and deep) and surround the opening;
    top and bottom bars span the full outer width. By symmetry only |x|, |y| and |z| matter: the
    top/bottom bars are the box |x| <= w/2, |y| <= h + w, h <= |z| <= h + w (h = size/2, w =
    frame_width) and the side bars the box |x| <= w/2, h <= |y| <= h + w, |z| <= h.

    Args:
        local: (..., 3) points in gate frame.
        size: (...) opening side, metres.
        frame_width: (...) bar width, metres.

    Returns:
        (...) squared distance in m².
    """
    x, y, z = np.abs(local[..., 0]), np.abs(local[..., 1]), np.abs(local[..., 2])
    h, w = size / 2.0, frame_width
    hw = w / 2.0
    dx = np.maximum(x - hw, 0.0)
    dz_top = np.maximum(np.abs(z - h - hw) - hw, 0.0)
    dy_top = np.maximum(y - h - w, 0.0)
    dy_side = np.maximum(np.abs(y - h - hw) - hw, 0.0)
    dz_side = np.maximum(z - h, 0.0)
    return dx * dx + np.minimum(
        dy_top * dy_top + dz_top * dz_top, dy_side * dy_side + dz_side * dz_side
    )


def bar_distance_local(local: np.ndarray, size: np.ndarray, frame_width: np.ndarray) -> np.ndarray:
    """Distance from points in gate frame to the gate's frame bars, metres (see the squared form)."""
    return np.sqrt(bar_distance_sq_local(local, size, frame_width))


def gate_bar_distance(points, gate_pos, gate_yaw, size, frame_width) -> np.ndarray:
    """Distance from world points to every gate's frame bars.

    Args:
        points: (N, 3) or (N, G, 3) world positions.
        gate_pos: (N, G, 3); gate_yaw, size, frame_width: (N, G).

    Returns:
        (N, G) distances, metres.
    """
    return bar_distance_local(to_gate_frame(points, gate_pos, gate_yaw), size, frame_width)


def frame_collision(points, radius, gate_pos, gate_yaw, size, frame_width, gate_mask) -> np.ndarray:
    """Whether a sphere of ``radius`` at each point touches any (unmasked) gate bar.

    Args:
        points: (N, 3) world centres.
        radius: scalar or (N,) sphere radius.
        gate_pos: (N, G, 3); gate_yaw, size, frame_width: (N, G).
        gate_mask: (N, G) bool, True for gates that exist.

    Returns:
        (N,) bool.
    """
    d = gate_bar_distance(points, gate_pos, gate_yaw, size, frame_width)
    r = np.asarray(radius)
    hit = (d < (r[:, None] if r.ndim else r)) & gate_mask
    return hit.any(axis=1)


def trail_frame_collision(
    trail: np.ndarray,
    radius: float | np.ndarray,
    gate_pos: np.ndarray,
    gate_cos: np.ndarray,
    gate_sin: np.ndarray,
    size: np.ndarray,
    frame_width: np.ndarray,
    reach: np.ndarray,
    gate_mask: np.ndarray,
) -> np.ndarray:
    """(N,) bool: any sub-step position (trail (S, N, 3)) within the drone radius of a bar.

    A broad phase keeps only (drone, gate) pairs whose centres are within reach of each other
    at the end of the step; the exact bar distance is computed for those pairs alone.

    Args:
        trail: (S, N, 3) world sub-step positions.
        radius: scalar or (N,) drone sphere radius, metres.
        gate_pos: (N, G, 3) gate centres, world.
        gate_cos, gate_sin: (N, G) cosine and sine of the gate headings.
        size, frame_width: (N, G) inner opening and bar width, metres.
        reach: (N, G) centre-to-outer-corner distance of each gate, metres.
        gate_mask: (N, G) bool, True for gates that exist.

    Returns:
        (N,) bool.
    """
    end = trail[-1]
    diff = gate_pos - end[:, None, :]
    travel = np.abs(trail[-1] - trail[0]).sum(axis=1)
    reach = reach + (radius + travel)[:, None]
    near = (np.einsum("ngi,ngi->ng", diff, diff) < reach * reach) & gate_mask
    ni, gi = np.nonzero(near)
    hit = np.zeros(len(end), dtype=bool)
    if ni.size == 0:
        return hit
    d = trail[:, ni, :] - gate_pos[ni, gi]
    c, s = gate_cos[ni, gi], gate_sin[ni, gi]
    local = np.stack(
        (c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]), axis=-1
    )
    dist_sq = bar_distance_sq_local(local, size[ni, gi], frame_width[ni, gi])
    r = np.broadcast_to(radius, hit.shape)[ni]
    hit[ni[(dist_sq < r * r).any(axis=0)]] = True
    return hit


def gate_passage(p0: np.ndarray, p1: np.ndarray, gate_pos, gate_yaw, size) -> np.ndarray:
    """Whether each drone's segment p0 -> p1 passes its target gate.

    A passage is a crossing of the gate plane from x < 0 to x >= 0 (gate frame) with the crossing
    point strictly inside the opening.

    Args:
        p0, p1: (N, 3) world positions before and after the step.
        gate_pos: (N, 3) target gate centres; gate_yaw, size: (N,).

    Returns:
        (N,) bool.
    """
    return gate_crossing(p0, p1, gate_pos, gate_yaw, size)[0]


def gate_crossing(
    p0: np.ndarray, p1: np.ndarray, gate_pos, gate_yaw, size
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gate passages (see ``gate_passage``), how central each one was, and when in the step.

    Returns:
        passed: (N,) bool.
        centrality: (N,) 1 − max(|y|, |z|) / (size / 2) at the crossing point: 1 through the
            centre, 0 at the opening's edge; 0 where no gate was passed.
        fraction: (N,) where along the step p0 → p1 the gate plane was crossed, in [0, 1] (the
            step taken as straight): the passage's time is the step's start + fraction × its
            length, as a timing gate would read it; 1 where no gate was passed.
    """
    c, s = np.cos(gate_yaw), np.sin(gate_yaw)
    x0 = c * (p0[:, 0] - gate_pos[:, 0]) + s * (p0[:, 1] - gate_pos[:, 1])
    x1 = c * (p1[:, 0] - gate_pos[:, 0]) + s * (p1[:, 1] - gate_pos[:, 1])
    crossed = (x0 < 0.0) & (x1 >= 0.0)
    if not crossed.any():  # the common case: nobody reached a gate plane this step
        return crossed, np.zeros(len(crossed)), np.ones(len(crossed))
    both = to_gate_frame(np.stack((p0, p1), axis=1), gate_pos[:, None], gate_yaw[:, None])
    l0, l1 = both[:, 0], both[:, 1]
    denom = np.where(crossed, l1[:, 0] - l0[:, 0], 1.0)
    t = np.clip(-l0[:, 0] / denom, 0.0, 1.0)
    hit = l0[:, 1:] + t[:, None] * (l1[:, 1:] - l0[:, 1:])
    h = size / 2.0
    passed = crossed & (np.abs(hit[:, 0]) < h) & (np.abs(hit[:, 1]) < h)
    offset = np.maximum(np.abs(hit[:, 0]), np.abs(hit[:, 1])) / h
    return passed, np.where(passed, 1.0 - offset, 0.0), np.where(passed, t, 1.0)


def crossing_alignment(p0: np.ndarray, p1: np.ndarray, gate_yaw: np.ndarray) -> np.ndarray:
    """(N,) cosine between each step's direction p0 -> p1 and its gate's passage direction.

    1 for a step straight through the gate, 0.5 for one 60° off its normal. A crossing that
    oblique leaves a sphere of radius r a window of only ``size / 2 − r / cos`` either side of the
    centre (0.1 m of a 0.8 m opening at 60° for r = 0.15 m, against 0.25 m straight through).
    Zero-length steps give 0.
    """
    d = p1 - p0
    along = np.cos(gate_yaw) * d[:, 0] + np.sin(gate_yaw) * d[:, 1]
    return along / np.maximum(np.linalg.norm(d, axis=1), 1e-9)


def out_of_bounds(pos: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(N,) bool: position outside the box [lo, hi] ((N, 3) or (3,) each)."""
    return np.any((pos < lo) | (pos > hi), axis=-1)


def ground_contact(pos: np.ndarray, radius) -> np.ndarray:
    """(N,) bool: the drone's sphere touches the ground plane z = 0."""
    return pos[:, 2] < radius

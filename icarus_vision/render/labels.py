"""Ground-truth gate labels of a rendered frame: corners, COCO visibility, box, distance, pose.

Corner order is TL, TR, BR, BL as seen by a drone approaching the gate along its passage direction
(ARCHITECTURE.md). A physical gate flown in both directions is labelled with the passage whose
approach side the camera is on, so the order always reads TL, TR, BR, BL on screen for a level
camera. A gate seen only from its exit side looks the same as from its approach side (the frame is
symmetric); with ``back_views`` it is labelled too, its corners named as seen from that side
(``passage`` None, ``from_behind`` True), so a detector is never taught that a gate is not a gate.
Visibility comes from the renderer's segmentation and depth, never from geometry alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from icarus_vision.render.camera import Camera, project_points, world_to_camera
from icarus_vision.render.frustum import spheres_in_view
from icarus_vision.sim.track import SAME_GATE_TOL, Gate, Track

VISIBLE, HIDDEN, OUTSIDE = 2, 1, 0
"""COCO keypoint visibility flags."""


@dataclass(frozen=True)
class GateLabel:
    """One gate in one frame.

    Attributes:
        gate_id: index of the physical gate in ``track.physical_gates()``.
        passage: index in ``track.gates`` of the passage whose direction orders the corners; None
            for a gate seen from behind (corners then named as seen from its exit side).
        corners_px: (4, 2) float64 (u, v) of the opening's corners, TL, TR, BR, BL; NaN for a corner
            behind the camera.
        visibility: (4,) int64 COCO flags: 2 visible, 1 in the image but hidden, 0 outside the image.
        bbox: (x, y, w, h) pixels, COCO style: the projected outer frame clipped to the image.
        distance: camera centre to gate centre, m.
        r_cam_gate: (3, 3) gate frame (x passage, y left, z up) axes in the camera optical frame.
        t_cam_gate: (3,) gate centre in the camera optical frame, m.
        pixels: number of pixels of the gate in the segmentation mask.
    """

    gate_id: int
    passage: int | None
    corners_px: np.ndarray
    visibility: np.ndarray
    bbox: tuple[float, float, float, float]
    distance: float
    r_cam_gate: np.ndarray
    t_cam_gate: np.ndarray
    pixels: int

    @property
    def from_behind(self) -> bool:
        """The camera sees the gate from its exit side (no passage approaches from there)."""
        return self.passage is None

    @property
    def num_visible(self) -> int:
        """Number of corners flagged visible (2)."""
        return int(np.sum(self.visibility == VISIBLE))


def _yaw_rot(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def facing_passage(track: Track, gate: Gate, cam_pos: np.ndarray) -> int | None:
    """Index in ``track.gates`` of the passage through ``gate`` whose approach side holds ``cam_pos``.

    Returns None when the camera sees the gate from no passage's approach side.
    """
    pos = np.array([g.pos for g in track.gates], dtype=float)
    normals = np.array([g.normal for g in track.gates])
    rel = np.asarray(cam_pos, dtype=float) - pos
    cos = np.einsum("ij,ij->i", rel, normals) / np.maximum(np.linalg.norm(rel, axis=1), 1e-9)
    cos[np.linalg.norm(pos - np.asarray(gate.pos), axis=1) >= SAME_GATE_TOL] = np.inf
    best = int(np.argmin(cos))  # the passage seen most head-on (the first one on ties)
    return best if cos[best] < 0.0 else None


def corner_visibility(
    seg: np.ndarray,
    depth: np.ndarray,
    body: int,
    probe_px: np.ndarray,
    probe_z: np.ndarray,
    corner_in_image: np.ndarray,
    tol_m: float,
) -> np.ndarray:
    """COCO flags from the mask: a corner is visible when, within one pixel of its probe (a point on
    the frame bar just outside the opening's corner), the mask shows this gate at the probe's depth.

    Args:
        seg: (H, W) body ids; depth: (H, W) metric z.
        body: the gate's body id.
        probe_px: (4, 2) probe pixels (u, v); probe_z: (4,) their depth, m.
        corner_in_image: (4,) bool, the corner itself lies in the image.
        tol_m: depth tolerance, m (the bar's depth plus margin).

    Returns:
        (4,) int64 flags.
    """
    h, w = seg.shape
    out = np.where(corner_in_image, HIDDEN, OUTSIDE).astype(np.int64)
    for k in range(4):
        if not corner_in_image[k] or not np.all(np.isfinite(probe_px[k])):
            continue
        u, v = int(round(probe_px[k, 0])), int(round(probe_px[k, 1]))
        u0, u1, v0, v1 = max(u - 1, 0), min(u + 2, w), max(v - 1, 0), min(v + 2, h)
        if u0 >= u1 or v0 >= v1:
            continue
        win_s, win_z = seg[v0:v1, u0:u1], depth[v0:v1, u0:u1]
        ok = (win_s == body) & (np.abs(win_z - probe_z[k]) <= tol_m + 0.01 * probe_z[k])
        if ok.any():
            out[k] = VISIBLE
    return out


def gate_labels(
    track: Track,
    camera: Camera,
    pos: np.ndarray,
    quat: np.ndarray,
    seg: np.ndarray,
    depth: np.ndarray,
    gate_bodies: tuple[int, ...],
    frame_width: float | None = None,
    physical_gates: tuple[Gate, ...] | None = None,
    back_views: bool = False,
) -> list[GateLabel]:
    """Labels of every gate whose opening faces the camera, lies in front of it and shows in the image.

    Args:
        track: the track the scene was built from.
        camera: the camera that rendered the frame.
        pos: (3,) body position; quat: (4,) body attitude x, y, z, w.
        seg: (H, W) int32 segmentation (body ids) of the frame.
        depth: (H, W) metric depth of the frame, m.
        gate_bodies: body id of each physical gate, ``track.physical_gates()`` order.
        frame_width: rendered bar width when the scene overrode it (None: each gate's own).
        physical_gates: ``track.physical_gates()`` when the caller has it already.
        back_views: also label gates seen from behind (see the module docstring).

    Returns:
        labels sorted by distance, nearest first.
    """
    r_wc, t_wc = camera.pose(pos, quat)
    k = camera.K
    labels = []
    gates = track.physical_gates() if physical_gates is None else physical_gates
    # Skip the gates that cannot show in the image (bounding sphere outside the view pyramid).
    fws = np.array([frame_width or g.frame_width for g in gates])
    radii = math.sqrt(2.0) * (np.array([g.size for g in gates]) / 2.0 + fws) + fws
    centres = np.array([g.pos for g in gates], dtype=float)
    cover = camera.pinhole_cover()[0]  # the pinhole view of every ray the lens sees
    in_view = spheres_in_view(cover, r_wc[None], t_wc[None], centres, radii)[0]
    for gid, gate in enumerate(gates):
        if not in_view[gid]:
            continue
        passage = facing_passage(track, gate, t_wc)
        if passage is None and not back_views:
            continue
        # Seen from behind: the same frame turned about z, so corners are named from this side.
        g = track.gates[passage] if passage is not None else _turned(gate)
        fw = frame_width or g.frame_width
        r_wg = _yaw_rot(g.yaw)
        t_cg = world_to_camera(np.asarray(g.pos)[None], r_wc, t_wc)[0]
        if t_cg[2] <= camera.near:
            continue
        corners = g.corners()
        px, z = project_points(k, world_to_camera(corners, r_wc, t_wc))
        px = camera.distort(px)
        in_front = z > camera.near
        px[~in_front] = np.nan
        bbox = _outer_bbox(camera, r_wc, t_wc, g, fw, seg == gate_bodies[gid])
        if bbox is None:
            continue
        # Probe: on the approach face, pushed diagonally out of the opening onto the bar by about
        # 1.5 px (at most half the bar), so it samples the frame right at the corner.
        outward = (corners - np.asarray(g.pos)) / (g.size / 2.0)  # (4, 3): (0, ±1, ±1) rotated
        px_m = 1.5 * np.maximum(z, camera.near) / k[0, 0]
        off = np.minimum(0.5 * fw, px_m)[:, None] * outward - 0.5 * fw * g.normal
        probe_px, probe_z = project_points(k, world_to_camera(corners + off, r_wc, t_wc))
        probe_px = camera.distort(probe_px)
        inside = camera.in_image(px) & in_front
        vis = corner_visibility(seg, depth, gate_bodies[gid], probe_px, probe_z, inside, fw + 0.02)
        labels.append(
            GateLabel(
                gate_id=gid,
                passage=passage,
                corners_px=px,
                visibility=vis,
                bbox=bbox,
                distance=float(np.linalg.norm(t_cg)),
                r_cam_gate=r_wc.T @ r_wg,
                t_cam_gate=t_cg,
                pixels=int(np.count_nonzero(seg == gate_bodies[gid])),
            )
        )
    labels.sort(key=lambda lab: lab.distance)
    return labels


def _turned(gate: Gate) -> Gate:
    """``gate`` with its passage direction reversed (the same frame, corners named from behind)."""
    return replace(gate, yaw_deg=gate.yaw_deg + 180.0)


def _outer_bbox(camera, r_wc, t_wc, gate: Gate, fw: float, mask: np.ndarray):
    """COCO box of the projected outer frame clipped to the image (the mask's box where part of
    the frame is behind the camera); None when nothing of the gate falls in the image."""
    h = gate.size / 2.0 + fw
    local = np.array([[x, y, z] for x in (-fw / 2, fw / 2) for y in (-h, h) for z in (-h, h)])
    if camera.distorted:  # the lens bends the frame's edges: bound points along them too
        t = np.linspace(0.0, 1.0, 17)[:, None, None]
        pairs = [(i, j) for i in range(8) for j in range(i + 1, 8)
                 if np.count_nonzero(local[i] != local[j]) == 1]  # fmt: skip
        local = np.concatenate([local[i] + t[:, 0] * (local[j] - local[i]) for i, j in pairs])
    world = local @ _yaw_rot(gate.yaw).T + np.asarray(gate.pos)
    px, z = project_points(camera.K, world_to_camera(world, r_wc, t_wc))
    px = camera.distort(px)
    if np.all(z > camera.near):
        x0, y0 = np.maximum(px.min(axis=0), -0.5)
        x1 = min(px[:, 0].max(), camera.width - 0.5)
        y1 = min(px[:, 1].max(), camera.height - 0.5)
    else:
        vs, us = np.nonzero(mask)
        if len(us) == 0:
            return None
        x0, y0, x1, y1 = us.min() - 0.5, vs.min() - 0.5, us.max() + 0.5, vs.max() + 0.5
    if x1 <= x0 or y1 <= y0:
        return None
    return (float(x0), float(y0), float(x1 - x0), float(y1 - y0))


def frame_labels(
    scene,
    frame,
    pos: np.ndarray,
    quat: np.ndarray,
    camera: Camera | None = None,
    back_views: bool = False,
):
    """:func:`gate_labels` of a :class:`~icarus_vision.render.scene.Frame` rendered by ``scene``."""
    cam = camera or scene.camera
    return gate_labels(
        scene.track,
        cam,
        pos,
        quat,
        frame.seg,
        frame.depth,
        scene.gate_bodies,
        scene.style.frame_width,
        scene.gates,
        back_views,
    )

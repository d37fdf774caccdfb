"""Race video: the FPV image with detected corners and the estimated gate, beside a top view."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from icarus_vision.fileio import atomic_path
from icarus_vision.render.camera import Camera
from icarus_vision.sim.track import Track

FPV_SCALE = 2
TOP_SIZE = 480
CORNER_COLORS = [
    (255, 80, 80),
    (80, 255, 80),
    (80, 160, 255),
    (255, 255, 80),
]  # TL, TR, BR, BL (RGB)


GHOST_COLOR = (150, 150, 150)


class VideoComposer:
    """Draws one video frame per camera frame. Frames are RGB uint8 (H, W, 3).

    With ``ghost`` (the time-optimal plan as (t (M,), pos (M, 3))), the top view also shows the
    planned path and, as a grey ring, where the plan is at the same moment of the race.
    """

    def __init__(
        self,
        track: Track,
        camera: Camera,
        scene,
        ghost: tuple[np.ndarray, np.ndarray] | None = None,
        frame_dt: float = 1 / 30,
    ) -> None:
        self.track, self.camera, self.scene = track, camera, scene
        self.ghost, self.frame_dt, self.frames = ghost, frame_dt, 0
        pts = np.array([track.start_pos, *(g.pos for g in track.gates)])[:, :2]
        if ghost is not None:
            pts = np.concatenate((pts, np.asarray(ghost[1])[:, :2]))
        lo, hi = pts.min(axis=0) - 3.0, pts.max(axis=0) + 3.0
        self.scale = (TOP_SIZE - 20) / float(max(hi - lo))
        self.lo = lo
        self.trail: list[tuple[int, int]] = []
        self.background = self._draw_track()

    def _px(self, xy) -> tuple[int, int]:
        u = 10 + (xy[0] - self.lo[0]) * self.scale
        v = TOP_SIZE - 10 - (xy[1] - self.lo[1]) * self.scale
        return int(round(u)), int(round(v))

    def _draw_track(self) -> np.ndarray:
        img = np.full((TOP_SIZE, TOP_SIZE, 3), 245, np.uint8)
        if self.ghost is not None:
            path = np.array([self._px(p[:2]) for p in np.asarray(self.ghost[1])], np.int32)
            cv2.polylines(img, [path], False, GHOST_COLOR, 1, cv2.LINE_AA)
        for i, g in enumerate(self.track.gates):
            c = np.asarray(g.pos)
            half = (g.size / 2 + g.frame_width) * np.array([-np.sin(g.yaw), np.cos(g.yaw)])
            cv2.line(
                img, self._px(c[:2] - half), self._px(c[:2] + half), (240, 120, 20), 3, cv2.LINE_AA
            )
            cv2.putText(
                img,
                str(i),
                self._px(c[:2] + 1.5 * half),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.4,
                (60, 60, 60),
                1,
                cv2.LINE_AA,
            )
        return img

    def compose(self, rgb, detections, estimate, state) -> np.ndarray:
        pos, quat = state.pos[0], state.quat[0]
        if rgb is None:
            rgb = self.scene.render(pos, quat).rgb
        fpv = cv2.resize(rgb, None, fx=FPV_SCALE, fy=FPV_SCALE, interpolation=cv2.INTER_NEAREST)
        for d in detections:
            pts = (np.asarray(d.corners) * FPV_SCALE).astype(np.int32)
            cv2.polylines(fpv, [pts], True, (0, 255, 0), 1, cv2.LINE_AA)
            for p, col in zip(pts, CORNER_COLORS, strict=True):
                cv2.circle(fpv, tuple(int(v) for v in p), 4, col, -1, cv2.LINE_AA)
        if estimate is not None and estimate.valid:
            size = self.track.gates[0].size
            h = size / 2
            local = np.array([[0, h, h], [0, -h, h], [0, -h, -h], [0, h, -h]])
            c, s = np.cos(estimate.yaw), np.sin(estimate.yaw)
            rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
            world = local @ rot.T + estimate.gate_pos
            px, depth = self.camera.project(world, pos, quat)
            if np.all(depth > 0) and np.all(np.isfinite(px)):
                cv2.polylines(
                    fpv, [(px * FPV_SCALE).astype(np.int32)], True, (255, 0, 255), 2, cv2.LINE_AA
                )
        top = self.background.copy()
        self.trail.append(self._px(pos[:2]))
        if len(self.trail) > 1:
            cv2.polylines(
                top, [np.array(self.trail, np.int32)], False, (30, 90, 200), 2, cv2.LINE_AA
            )
        if self.ghost is not None:
            t_plan, p_plan = np.asarray(self.ghost[0]), np.asarray(self.ghost[1])
            now = min(self.frames * self.frame_dt, float(t_plan[-1]))
            at = [np.interp(now, t_plan, p_plan[:, k]) for k in range(2)]
            cv2.circle(top, self._px(at), 7, GHOST_COLOR, 2, cv2.LINE_AA)
        self.frames += 1
        cv2.circle(top, self.trail[-1], 6, (200, 30, 30), -1, cv2.LINE_AA)
        speed = float(np.linalg.norm(state.vel[0]))
        cv2.putText(
            top,
            f"{speed:4.1f} m/s",
            (10, 24),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.7,
            (20, 20, 20),
            2,
            cv2.LINE_AA,
        )
        pad = np.full((TOP_SIZE, fpv.shape[1], 3), 20, np.uint8)
        pad[: fpv.shape[0]] = fpv[:TOP_SIZE]
        return np.concatenate((pad, top), axis=1)


def write_video(path: str | os.PathLike, frames: list[np.ndarray], fps: float) -> None:
    """Encode frames (RGB uint8) to an MP4 (H.264) atomically: temporary file, then rename."""
    import imageio.v2 as imageio

    if not frames:
        raise ValueError("no frames to write")
    with (
        atomic_path(path, suffix=Path(path).suffix or ".mp4") as tmp,
        imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7, macro_block_size=16) as w,
    ):
        for f in frames:
            w.append_data(f)

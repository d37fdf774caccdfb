"""The gate-corner detector interface, and an oracle detector built from the true geometry.

Every detector maps one FPV image to a list of :class:`GateDetection`: the four inner-opening
corners of each gate it sees, in pixels, in the keypoint order of ARCHITECTURE.md (TL, TR, BR, BL
as seen from the gate's approach side), with per-corner and per-gate scores.

:class:`OracleDetector` stands in for a real detector when measuring the estimator: it projects the
true corners of the gates in view (from the true drone pose, which the simulator knows), optionally
adds pixel noise and drops gates at random. Visibility comes from the rendered segmentation mask when
a frame is given, else from geometry (in front of the camera, inside the image, seen from the
approach side).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from icarus_vision.render.camera import Camera, project_points, world_to_camera
from icarus_vision.render.labels import VISIBLE, facing_passage, gate_labels
from icarus_vision.sim.track import Track

FLIP_ORDER = [1, 0, 3, 2]
"""Corner order of a mirrored gate: the new TL is the old TR, and so on."""


@dataclass(frozen=True)
class GateDetection:
    """One gate found in one image.

    Attributes:
        corners: (4, 2) float64 pixel coordinates (u, v) of the opening's corners, TL, TR, BR, BL.
        corner_scores: (4,) float64 confidence of each corner in [0, 1].
        score: confidence that this is a gate, in [0, 1].
    """

    corners: np.ndarray
    corner_scores: np.ndarray
    score: float

    def __post_init__(self) -> None:
        corners = np.asarray(self.corners, dtype=np.float64)
        scores = np.asarray(self.corner_scores, dtype=np.float64)
        if corners.shape != (4, 2):
            raise ValueError(
                f"corners must have shape (4, 2) (TL, TR, BR, BL), got {corners.shape}"
            )
        if scores.shape != (4,):
            raise ValueError(f"corner_scores must have shape (4,), got {scores.shape}")
        object.__setattr__(self, "corners", corners)
        object.__setattr__(self, "corner_scores", scores)
        object.__setattr__(self, "score", float(self.score))


def validate_image(image: np.ndarray) -> np.ndarray:
    """Check a detector input and return it as an array.

    Args:
        image: (H, W, 3) uint8 RGB image.

    Raises:
        ValueError: not an array of that dtype, rank or channel count, or empty.
    """
    if not isinstance(image, np.ndarray):
        raise ValueError(
            f"image must be a numpy array (H, W, 3) uint8 RGB, got {type(image).__name__}"
        )
    if image.dtype != np.uint8:
        raise ValueError(f"image must be uint8 RGB (H, W, 3), got dtype {image.dtype}")
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must have shape (H, W, 3) (RGB), got {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"image must not be empty, got shape {image.shape}")
    return image


class Detector(abc.ABC):
    """A gate-corner detector. Subclasses implement :meth:`_detect`; :meth:`detect` validates."""

    name: str = "abstract"
    """Short name used in reports (``oracle``, ``opencv``, ``cnn``)."""

    def detect(self, image: np.ndarray) -> list[GateDetection]:
        """Gates in one image.

        Args:
            image: (H, W, 3) uint8 RGB.

        Returns:
            detections, best score first (empty when no gate is seen).

        Raises:
            ValueError: the image has the wrong dtype, shape or channel count.
        """
        return self._detect(validate_image(image))

    @abc.abstractmethod
    def _detect(self, image: np.ndarray) -> list[GateDetection]:
        """Gates in a validated image."""


class OracleDetector(Detector):
    """Projected true corners of the gates in view, with optional pixel noise and misses.

    Call :meth:`set_pose` with the true drone pose (and the rendered frame, if any) before
    :meth:`detect`; the image itself is only validated.

    Args:
        track: the true track (the simulator's, not the estimator's map).
        camera: the camera that renders the frames.
        sigma_px: standard deviation of the Gaussian noise added to each corner coordinate, pixels.
        miss_rate: probability that a gate in view is not reported.
        seed: seed of the noise and miss draws.
        gate_bodies: body id of each physical gate in the rendering scene (``Scene.gate_bodies``);
            needed to read visibility from a frame's segmentation mask.
        min_visible: fewest corners that must be visible in the mask for a gate to be reported
            (all four must lie inside the image in every case).
        min_side_px: smallest mean side of the projected opening that is reported, pixels.
    """

    name = "oracle"

    def __init__(
        self,
        track: Track,
        camera: Camera,
        *,
        sigma_px: float = 0.0,
        miss_rate: float = 0.0,
        seed: int | None = 0,
        gate_bodies: tuple[int, ...] | None = None,
        min_visible: int = 3,
        min_side_px: float = 4.0,
    ) -> None:
        if not (np.isfinite(sigma_px) and sigma_px >= 0):
            raise ValueError(f"sigma_px must be finite and >= 0, got {sigma_px}")
        if not 0.0 <= miss_rate <= 1.0:
            raise ValueError(f"miss_rate must be in [0, 1], got {miss_rate}")
        self.track, self.camera = track, camera
        self.sigma_px, self.miss_rate = float(sigma_px), float(miss_rate)
        self.gate_bodies, self.min_visible, self.min_side_px = gate_bodies, min_visible, min_side_px
        self.rng = np.random.default_rng(seed)
        self._gates = track.physical_gates()
        self._pose: tuple[np.ndarray, np.ndarray] | None = None
        self._frame = None

    def set_pose(self, pos: np.ndarray, quat: np.ndarray, frame=None) -> None:
        """The true body pose (pos (3,) world, quat (4,) x, y, z, w) of the next image, and the
        rendered :class:`~icarus_vision.render.style.Frame` (for mask visibility) or None."""
        if frame is not None and self.gate_bodies is None:
            raise ValueError("OracleDetector needs gate_bodies to read visibility from a frame")
        self._pose = (np.asarray(pos, dtype=float).reshape(3), np.asarray(quat, float).reshape(4))
        self._frame = frame

    def detect_pose(self, pos: np.ndarray, quat: np.ndarray, frame=None) -> list[GateDetection]:
        """:meth:`set_pose` then detection, without an image."""
        self.set_pose(pos, quat, frame)
        return self._detect(None)

    def _detect(self, image: np.ndarray | None) -> list[GateDetection]:
        if self._pose is None:
            raise RuntimeError("OracleDetector.set_pose() must be called before detect()")
        pos, quat = self._pose
        if self._frame is not None:
            found = self._from_mask(pos, quat, self._frame)
        else:
            found = self._from_geometry(pos, quat)
        out = []
        for corners, scores in found:
            if self.miss_rate > 0 and self.rng.random() < self.miss_rate:
                continue
            sides = np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)
            if sides.mean() < self.min_side_px:
                continue
            if self.sigma_px > 0:
                corners = corners + self.rng.normal(0.0, self.sigma_px, corners.shape)
            out.append(GateDetection(corners, scores, float(scores.mean())))
        return out

    def _from_mask(self, pos, quat, frame) -> list[tuple[np.ndarray, np.ndarray]]:
        labels = gate_labels(
            self.track, self.camera, pos, quat, frame.seg, frame.depth, self.gate_bodies
        )
        found = []
        for lab in labels:
            inside = self.camera.in_image(lab.corners_px)
            if inside.all() and lab.num_visible >= self.min_visible:
                scores = np.where(lab.visibility == VISIBLE, 1.0, 0.5)
                found.append((lab.corners_px.copy(), scores))
        return found

    def _from_geometry(self, pos, quat) -> list[tuple[np.ndarray, np.ndarray]]:
        cam = self.camera
        r_wc, t_wc = cam.pose(pos, quat)
        found = []
        for gate in self._gates:
            passage = facing_passage(self.track, gate, t_wc)
            if passage is None:
                continue
            g = self.track.gates[passage]
            px, z = project_points(cam.K, world_to_camera(g.corners(), r_wc, t_wc))
            if np.all(z > cam.near) and cam.in_image(px).all():
                found.append((px, np.ones(4), float(np.linalg.norm(np.subtract(g.pos, t_wc)))))
        found.sort(key=lambda f: f[2])
        return [(px, s) for px, s, _ in found]

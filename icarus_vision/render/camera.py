"""The FPV camera model shared by rendering, labelling and (later) PnP.

Frames:

* world: z up; body: FLU (x forward, y left, z up); quaternions x, y, z, w, body -> world.
* camera: OpenCV optical frame, x right, y down, z forward (along the optical axis). With zero
  uptilt and roll the optical axis is the body x axis, image right is body -y, image down is body -z.
  ``uptilt_deg`` pitches the camera *up* about body y; ``roll_deg`` rolls it about its optical axis.
* pixels: OpenCV convention, (u, v) = (column, row) with the centre of the top-left pixel at (0, 0),
  so the image spans [-0.5, width - 0.5] x [-0.5, height - 0.5].

The pure functions take batched arrays; :class:`Camera` holds the parameters and derives the
PyBullet view and projection matrices from the very same K and extrinsics, so a rendered image and
its labels cannot disagree.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from icarus_vision.render.distortion import check_distortion, distort_pixels, undistort_pixels
from icarus_vision.sim.dynamics import quat_to_rot
from icarus_vision.sim.quad import CameraParams

# Columns: the optical axes (x right, y down, z forward) expressed in the FLU body frame.
_R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# OpenCV optical frame -> OpenGL eye frame (x right, y up, z backward).
_CV_TO_GL = np.diag([1.0, -1.0, -1.0])

TINY_RENDERER_SAMPLE_OFFSET = (-0.5, 0.5)
"""Where PyBullet's TinyRenderer samples pixel (u, v) relative to its centre (measured: it covers
pixel corners, rows flipped), so that :meth:`Camera.projection_matrix` can compensate."""

HARDWARE_OPENGL_SAMPLE_OFFSET = (0.0, 0.0)
"""The same for PyBullet's OpenGL renderer (the EGL plugin): it samples pixel centres (measured)."""


PAD_VALUE = 114
"""Grey level of the padding that letterboxes a frame of another aspect ratio (the detector's
network input, and datasets of cameras of other aspects)."""


def letterbox_size(size: tuple[int, int], input_size: tuple[int, int]) -> tuple[int, int]:
    """(W, H) of a ``size`` frame padded at the right or bottom to ``input_size``'s aspect ratio
    (``size`` itself when it already has it)."""
    (w, h), (iw, ih) = size, input_size
    if w * ih >= h * iw:
        return w, -(-w * ih // iw)
    return -(-h * iw // ih), h


def intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """Pinhole matrix K for square pixels and a centred principal point.

    Args:
        width: image width, pixels.
        height: image height, pixels.
        hfov_deg: horizontal field of view between the outer edges of the image, degrees.

    Returns:
        (3, 3) float64 K = [[f, 0, cx], [0, f, cy], [0, 0, 1]], cx = (width - 1)/2, cy = (height - 1)/2.
    """
    if not 0.0 < hfov_deg < 180.0:
        raise ValueError(f"hfov_deg must be in (0, 180), got {hfov_deg}")
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def body_to_camera_rotation(uptilt_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """Rotation of the camera mount.

    Returns:
        (3, 3) R_body_cam: columns are the optical axes (x right, y down, z forward) in the body frame.
    """
    a = math.radians(uptilt_deg)
    # Pitch up = rotation by -uptilt about body y (a positive rotation about y tips x down).
    pitch_up = np.array(
        [[math.cos(a), 0.0, -math.sin(a)], [0.0, 1.0, 0.0], [math.sin(a), 0.0, math.cos(a)]]
    )
    r = math.radians(roll_deg)
    roll = np.array(
        [[math.cos(r), -math.sin(r), 0.0], [math.sin(r), math.cos(r), 0.0], [0.0, 0.0, 1.0]]
    )
    return pitch_up @ _R_BODY_OPTICAL @ roll


def camera_poses(
    pos: np.ndarray, quat: np.ndarray, r_body_cam: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World pose of the camera for N body poses (camera at the centre of mass).

    Args:
        pos: (N, 3) body positions, world frame, m.
        quat: (N, 4) body attitudes x, y, z, w (body -> world).
        r_body_cam: (3, 3) mount rotation from :func:`body_to_camera_rotation`.

    Returns:
        r_world_cam: (N, 3, 3), columns are the optical axes in the world frame.
        t_world_cam: (N, 3) camera centre in the world frame.
    """
    pos = np.asarray(pos, dtype=float).reshape(-1, 3)
    quat = np.asarray(quat, dtype=float).reshape(-1, 4)
    quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    return quat_to_rot(quat) @ r_body_cam, pos.copy()


def world_to_camera(
    points: np.ndarray, r_world_cam: np.ndarray, t_world_cam: np.ndarray
) -> np.ndarray:
    """Express world points in the camera (optical) frame.

    Args:
        points: (..., M, 3) world points; leading dims broadcast against the pose's.
        r_world_cam: (..., 3, 3) camera rotation.
        t_world_cam: (..., 3) camera centre.

    Returns:
        (..., M, 3) points in the optical frame, m (z is the depth along the optical axis).
    """
    t = np.asarray(t_world_cam, dtype=float)[..., None, :]
    return (np.asarray(points, dtype=float) - t) @ np.asarray(r_world_cam, dtype=float)


def camera_to_world(
    points_cam: np.ndarray, r_world_cam: np.ndarray, t_world_cam: np.ndarray
) -> np.ndarray:
    """Inverse of :func:`world_to_camera`; shapes as there."""
    r = np.asarray(r_world_cam, dtype=float)
    return (
        np.asarray(points_cam, dtype=float) @ np.swapaxes(r, -1, -2)
        + np.asarray(t_world_cam)[..., None, :]
    )


def project_points(k: np.ndarray, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection of camera-frame points.

    Args:
        k: (3, 3) intrinsics.
        points_cam: (..., 3) points in the optical frame.

    Returns:
        pixels: (..., 2) float64 (u, v); NaN for points at or behind the camera centre (z <= 0).
        depth: (..., ) float64 z along the optical axis, m.
    """
    p = np.asarray(points_cam, dtype=float)
    z = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        safe = np.where(z > 0, z, np.nan)
        u = k[0, 0] * p[..., 0] / safe + k[0, 1] * p[..., 1] / safe + k[0, 2]
        v = k[1, 1] * p[..., 1] / safe + k[1, 2]
    return np.stack([u, v], axis=-1), z


def unproject_pixels(k: np.ndarray, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Back-project pixels with known depth into the optical frame.

    Args:
        k: (3, 3) intrinsics (zero skew).
        pixels: (..., 2) (u, v).
        depth: (...,) z along the optical axis, m.

    Returns:
        (..., 3) points in the optical frame.
    """
    pix = np.asarray(pixels, dtype=float)
    z = np.asarray(depth, dtype=float)
    x = (pix[..., 0] - k[0, 2]) / k[0, 0] * z
    y = (pix[..., 1] - k[1, 2]) / k[1, 1] * z
    return np.stack([x, y, z], axis=-1)


def gl_projection_matrix(
    k: np.ndarray, width: int, height: int, near: float, far: float
) -> np.ndarray:
    """OpenGL projection matrix that rasterises exactly like K (pixel centres at integer (u, v)).

    Returns:
        (4, 4) row-major matrix mapping OpenGL eye coordinates to clip coordinates.
    """
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    m = np.zeros((4, 4))
    m[0, 0] = 2.0 * fx / width
    m[0, 1] = -2.0 * k[0, 1] / width
    m[0, 2] = (width - 2.0 * cx - 1.0) / width
    m[1, 1] = 2.0 * fy / height
    m[1, 2] = (2.0 * cy + 1.0 - height) / height
    m[2, 2] = -(far + near) / (far - near)
    m[2, 3] = -2.0 * far * near / (far - near)
    m[3, 2] = -1.0
    return m


def gl_view_matrix(r_world_cam: np.ndarray, t_world_cam: np.ndarray) -> np.ndarray:
    """OpenGL view matrix (world -> eye, row-major (4, 4)) of one camera pose."""
    r_gl = np.asarray(r_world_cam, dtype=float) @ _CV_TO_GL
    m = np.eye(4)
    m[:3, :3] = r_gl.T
    m[:3, 3] = -r_gl.T @ np.asarray(t_world_cam, dtype=float)
    return m


def depth_buffer_to_z(buffer: np.ndarray, near: float, far: float) -> np.ndarray:
    """PyBullet's non-linear depth buffer in [0, 1] -> metric depth z along the optical axis."""
    b = np.array(buffer, dtype=np.float64)  # a copy, then in place: far - (far - near) * b
    b *= -(far - near)
    b += far
    return np.divide(far * near, b, out=b)


@dataclass(frozen=True)
class Camera:
    """An FPV camera rigidly mounted at the drone's centre of mass.

    The one object used to render, label and solve PnP: K, the extrinsics and the PyBullet matrices
    all derive from these fields.
    """

    width: int = 320
    """Image width, pixels."""
    height: int = 240
    """Image height, pixels."""
    hfov_deg: float = 90.0
    """Horizontal field of view, degrees."""
    uptilt_deg: float = 20.0
    """Camera pitched up from the body x axis, degrees."""
    roll_deg: float = 0.0
    """Mount roll about the optical axis, degrees (0 for a level mount; jittered for data)."""
    near: float = 0.05
    """Near clipping distance, m."""
    far: float = 200.0
    """Far clipping distance, m."""
    distortion: str = "none"
    """Lens model: ``none``, ``radtan`` or ``fisheye`` (:mod:`.distortion`); K stays the pinhole
    one, and every projection, render and label goes through the lens."""
    dist_coeffs: tuple[float, ...] = ()
    """The lens model's coefficients (OpenCV's order)."""

    def __post_init__(self) -> None:
        if self.width < 8 or self.height < 8:
            raise ValueError(f"camera resolution too small: {self.width}x{self.height}")
        if not 0.0 < self.hfov_deg < 170.0:
            raise ValueError(f"hfov_deg must be in (0, 170), got {self.hfov_deg}")
        if not 0.0 < self.near < self.far:
            raise ValueError(f"need 0 < near < far, got near={self.near}, far={self.far}")
        object.__setattr__(self, "dist_coeffs", tuple(float(c) for c in self.dist_coeffs))
        problem = check_distortion(self.distortion, self.dist_coeffs)
        if problem is not None:
            raise ValueError(problem)

    @classmethod
    def from_params(cls, params: CameraParams, **overrides: float) -> Camera:
        """The camera of a quadrotor file (``QuadParams.camera``), with optional field overrides."""
        kw = dict(width=params.width, height=params.height, hfov_deg=params.hfov_deg)
        kw["uptilt_deg"] = params.uptilt_deg
        kw["distortion"], kw["dist_coeffs"] = params.distortion, tuple(params.dist_coeffs)
        kw.update(overrides)
        return cls(**kw)

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the usual name of the intrinsic matrix
        """(3, 3) intrinsics."""
        return intrinsics(self.width, self.height, self.hfov_deg)

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view between the outer image edges, degrees."""
        return math.degrees(2.0 * math.atan(0.5 * self.height / self.K[1, 1]))

    @property
    def r_body_cam(self) -> np.ndarray:
        """(3, 3) mount rotation; columns are the optical axes in the body frame."""
        return body_to_camera_rotation(self.uptilt_deg, self.roll_deg)

    def pose(self, pos: np.ndarray, quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera pose in the world for one body pose: (R_world_cam (3, 3), t_world_cam (3,))."""
        r, t = camera_poses(pos, quat, self.r_body_cam)
        return r[0], t[0]

    def to_camera(self, points_world: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> (..., 3) optical-frame points, for one body pose."""
        r, t = self.pose(pos, quat)
        pts = np.asarray(points_world, dtype=float)
        return world_to_camera(pts.reshape(-1, 3), r, t).reshape(pts.shape)

    def project(
        self, points_world: np.ndarray, pos: np.ndarray, quat: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Project world points seen from one body pose (through the lens).

        Args:
            points_world: (..., 3) world points.
            pos: (3,) body position; quat: (4,) body attitude x, y, z, w.

        Returns:
            pixels: (..., 2) (u, v), NaN behind the camera; depth: (...,) z in the optical frame.
        """
        px, z = project_points(self.K, self.to_camera(points_world, pos, quat))
        return self.distort(px), z

    @property
    def distorted(self) -> bool:
        """Whether the lens moves pixels (a ``distortion`` other than ``none``)."""
        return self.distortion != "none"

    def distort(self, pixels: np.ndarray) -> np.ndarray:
        """(..., 2) pinhole pixels (of K) -> where this lens images them (a copy if none)."""
        return distort_pixels(self.K, pixels, self.distortion, self.dist_coeffs)

    def undistort(self, pixels: np.ndarray) -> np.ndarray:
        """(..., 2) pixels of this camera's images -> pinhole pixels of K (what PnP takes)."""
        return undistort_pixels(self.K, pixels, self.distortion, self.dist_coeffs)

    def pinhole_cover(self, max_margin: float = 1.0) -> tuple[Camera, tuple[int, int]]:
        """An undistorted camera whose image holds every ray this one sees, and its margin
        (:func:`_pinhole_cover`, computed once per camera)."""
        return _pinhole_cover(self, max_margin)

    def _cover(self, max_margin: float) -> tuple[Camera, tuple[int, int]]:
        """An undistorted camera whose image holds every ray this one sees, and its margin.

        The same focal length and optical axis on a larger image: pixel (u, v) of K is pixel
        (u + mx, v + my) of the cover. The margin is where the undistorted border of this image
        falls, at most ``max_margin`` x the image size per side (rays beyond are not rendered).

        Returns:
            (the cover camera, (mx, my) pixels); (self, (0, 0)) without distortion.
        """
        if not self.distorted:
            return self, (0, 0)
        w, h = self.width, self.height
        t = np.linspace(0.0, 1.0, 64)
        border = np.concatenate([
            np.stack([t * (w - 1), np.zeros_like(t)], 1), np.stack([t * (w - 1), np.full_like(t, h - 1)], 1),
            np.stack([np.zeros_like(t), t * (h - 1)], 1), np.stack([np.full_like(t, w - 1), t * (h - 1)], 1),
        ])  # fmt: skip
        pin = self.undistort(border)
        pin = pin[np.isfinite(pin).all(axis=1)]
        over_x = max(0.0, -pin[:, 0].min(), pin[:, 0].max() - (w - 1)) if len(pin) else 0.0
        over_y = max(0.0, -pin[:, 1].min(), pin[:, 1].max() - (h - 1)) if len(pin) else 0.0
        f = self.K[0, 0]
        widest = f * math.tan(math.radians(84.0)) - 0.5 * w  # keep the cover's FOV under 168°
        mx = int(math.ceil(min(over_x, max_margin * w, widest))) + 2
        my = int(math.ceil(min(over_y, max_margin * h, widest))) + 2
        hfov = math.degrees(2.0 * math.atan(0.5 * (w + 2 * mx) / f))
        cover = Camera(w + 2 * mx, h + 2 * my, hfov, self.uptilt_deg, self.roll_deg, self.near,
                       self.far)  # fmt: skip
        return cover, (mx, my)

    def lens_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) float32 maps for ``cv2.remap``: where each pixel of this camera's image lies in
        the image of :meth:`pinhole_cover` (NaN-free: unreachable pixels map outside it)."""
        cover, (mx, my) = self.pinhole_cover()
        u, v = np.meshgrid(np.arange(self.width, dtype=float), np.arange(self.height, dtype=float))
        pin = self.undistort(np.stack([u, v], axis=-1))
        pin = np.where(np.isfinite(pin), pin, -1e4)
        return (pin[..., 0] + mx).astype(np.float32), (pin[..., 1] + my).astype(np.float32)

    def in_image(self, pixels: np.ndarray) -> np.ndarray:
        """(..., 2) pixels -> (...,) bool, True inside the image area (NaN counts as outside)."""
        u, v = pixels[..., 0], pixels[..., 1]
        with np.errstate(invalid="ignore"):
            return (u >= -0.5) & (u < self.width - 0.5) & (v >= -0.5) & (v < self.height - 0.5)

    def view_matrix(self, pos: np.ndarray, quat: np.ndarray) -> list[float]:
        """PyBullet ``viewMatrix`` (16 floats, column-major) for one body pose."""
        return gl_view_matrix(*self.pose(pos, quat)).flatten(order="F").tolist()

    def projection_matrix(
        self, sample_offset: tuple[float, float] = (0.0, 0.0), rows: tuple[int, int] | None = None
    ) -> list[float]:
        """PyBullet ``projectionMatrix`` (16 floats, column-major) matching K.

        Args:
            sample_offset: where the rasteriser samples pixel (u, v), relative to its centre, in
                pixels; compensated so that pixel (u, v) shows what K projects to (u, v).
                TinyRenderer samples at (u - 0.5, v + 0.5): :data:`TINY_RENDERER_SAMPLE_OFFSET`;
                OpenGL at the centre: :data:`HARDWARE_OPENGL_SAMPLE_OFFSET`.
            rows: (r0, r1) to render only the band of image rows r0:r1 (an image r1 - r0 high);
                None: the whole image.
        """
        r0, r1 = rows or (0, self.height)
        k = self.K
        k[0, 2] += sample_offset[0]
        k[1, 2] += sample_offset[1] - r0
        m = gl_projection_matrix(k, self.width, r1 - r0, self.near, self.far)
        return m.flatten(order="F").tolist()

    def depth_to_z(self, buffer: np.ndarray) -> np.ndarray:
        """Rendered depth buffer (H, W) in [0, 1] -> metric z along the optical axis (H, W)."""
        return depth_buffer_to_z(buffer, self.near, self.far)


@functools.lru_cache(maxsize=64)
def _pinhole_cover(camera: Camera, max_margin: float) -> tuple[Camera, tuple[int, int]]:
    return camera._cover(max_margin)

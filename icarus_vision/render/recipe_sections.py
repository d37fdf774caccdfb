"""Sections of the visual domain-randomisation recipe: one frozen dataclass per TOML table.

Each dataclass below is one table of a recipe file (see :mod:`icarus_vision.render.recipe`); its
fields, with their docstrings and defaults, are the keys of that table. :class:`Recipe` gathers
them. Loading and validation live in :mod:`icarus_vision.render.recipe_toml`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from icarus_vision.render.textures import KINDS

Range = tuple[float, float]


@dataclass(frozen=True)
class SurfaceRanges:
    """Look of a surface: pattern kind, two colours in HSV, texture scale."""

    kinds: tuple[str, ...] = KINDS
    """Patterns to draw from: ``solid``, ``stripes``, ``checker``, ``noise``."""
    kind_weights: tuple[float, ...] = (0.4, 0.2, 0.2, 0.2)
    """Relative weight of each entry of ``kinds``."""
    hue: Range = (0.0, 1.0)
    """Hue of the main colour, in [0, 1] (wraps)."""
    saturation: Range = (0.0, 1.0)
    """Saturation of the main colour."""
    value: Range = (0.2, 1.0)
    """Value (brightness) of the main colour."""
    contrast: Range = (0.1, 0.6)
    """Value difference between the second and the main colour (second is darker or lighter)."""
    tile: Range = (0.2, 2.0)
    """Texture tile size: metres on gates and ground, pixels on the sky."""


@dataclass(frozen=True)
class GateRanges(SurfaceRanges):
    """Gate look. Colours come from ``palette`` (jittered) or, with ``random_color_prob``, from the
    HSV ranges inherited from :class:`SurfaceRanges`."""

    kind_weights: tuple[float, ...] = (0.55, 0.2, 0.15, 0.1)
    """Relative weight of each entry of ``kinds``."""
    palette: tuple[tuple[float, float, float], ...] = ((1.0, 0.35, 0.0),)
    """Typical race-gate RGB colours in [0, 1]."""
    palette_jitter: float = 0.08
    """Uniform jitter added to each RGB channel of a palette colour."""
    random_color_prob: float = 0.25
    """Probability of an HSV-random colour instead of a palette one."""
    same_look_prob: float = 0.7
    """Probability that all gates of a frame share one look (else one look per gate)."""
    tile: Range = (0.1, 0.5)
    """Texture tile size on the bars, m."""
    frame_width: Range = (0.06, 0.16)
    """Rendered bar width, m."""
    depth: Range = (0.0, 0.0)
    """Bar depth along the passage, m; 0: as deep as wide (a printed panel is a few cm deep)."""
    trim_prob: float = 0.0
    """Probability that a scene's gates have a trim lining the opening (an LED strip or padding,
    its inner edge the opening's), of width ``trim_width`` and a colour of ``trim_palette``."""
    trim_width: Range = (0.02, 0.08)
    """Width of the trim, m."""
    trim_led_prob: float = 0.6
    """Probability that the trim is an LED strip: drawn at full brightness whatever the light,
    with a glow around it."""
    trim_palette: tuple[tuple[float, float, float], ...] = (
        (1.0, 1.0, 1.0), (0.3, 1.0, 0.8), (0.2, 0.6, 1.0), (1.0, 0.2, 0.2), (0.3, 1.0, 0.3),
    )  # fmt: skip
    """Trim / LED colours, RGB in [0, 1] (jittered by ``palette_jitter``)."""


@dataclass(frozen=True)
class LightRanges:
    """The directional light."""

    elevation_deg: Range = (20.0, 90.0)
    """Light elevation above the horizon, degrees."""
    azimuth_deg: Range = (0.0, 360.0)
    """Light azimuth about world z, degrees."""
    ambient: Range = (0.35, 0.8)
    """Ambient coefficient."""
    diffuse: Range = (0.1, 0.6)
    """Diffuse coefficient."""
    specular: Range = (0.0, 0.3)
    """Specular coefficient."""
    color_jitter: float = 0.1
    """Each RGB channel of the white light is scaled by 1 - U(0, color_jitter)."""
    shadow_prob: float = 0.3
    """Probability of rendering shadows: objects on objects (TinyRenderer's shadow map) and on the
    ground (:mod:`icarus_vision.render.shadows`)."""


EXTRA_SHAPES = ("person", "tree", "net", "banner", "screen")
"""Shapes ``DistractorRanges.extra_shapes`` may name."""


@dataclass(frozen=True)
class DistractorRanges:
    """Non-gate objects around the gates."""

    count: tuple[int, int] = (0, 8)
    """Number of distractors per scene, inclusive range."""
    gate_like_prob: float = 0.3
    """Probability that a distractor is gate-like: an arch or a non-square frame in gate colours."""
    distance: Range = (1.5, 12.0)
    """Horizontal distance from a randomly chosen gate's centre, m."""
    size: Range = (0.2, 2.0)
    """Typical extent, m."""
    height: Range = (0.0, 3.0)
    """Height of the object's centre above the ground, m (raised so it never sinks)."""
    extra_prob: float = 0.0
    """Probability that a distractor that is not gate-like is one of ``extra_shapes``."""
    extra_shapes: tuple[str, ...] = ("person", "tree", "net", "banner")
    """Shapes of the later recipes: ``person`` (a body and a head, 1.5-1.9 m), ``tree`` (a trunk
    and a crown), ``net`` (a fence of thin bars in a grid), ``banner`` (a thin printed board),
    ``screen`` (a filled rectangle in a bezel, 0.4-2.5 m wide, square or not: monitors, windows,
    doors; not in the default, which the older recipes keep)."""


@dataclass(frozen=True)
class CameraJitter:
    """Camera parameters around the quadrotor's nominal camera."""

    hfov_deg: Range = (80.0, 110.0)
    """Horizontal field of view, degrees."""
    uptilt_deg: Range = (10.0, 35.0)
    """Camera uptilt, degrees."""
    roll_deg: Range = (-3.0, 3.0)
    """Mount roll about the optical axis, degrees."""
    distortion_prob: float = 0.0
    """Probability that a scene's camera has a lens (render/distortion.py): fisheye with
    ``fisheye_prob``, else radial-tangential."""
    fisheye_prob: float = 0.5
    """Share of the lenses that are fisheye."""
    radtan_k1: Range = (-0.35, 0.05)
    """Radial-tangential k1 (negative: barrel, as wide-angle FPV lenses)."""
    radtan_k2: Range = (0.0, 0.12)
    """Radial-tangential k2 (p1, p2 are drawn within ±0.002)."""
    fisheye_k1: Range = (-0.08, 0.08)
    """Fisheye k1 (k2 within ±0.02, k3 = k4 = 0)."""
    aspect_prob: float = 0.0
    """Probability that a scene is seen by a camera of another aspect ratio (one of ``aspects``),
    as large as fits in the dataset's frame, letterboxed into it with the detector's grey at the
    right or bottom (what the detector reads from such a camera)."""
    aspects: tuple[float, ...] = (1.0, 1.5, 1.778, 2.0)
    """Width / height of those cameras (square FPV frames, 3:2 stills, 16:9, wide fisheye)."""


@dataclass(frozen=True)
class SensorRanges:
    """Image degradations applied after rendering."""

    noise_std: Range = (0.0, 6.0)
    """Standard deviation of additive Gaussian noise, 8-bit levels."""
    gamma: Range = (0.8, 1.25)
    """Gamma applied to the whole image."""
    gain: Range = (0.85, 1.15)
    """Brightness gain."""
    blur_prob: float = 0.2
    """Probability of a Gaussian blur."""
    blur_sigma_px: Range = (0.4, 1.2)
    """Blur standard deviation, pixels."""
    exposure_ev: Range = (0.0, 0.0)
    """Exposure change, stops (the image times 2^ev, clipped: under- and over-exposure)."""
    color_cast: float = 0.0
    """Each colour channel is scaled by 1 + U(-color_cast, color_cast)."""
    vignette_prob: float = 0.0
    """Probability of vignetting."""
    vignette: Range = (0.2, 0.6)
    """Brightness lost at the image corners (radial, quadratic)."""
    motion_blur_prob: float = 0.0
    """Probability of motion blur (a line kernel in a random direction)."""
    motion_blur_px: Range = (3.0, 12.0)
    """Length of the motion blur, pixels."""
    defocus_prob: float = 0.0
    """Probability of defocus (a disc kernel)."""
    defocus_px: Range = (1.0, 3.0)
    """Radius of the defocus disc, pixels."""
    bloom_prob: float = 0.0
    """Probability of bloom: the brightest parts of the image glow."""
    bloom: Range = (0.3, 1.0)
    """Strength of the bloom."""
    jpeg_prob: float = 0.0
    """Probability of JPEG compression."""
    jpeg_quality: Range = (30.0, 95.0)
    """JPEG quality."""


@dataclass(frozen=True)
class HallRanges:
    """Indoor scenes: walls and a ceiling around the track, ceiling lights, trusses, banners."""

    prob: float = 0.0
    """Probability that a scene is indoors."""
    height: Range = (5.0, 10.0)
    """Ceiling height, m."""
    margin: Range = (2.0, 10.0)
    """Distance from the outermost gates to the walls, m."""
    lights: tuple[int, int] = (4, 16)
    """Ceiling light panels, inclusive range (drawn at full brightness, with a glow)."""
    truss_prob: float = 0.5
    """Probability of trusses: rows of bars under the ceiling."""
    banners: tuple[int, int] = (0, 6)
    """Printed banners on the walls, inclusive range."""
    floor_gloss_prob: float = 0.0
    """Probability that a hall's floor is glossy: it reflects the gates, walls, lights and
    distractors above it (a second render of the scene, mirrored through the floor)."""
    floor_reflectivity: Range = (0.15, 0.5)
    """Share of a glossy floor's colour taken from the reflection, in [0, 1]."""
    floor_blur_px: Range = (0.0, 1.5)
    """Gaussian blur sigma of the reflection, pixels (a slightly rough gloss)."""


@dataclass(frozen=True)
class TrackRanges:
    """Random track layouts (:func:`icarus_vision.sim.random_track.random_track`); one per scene."""

    gates: tuple[int, int] = (3, 10)
    """Number of gates per track, inclusive range."""
    spacing: Range = (4.0, 8.0)
    """Distance between consecutive gates, m."""
    max_turn_deg: float = 60.0
    """Largest change of direction from one gate to the next, degrees."""
    height: Range = (1.0, 3.0)
    """Height of the gate centres above the ground, m."""
    size: Range = (1.0, 1.0)
    """Side of the square inner opening, m (one draw per track)."""


@dataclass(frozen=True)
class PoseRanges:
    """Racing-like camera poses: the drone on its way to a gate (:mod:`icarus_vision.render.poses`)."""

    distance: Range = (0.5, 15.0)
    """Distance from the camera to the centre of the gate it approaches, m (drawn uniformly)."""
    racing_line_prob: float = 0.5
    """Probability of a pose on the straight line from the previous gate (or the start) to the
    target gate, offset by ``lateral_std``; otherwise the pose lies in the approach cone below."""
    lateral_std: float = 0.5
    """Standard deviation of the sideways and vertical offsets from the racing line, m."""
    approach_azimuth_deg: Range = (-50.0, 50.0)
    """Approach cone: horizontal angle between the gate's passage axis and the camera's bearing
    from the gate (on the approach side), degrees."""
    approach_elevation_deg: Range = (-10.0, 30.0)
    """Approach cone: elevation of the camera seen from the gate's centre, degrees."""
    aim_offset_deg: Range = (0.0, 40.0)
    """Angle between the direction the camera is aimed at and the gate's centre, degrees; large
    values put the gate at or across the image border."""
    roll_deg: Range = (-45.0, 45.0)
    """Body roll, degrees."""
    pitch_deg: Range = (-45.0, 45.0)
    """Body pitch limits (positive: nose down), degrees; the pitch that aims the camera is clipped
    to them."""
    height: Range = (0.3, 6.0)
    """Allowed camera height above the ground, m; positions are clamped into it."""
    no_gate_prob: float = 0.1
    """Share of frames drawn to show no gate at all (the camera looks away from every gate)."""


@dataclass(frozen=True)
class DatasetSettings:
    """Layout of a generated dataset (``icarus-vision gen-dataset``)."""

    width: int = 320
    """Image width, pixels."""
    height: int = 240
    """Image height, pixels."""
    splits: tuple[float, float, float] = (0.8, 0.1, 0.1)
    """Fractions of the images in the ``train``, ``val`` and ``test`` splits (sum 1)."""
    shard_size: int = 100
    """Images per shard, the unit of parallel work, checksums and resuming."""
    frames_per_scene: int = 20
    """Frames rendered from one scene (one random track, look and camera) before the next."""


@dataclass(frozen=True)
class Recipe:
    """A visual domain-randomisation recipe (one per dataset)."""

    name: str = "default"
    """Short identifier, recorded in the dataset manifest."""
    gates: GateRanges = field(default_factory=GateRanges)
    """Gate colour, texture and frame width."""
    ground: SurfaceRanges = field(default_factory=SurfaceRanges)
    """Ground colour and texture (``tile`` in metres)."""
    sky: SurfaceRanges = field(default_factory=lambda: SurfaceRanges(tile=(8.0, 80.0)))
    """Background colour and texture (``tile`` in pixels)."""
    light: LightRanges = field(default_factory=LightRanges)
    """Light direction, strengths and shadows."""
    distractors: DistractorRanges = field(default_factory=DistractorRanges)
    """Distractor objects."""
    camera: CameraJitter = field(default_factory=CameraJitter)
    """Camera FOV, uptilt and roll jitter."""
    sensor: SensorRanges = field(default_factory=SensorRanges)
    """Sensor noise."""
    hall: HallRanges = field(default_factory=HallRanges)
    """Indoor scenes (none unless ``hall.prob`` > 0)."""
    tracks: TrackRanges = field(default_factory=TrackRanges)
    """Random track layouts."""
    poses: PoseRanges = field(default_factory=PoseRanges)
    """Camera poses."""
    dataset: DatasetSettings = field(default_factory=DatasetSettings)
    """Resolution, splits and sharding of a generated dataset."""

    def to_dict(self) -> dict:
        """Plain nested dict (JSON-ready) of the resolved recipe. A section's keys added after
        the first recipes (:data:`LATER_KEYS`) are left out while all of them keep their defaults
        (which switch nothing on), and so is a default ``hall``, so an older recipe keeps the
        identity its datasets were written with."""
        d = asdict(self)
        if d["hall"] == asdict(HallRanges()):
            del d["hall"]
        for section, keys in LATER_KEYS.items():
            default = asdict(type(getattr(self, section))())
            if section in d and all(d[section][k] == default[k] for k in keys):
                for k in keys:
                    del d[section][k]
        return d


LATER_KEYS = {
    "gates": ("depth", "trim_prob", "trim_width", "trim_led_prob", "trim_palette"),
    "distractors": ("extra_prob", "extra_shapes"),
    "camera": ("distortion_prob", "fisheye_prob", "radtan_k1", "radtan_k2", "fisheye_k1",
               "aspect_prob", "aspects"),
    "sensor": ("exposure_ev", "color_cast", "vignette_prob", "vignette", "motion_blur_prob",
               "motion_blur_px", "defocus_prob", "defocus_px", "bloom_prob", "bloom", "jpeg_prob",
               "jpeg_quality"),
    "hall": ("floor_gloss_prob", "floor_reflectivity", "floor_blur_px"),
}  # fmt: skip
"""Keys added after the first recipes, by section: with gates-v3 (real gates and places), and the
hall's with gates-v4 (glossy floors)."""

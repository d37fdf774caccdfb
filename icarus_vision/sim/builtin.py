"""Built-in named tracks (TOML files shipped in ``sim/tracks/``) and name-or-path resolution."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from icarus_vision.sim.track import Track, TrackError, load_track, track_from_dict

DEFAULT_TRACK = "grand-prix"
BUILTIN_TRACKS = (
    "single-gate",
    "three-gates",
    "five-gates",
    "ten-gates",
    "grand-prix",
    "split-s",
    "hairpin",
)


def builtin_track(name: str) -> Track:
    """Load a built-in track by name; unknown names raise TrackError listing the built-in names."""
    if name not in BUILTIN_TRACKS:
        raise TrackError(f"unknown track {name!r}; built-in tracks: {', '.join(BUILTIN_TRACKS)}")
    import tomllib

    text = resources.files("icarus_vision.sim").joinpath(f"tracks/{name}.toml").read_text()
    return track_from_dict(tomllib.loads(text), source=f"<builtin:{name}>")


def resolve_track(spec: str | Path | Track | None) -> Track:
    """A Track from a built-in name, a TOML path, or a Track (None gives the default track)."""
    if spec is None:
        return builtin_track(DEFAULT_TRACK)
    if isinstance(spec, Track):
        return spec
    s = str(spec)
    if s in BUILTIN_TRACKS:
        return builtin_track(s)
    if s.endswith(".toml") or "/" in s or Path(s).exists():
        return load_track(s)
    raise TrackError(
        f"unknown track {s!r}; built-in tracks: {', '.join(BUILTIN_TRACKS)} (or a .toml path)"
    )

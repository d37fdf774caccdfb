from __future__ import annotations

import pytest

from icarus_vision.sim.quad import QuadError, QuadParams, load_quad, save_quad


def test_default_racing_quad():
    q = QuadParams()
    assert 0.4 <= q.mass <= 0.6 and q.thrust_to_weight >= 3
    assert q.camera.width == 320 and q.camera.height == 240
    assert q.thrust_max == pytest.approx(4 * 0.5 * 9.81)
    # hover action balances gravity
    assert (q.hover_thrust_action + 1) / 2 * q.thrust_max == pytest.approx(q.mass * 9.81)


def test_load_partial_file_takes_defaults(tmp_path):
    p = tmp_path / "q.toml"
    p.write_text('name = "heavy"\nmass = 0.8\n[camera]\nwidth = 640\n')
    q = load_quad(p)
    assert q.name == "heavy" and q.mass == 0.8 and q.camera.width == 640
    assert q.inertia == QuadParams().inertia and q.camera.height == 240


def test_round_trip(tmp_path):
    q = QuadParams(name="x", mass=0.7, drag=(0.1, 0.2, 0.3))
    save_quad(q, tmp_path / "q.toml")
    assert load_quad(tmp_path / "q.toml") == q


@pytest.mark.parametrize(
    "text, match",
    [
        ("mass = 0.5\nwings = 2\n", "unknown key"),
        ("[camera]\nzoom = 2\n", r"\[camera\]: zoom: unknown key"),
        ("mass = -1.0\n", "mass must be > 0"),
        ("mass = nan\n", "mass: must be a finite number"),
        ("thrust_to_weight = 0.9\n", "thrust_to_weight must be > 1"),
        ("inertia = [0.1, 0.1]\n", "inertia: must have 3 values"),
        ("drag = [0.1, -0.1, 0.1]\n", "drag must be finite and >= 0"),
        ("[camera]\nwidth = 3\n", "camera.width"),
        ("mass = ", "not a valid TOML"),
    ],
)
def test_malformed_quad_files_are_refused(tmp_path, text, match):
    p = tmp_path / "bad_quad.toml"
    p.write_text(text)
    with pytest.raises(QuadError, match=match) as e:
        load_quad(p)
    assert "bad_quad.toml" in str(e.value)


def test_missing_quad_file(tmp_path):
    with pytest.raises(QuadError, match="not found"):
        load_quad(tmp_path / "missing.toml")

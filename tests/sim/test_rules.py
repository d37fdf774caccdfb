"""Gate passage, frame collision and crash rules: pure functions and through both backends."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icarus_vision.sim import rules
from icarus_vision.sim.dynamics import QuadState, rpy_to_quat
from icarus_vision.sim.pybullet_backend import gate_bar_boxes
from icarus_vision.sim.quad import QuadParams
from icarus_vision.sim.track import Gate, Track


def passage(p0, p1, pos=(5.0, 0.0, 2.0), yaw_deg=0.0, size=1.0):
    return bool(
        rules.gate_passage(
            np.array([p0], float), np.array([p1], float), np.array([pos], float),
            np.array([math.radians(yaw_deg)]), np.array([size]),
        )[0]
    )  # fmt: skip


def test_passage_cases():
    assert passage((4.9, 0, 2), (5.1, 0, 2)), "straight through"
    assert passage((4.9, 0.45, 2.45), (5.1, 0.45, 2.45)), "inside near a corner"
    assert not passage((4.9, 0.51, 2), (5.1, 0.51, 2)), "just outside the opening"
    assert not passage((4.9, 0, 2.51), (5.1, 0, 2.51)), "just above the opening"
    assert not passage((5.1, 0, 2), (4.9, 0, 2)), "wrong direction"
    assert not passage((4.0, 0, 2), (4.9, 0, 2)), "not yet at the plane"
    assert passage((4.99, 0, 2), (5.0, 0, 2)), "landing exactly on the plane counts (x >= 0)"
    # rotated gate: passage direction +y
    assert passage((0, -0.1, 2), (0, 0.1, 2), pos=(0, 0, 2), yaw_deg=90)
    assert not passage((0, 0.1, 2), (0, -0.1, 2), pos=(0, 0, 2), yaw_deg=90)
    # moved gate
    assert passage((-3.1, 7, 1), (-2.9, 7, 1), pos=(-3, 7, 1))
    assert not passage((4.9, 0, 2), (5.1, 0, 2), pos=(-3, 7, 1))
    # crossing point interpolated, not the end point: enters inside, ends outside the square
    assert passage((4.9, 0.4, 2), (5.3, 0.8, 2))


def test_bar_distance_matches_built_boxes():
    """The analytic bars (rules) and the PyBullet boxes describe the same frame."""
    size, fw = 1.2, 0.15
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1.0, 1.0, (2000, 3))
    d_rules = rules.bar_distance_local(pts, np.full(2000, size), np.full(2000, fw))
    d_boxes = np.full(2000, np.inf)
    for half, centre in gate_bar_boxes(size, fw):
        q = np.maximum(np.abs(pts - centre) - half, 0)
        d_boxes = np.minimum(d_boxes, np.linalg.norm(q, axis=1))
    np.testing.assert_allclose(d_rules, d_boxes, atol=1e-12)
    assert (
        rules.bar_distance_local(np.array([[0, 0, 0]]), np.array([size]), np.array([fw]))[0] > 0.5
    )
    assert (
        rules.bar_distance_local(
            np.array([[0, 0, size / 2 + fw / 2]]), np.array([size]), np.array([fw])
        )[0]
        == 0
    )


def fly_straight(make, start, vel, track, steps=60):
    """Teleport a drone to ``start`` moving at ``vel`` with hover thrust and fly level."""
    env = make(config=None, track=track)
    env.reset(seed=0)
    q = env.config.quad
    st = QuadState.zeros(1)
    st.pos[0], st.vel[0] = start, vel
    yaw = math.atan2(vel[1], vel[0])
    st.quat[:] = rpy_to_quat(np.array([[0, 0, yaw]]))
    st.thrust[0] = q.mass * 9.81
    env.core.taken_off[0] = True
    env.set_state(st)
    info = {}
    for _ in range(steps):
        _, _, term, trunc, info = env.step([q.hover_thrust_action, 0, 0, 0])
        if term or trunc:
            break
    return info


GATE_TRACK = Track("one", (Gate((5.0, 0.0, 2.0)),), (0.0, 0.0, 0.2))


def test_straight_through_passes(make):
    info = fly_straight(make, (3.0, 0, 2.0), (5.0, 0, 0), GATE_TRACK)
    assert info["gates_passed"] == 1 and info["all_gates_passed"] and not info["crashed"]


def test_just_outside_opening_does_not_pass(make):
    # centre passes 0.9 m to the side: clear of the bar (0.6 + 0.15 radius) but outside the opening
    info = fly_straight(make, (3.0, 0.9, 2.0), (5.0, 0, 0), GATE_TRACK, steps=40)
    assert info["gates_passed"] == 0 and not info["crashed"]


def test_grazing_a_bar_is_a_crash(make):
    # centre 0.45 m off-axis: the 0.15 m sphere overlaps the side bar (inner face at 0.5 m)
    info = fly_straight(make, (3.0, 0.45, 2.0), (5.0, 0, 0), GATE_TRACK)
    assert info["crashed"] and info["crash_reason"] == "gate_collision"


def test_wrong_direction_does_not_pass(make):
    info = fly_straight(make, (7.0, 0, 2.0), (-5.0, 0, 0), GATE_TRACK, steps=40)
    assert info["gates_passed"] == 0 and not info["crashed"]


def test_rotated_and_moved_gate(make):
    track = Track("rot", (Gate((2.0, 6.0, 1.5), yaw_deg=90.0),), (0.0, 0.0, 0.2))
    info = fly_straight(make, (2.0, 4.0, 1.5), (0, 5.0, 0), track)
    assert info["all_gates_passed"]
    info = fly_straight(make, (0.0, 6.0, 1.5), (5.0, 0, 0), track, steps=30)  # across its axis
    assert info["gates_passed"] == 0


def test_gate_flown_twice_in_opposite_directions(make):
    g = (5.0, 0.0, 2.0)
    track = Track(
        "twice", (Gate(g, 0.0), Gate((9.0, 0.0, 2.0), 0.0), Gate(g, 180.0)), (0.0, 0.0, 0.2)
    )
    env = make(track=track)
    env.reset(seed=0)
    assert len(track.physical_gates()) == 2
    info = fly_straight(make, (3.0, 0, 2.0), (8.0, 0, 0), track, steps=60)
    assert info["gates_passed"] == 2  # out through gate 0 and gate 1
    # then come back through gate 0 the other way
    env = make(track=track)
    env.reset(seed=0)
    env.core.target[0] = 2
    q = env.config.quad
    st = QuadState.zeros(1)
    st.pos[0], st.vel[0] = (7.0, 0, 2.0), (-5.0, 0, 0)
    st.quat[:] = rpy_to_quat(np.array([[0, 0, math.pi]]))
    st.thrust[0] = q.mass * 9.81
    env.core.taken_off[0] = True
    env.set_state(st)
    for _ in range(40):
        _, _, term, _, info = env.step([q.hover_thrust_action, 0, 0, 0])
        if term:
            break
    assert info["gates_passed"] == 3 and info["all_gates_passed"] and not info["crashed"]


def test_ground_after_takeoff_and_bounds_are_crashes(make):
    q = QuadParams()
    env = make(track="single-gate")
    env.reset(seed=0)
    for _ in range(100):  # sitting on the ground before take-off is not a crash
        _, _, term, _, info = env.step([-1, 0, 0, 0])
    assert not term and not info["crashed"]
    for _ in range(40):  # climb about a metre, then cut the motors
        _, _, term, _, info = env.step([-0.3, 0, 0, 0])
    assert not term
    for _ in range(200):
        _, _, term, _, info = env.step([-1, 0, 0, 0])
        if term:
            break
    assert info["crash_reason"] == "ground"
    info = fly_straight(make, (0.0, 0.0, 2.0), (0, 20.0, 0), builtin_single(), steps=50)
    assert info["crash_reason"] == "out_of_bounds"
    assert q.radius > 0


def builtin_single():
    from icarus_vision.sim.builtin import builtin_track

    return builtin_track("single-gate")


@pytest.mark.parametrize("radius_margin, hit", [(-0.01, True), (0.01, False)])
def test_frame_collision_threshold(radius_margin, hit):
    r = 0.15
    # point beside the right bar's outer face (bar spans |y| in [0.5, 0.6])
    p = np.array([[0.0, -(0.6 + r + radius_margin), 0.0]])
    got = rules.frame_collision(
        p,
        r,
        np.zeros((1, 1, 3)),
        np.zeros((1, 1)),
        np.ones((1, 1)),
        np.full((1, 1), 0.1),
        np.ones((1, 1), bool),
    )
    assert bool(got[0]) == hit


def test_crossing_fraction_is_where_in_the_step_the_plane_was_crossed():
    """A step 0.1 m short of a gate 30° turned and 0.3 m beyond it crosses at a quarter."""
    yaw = np.radians(30.0)
    normal = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    gate = np.array([[1.0, 2.0, 3.0]])
    p0, p1 = gate - 0.1 * normal, gate + 0.3 * normal + [[0.0, 0.0, 0.05]]
    passed, _, fraction = rules.gate_crossing(p0, p1, gate, np.array([yaw]), np.ones(1))
    assert passed[0] and fraction[0] == pytest.approx(0.25)


def test_crossing_centrality_falls_from_the_centre_to_the_edge():
    """1 through the centre, 1 − max(|y|, |z|) / half the opening elsewhere, 0 without a passage."""
    p0 = np.array([[4.9, 0, 2], [4.9, 0.25, 2.1], [4.9, 0.1, 2.45], [4.9, 0.6, 2], [4.0, 0, 2]])
    p1 = p0 + [0.2, 0, 0]
    gate = np.tile([5.0, 0, 2], (5, 1))
    passed, central, fraction = rules.gate_crossing(p0, p1, gate, np.zeros(5), np.ones(5))
    assert passed.tolist() == [True, True, True, False, False]
    assert central == pytest.approx([1.0, 0.5, 0.1, 0.0, 0.0])
    assert fraction == pytest.approx([0.5, 0.5, 0.5, 1.0, 1.0])  # 0.1 of a 0.2 m step; 1: none
    assert passed.tolist() == rules.gate_passage(p0, p1, gate, np.zeros(5), np.ones(5)).tolist()


def test_trail_collision_takes_a_radius_per_drone():
    """Two drones at the same point 0.12 m beside a bar: only the one with the larger sphere
    touches it."""
    p = np.tile([0.0, -0.72, 0.0], (2, 1))
    trail = np.stack([p, p])  # (S=2, N=2, 3)
    gates = dict(gate_pos=np.zeros((2, 1, 3)), gate_cos=np.ones((2, 1)), gate_sin=np.zeros((2, 1)),
                 size=np.ones((2, 1)), frame_width=np.full((2, 1), 0.1), reach=np.full((2, 1), 1.0),
                 gate_mask=np.ones((2, 1), bool))  # fmt: skip
    hit = rules.trail_frame_collision(trail, np.array([0.1, 0.15]), **gates)
    assert hit.tolist() == [False, True]
    assert rules.trail_frame_collision(trail, 0.15, **gates).tolist() == [True, True]

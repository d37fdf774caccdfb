"""Reward terms on hand-made states, and the racing-line preset's shape."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.sim.config import PROGRESS_REWARD, RACING_LINE_REWARD, EnvConfig
from icarus_vision.sim.dynamics import quat_to_rot, rpy_to_quat
from icarus_vision.sim.reward import (
    camera_gate_angle,
    compute_reward,
    cost_action_change,
    cost_perception,
    path_position,
    reward_line,
    reward_path,
)
from icarus_vision.sim.vec_env import BatchedRacingVecEnv


def test_line_progress_is_the_step_along_the_segment():
    seg_from = np.array([[0.0, 0, 2], [0, 0, 2]])
    gate = np.array([[10.0, 0, 2], [10, 0, 2]])
    p0 = np.array([[1.0, 0, 2], [1, 3, 2]])
    p1 = np.array([[2.0, 0, 2], [1, 2, 2]])  # 1 m along; 1 m sideways toward the line
    assert reward_line(p0, p1, seg_from, gate) == pytest.approx([1.0, 0.0])


def test_line_progress_falls_back_to_the_gate_on_a_hairpin():
    """A gate flown straight back: the segment has no length, so progress is toward the gate."""
    gate = np.array([[5.0, 0, 2]])
    p0, p1 = np.array([[7.0, 0, 2]]), np.array([[6.0, 0, 2]])
    assert reward_line(p0, p1, gate.copy(), gate) == pytest.approx([1.0])


def test_camera_angle_zero_when_the_gate_is_on_the_optical_axis():
    uptilt = np.radians(20.0)
    rot = quat_to_rot(rpy_to_quat(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.pi / 2]])))
    on_axis = np.array([[np.cos(uptilt), 0.0, np.sin(uptilt)], [1.0, 0.0, 0.0]])
    angle = camera_gate_angle(rot, on_axis * 5.0, uptilt)
    assert angle[0] == pytest.approx(0.0, abs=1e-9)
    assert angle[1] == pytest.approx(np.arccos(np.cos(uptilt) * 0.0), abs=1e-9)  # gate to the right
    assert cost_perception(np.radians([10.0, 50.0]), np.radians(30.0)) == pytest.approx(
        [0.0, np.radians(20.0)]
    )


def test_action_change_is_squared_and_free_on_the_first_step():
    a = np.array([[0.5, 0, 0, 0], [0.5, 0, 0, 0]])
    prev = np.array([[0.0, 0, 0, 0], [np.nan] * 4])
    assert cost_action_change(a, prev) == pytest.approx([0.25, 0.0])


def _terms(cfg, **over):
    n = 1
    base = dict(
        prev_dist=np.array([3.0]), dist=np.array([3.0]), passed=np.zeros(n, bool),
        crashed=np.zeros(n, bool), rpy=np.zeros((n, 3)), vel=np.zeros((n, 3)),
        to_gate=np.array([[3.0, 0, 0]]), dt=0.02, line=np.zeros(n),
        camera_angle=np.array([0.9]), omega=np.array([[0.0, 0, 1.0]]),
        action_change=np.array([0.1]),
    )  # fmt: skip
    base.update(over)
    return compute_reward(cfg, **base)


def test_racing_line_preset_pays_nothing_for_hovering_near_a_gate():
    reward, terms = _terms(RACING_LINE_REWARD)
    assert set(terms) == {"gate", "crash", "line", "perception", "rates", "action_change"}
    assert all(v[0] <= 0 for v in terms.values())
    assert reward[0] < 0
    reward, terms = _terms(RACING_LINE_REWARD, line=np.array([0.2]), camera_angle=np.array([0.1]))
    assert terms["line"][0] == pytest.approx(0.2) and terms["perception"][0] == 0.0
    assert reward[0] > 0.19  # smoothness costs are small beside progress


def test_progress_preset_terms_unchanged():
    _, terms = _terms(PROGRESS_REWARD, dist=np.array([2.5]))
    assert list(terms) == ["progress", "gate", "crash", "attitude"]
    assert terms["progress"][0] == pytest.approx(0.5)


def test_env_logs_each_racing_line_term():
    cfg = EnvConfig(random_tracks=True, num_gates=3, reward=RACING_LINE_REWARD)
    env = BatchedRacingVecEnv(4, cfg, info_mode="full")
    env.seed(0)
    env.reset()
    _, reward, _, infos = env.step(np.tile([0.6, 0.1, 0.0, 0.0], (4, 1)))
    terms = infos[0]["reward_terms"]
    assert {"line", "perception", "rates", "action_change"} <= set(terms)
    assert terms["action_change"] == 0.0  # no previous action on the first step
    _, reward2, _, infos = env.step(np.tile([0.2, 0.1, 0.0, 0.0], (4, 1)))
    assert infos[0]["reward_terms"]["action_change"] == pytest.approx(-2e-3 * 0.16)
    assert reward2[0] == pytest.approx(sum(infos[0]["reward_terms"].values()), rel=1e-5)


def test_line_progress_stops_at_the_gate_plane():
    """Flying on past the gate beside it earns nothing; coming back costs what was earned."""
    seg_from, gate = np.array([[0.0, 0, 2]]), np.array([[10.0, 0, 2]])
    past = reward_line(np.array([[10.5, 3, 2]]), np.array([[12.0, 3, 2]]), seg_from, gate)
    assert past == pytest.approx([0.0])
    across = reward_line(np.array([[9.5, 3, 2]]), np.array([[11.0, 3, 2]]), seg_from, gate)
    assert across == pytest.approx([0.5])
    back = reward_line(np.array([[11.0, 3, 2]]), np.array([[9.0, 3, 2]]), seg_from, gate)
    assert back == pytest.approx([-1.0])


def test_center_term_pays_a_central_passage_only_when_weighted():
    from dataclasses import replace

    cfg = replace(RACING_LINE_REWARD, center=5.0)
    _, terms = _terms(cfg, passed=np.array([True]), centrality=np.array([0.8]))
    assert terms["center"][0] == pytest.approx(4.0)
    _, terms = _terms(RACING_LINE_REWARD, passed=np.array([True]), centrality=np.array([0.8]))
    assert "center" not in terms


def test_crossing_alignment_is_the_cosine_to_the_passage_direction():
    from icarus_vision.sim.rules import crossing_alignment

    p0 = np.zeros((4, 3))
    p1 = np.array([[0.2, 0, 0], [0.1, 0.1 * np.sqrt(3), 0], [0.1, 0.1, 0], [0.0, 0, 0]])
    yaw = np.array([0.0, 0.0, np.pi / 4, 0.0])
    assert crossing_alignment(p0, p1, yaw) == pytest.approx([1.0, 0.5, 1.0, 0.0])


def test_align_term_pays_a_straight_passage_only_when_weighted():
    from dataclasses import replace

    cfg = replace(RACING_LINE_REWARD, align=4.0)
    _, terms = _terms(cfg, passed=np.array([True]), alignment=np.array([0.5]))
    assert terms["align"][0] == pytest.approx(2.0)
    _, terms = _terms(RACING_LINE_REWARD, passed=np.array([True]), alignment=np.array([0.5]))
    assert "align" not in terms


@pytest.mark.parametrize(("vel", "expected"), [((5.0, 0.0), 4.0), ((5.0, 5.0), 4.0 / np.sqrt(2))])
def test_env_pays_the_align_term_by_the_crossing_angle(vel, expected):
    """Straight through the gate earns the whole align weight, 45° off its normal cos 45° of it."""
    from dataclasses import replace

    from icarus_vision.sim.track import Gate, Track

    track = Track(name="one", gates=(Gate((2.0, 0.0, 1.0)),), start_pos=(0.0, 0.0, 1.0))
    cfg = EnvConfig(track=track, reward=replace(RACING_LINE_REWARD, align=4.0))
    env = BatchedRacingVecEnv(1, cfg, info_mode="full")
    env.seed(0)
    env.reset()
    env.state.pos[0] = [1.95, -0.05 * vel[1] / vel[0], 1.0]
    env.state.vel[0] = [vel[0], vel[1], 0.0]
    _, _, done, infos = env.step(np.array([[0.0, 0.0, 0.0, 0.0]]))
    assert done[0] and infos[0]["all_gates_passed"]
    assert infos[0]["reward_terms"]["align"] == pytest.approx(expected, abs=0.05)


def test_env_pays_the_center_term_on_a_gate_passage():
    """A drone that flies straight through a gate's centre earns the whole center weight."""
    from dataclasses import replace

    from icarus_vision.sim.track import Gate, Track

    track = Track(name="one", gates=(Gate((2.0, 0.0, 1.0)),), start_pos=(0.0, 0.0, 1.0))
    cfg = EnvConfig(track=track, reward=replace(RACING_LINE_REWARD, center=5.0))
    env = BatchedRacingVecEnv(1, cfg, info_mode="full")
    env.seed(0)
    env.reset()
    env.state.pos[0] = [1.95, 0.0, 1.0]
    env.state.vel[0] = [5.0, 0.0, 0.0]
    _, _, done, infos = env.step(np.array([[0.0, 0.0, 0.0, 0.0]]))
    assert done[0] and infos[0]["all_gates_passed"]
    assert infos[0]["reward_terms"]["center"] == pytest.approx(5.0, abs=0.1)


L_PATH = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 2.0, 0.0]])  # 2 m along x, 2 m along y
L_ARC = np.array([0.0, 2.0, 4.0])


def _on_l(points):
    p = np.asarray(points, float)
    n = len(p)
    return path_position(p, np.tile(L_PATH, (n, 1, 1)), np.tile(L_ARC, (n, 1)))


def test_path_position_is_the_arc_length_of_the_nearest_point():
    """On the path, beside it, before its start and beyond its end (clamped to 0 and 4 m)."""
    got = _on_l(
        [[1.0, 0, 0], [2.0, 1.5, 0], [1.0, -0.5, 0.3], [2.4, 1.0, 0], [-1.0, 0, 0], [2, 3, 0]]
    )
    assert got == pytest.approx([1.0, 3.5, 1.0, 3.0, 0.0, 4.0])


def test_path_reward_pays_the_metres_along_the_path_not_the_metres_flown():
    """A step along the second leg earns its length; the same step across the path earns nothing;
    back along it costs; a step beside the corner that cuts it earns the arc it skips."""
    n = 4
    p0 = np.array([[2.0, 0.5, 0], [2.5, 1.0, 0], [1.5, 0, 0], [1.5, -0.1, 0]])
    p1 = np.array([[2.0, 1.0, 0], [1.5, 1.0, 0], [1.0, 0, 0], [2.1, 0.5, 0]])
    got = reward_path(p0, p1, np.tile(L_PATH, (n, 1, 1)), np.tile(L_ARC, (n, 1)))
    assert got == pytest.approx([0.5, 0.0, -0.5, 1.0])


def _one_gate_env(reward, n=1):
    from icarus_vision.sim.track import Gate, Track

    track = Track(name="one", gates=(Gate((2.0, 0.0, 1.0)),), start_pos=(0.0, 0.0, 1.0))
    env = BatchedRacingVecEnv(n, EnvConfig(track=track, reward=reward), info_mode="full")
    env.seed(0)
    env.reset()
    return env


def test_env_pays_the_path_term_along_its_reference():
    """A straight reference to the gate: a step at 5 m/s toward it earns about 0.1 m; the term is
    logged, and without a reference the core says what it needs."""
    from dataclasses import replace

    reward = replace(RACING_LINE_REWARD, line=0.0, path=1.0)
    env = _one_gate_env(reward)
    with pytest.raises(RuntimeError, match="set_reference"):
        env.step(np.zeros((1, 4)))
    env = _one_gate_env(reward)
    env.core.set_reference([np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [2.0, 0.0, 1.0]])])
    env.state.pos[0] = [0.5, 0.0, 1.0]
    env.state.vel[0] = [5.0, 0.0, 0.0]
    _, _, _, infos = env.step(np.zeros((1, 4)))
    assert infos[0]["reward_terms"]["path"] == pytest.approx(0.1, abs=0.01)
    assert "line" not in infos[0]["reward_terms"]


@pytest.mark.parametrize(
    "paths, match",
    [
        ([], "1 passages"),
        ([np.zeros((1, 3))], "two or more"),
        ([np.zeros((3, 2))], "two or more"),
        ([np.array([[0, 0, 0], [np.nan, 0, 0]])], "finite"),
    ],
)
def test_a_bad_reference_is_refused(paths, match):
    env = _one_gate_env(RACING_LINE_REWARD)
    with pytest.raises(ValueError, match=match):
        env.core.set_reference(paths)
    rnd = BatchedRacingVecEnv(1, EnvConfig(random_tracks=True, num_gates=2))
    with pytest.raises(ValueError, match="fixed track"):
        rnd.core.set_reference([np.zeros((2, 3))] * 2)

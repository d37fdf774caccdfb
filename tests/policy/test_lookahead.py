"""The look-ahead safety filter: leaves a clear flight alone, averts a predicted crash, learns the
disturbance its model misses, and flies evaluations; its racing mode flies a faster candidate only
where that stays clear by its margin."""

from __future__ import annotations

import numpy as np
import pytest

from icarus_vision.policy.evaluate import evaluate_policy
from icarus_vision.policy.lookahead import (
    Lookahead,
    LookaheadConfig,
    as_config,
    candidate_offsets,
    racing,
)
from icarus_vision.policy.pilots import resolve_policy
from icarus_vision.sim import dynamics
from icarus_vision.sim.config import EnvConfig
from icarus_vision.sim.quad import GRAVITY, QuadParams
from icarus_vision.sim.vec_env import BatchedRacingVecEnv


class ConstantPilot:
    """A stand-in policy: the same action whatever it sees."""

    def __init__(self, action) -> None:
        self.action = np.asarray(action, dtype=np.float32)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.tile(self.action, (len(obs), 1))


def hover_thrust(quad: QuadParams) -> float:
    return 2 * quad.mass * GRAVITY / quad.thrust_max - 1


def test_candidates_on_some_axes():
    offs = candidate_offsets((0.5,), axes=(2,))
    np.testing.assert_array_equal(offs, [[0, 0, 0, 0], [0, 0, 0.5, 0], [0, 0, -0.5, 0]])


def test_candidates_start_with_the_policy_alone():
    offs = candidate_offsets((0.25, 1.0))
    assert offs.shape == (17, 4)
    assert not offs[0].any()
    assert (np.count_nonzero(offs[1:], axis=1) == 1).all()
    assert sorted(np.abs(offs[1:]).max(axis=1)) == [0.25] * 8 + [1.0] * 8


@pytest.mark.parametrize(
    "kwargs",
    [{"horizon_s": 0}, {"offset_s": 1.0}, {"amplitudes": ()}, {"amplitudes": (3.0,)},
     {"disturbance_gain": 1.5}, {"margin_m": -0.1}, {"race_amplitudes": (0.0,)},
     {"race_amplitudes": (0.5,), "race_axes": (4,)}, {"race_amplitudes": (0.5,), "race_axes": ()},
     {"keep_s": -0.1}, {"keep_pos_m": -1}, {"keep_margin_m": float("nan")}],
)  # fmt: skip
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(ValueError):
        LookaheadConfig(**kwargs)


def test_the_filter_asked_for_is_a_bool_or_a_config():
    assert as_config(False) is None
    assert as_config(True) == LookaheadConfig()
    assert as_config(racing()) == racing()
    policy = resolve_policy("default")
    for bad in ("race", 1, None):
        with pytest.raises(ValueError, match="bool or a LookaheadConfig"):
            as_config(bad)
    with pytest.raises(ValueError, match="bool or a LookaheadConfig"):
        evaluate_policy(policy, "single-gate", episodes=1, lookahead="race")


def test_a_clear_flight_is_flown_unchanged():
    policy = resolve_policy("default")
    env = BatchedRacingVecEnv(4, EnvConfig(track="grand-prix", observation=policy.observation))
    env.seed(0)
    obs = env.reset()
    filt = Lookahead(policy, env.config)
    for _ in range(25):
        action = filt.act(env.core, env.state, obs)
        np.testing.assert_array_equal(action, policy.act(obs))
        obs, *_ = env.step(action)
    assert filt.interventions == 0


def airborne(height: float) -> tuple[BatchedRacingVecEnv, np.ndarray]:
    """One drone on grand-prix, taken off and level at ``height``; its observation."""
    env = BatchedRacingVecEnv(1, EnvConfig(track="grand-prix"))
    env.seed(0)
    env.reset()
    env.state.pos[0, 2] = height
    env.core.taken_off[:] = True
    return env, env.core.observe(env.state)


def hovering(height: float) -> tuple[BatchedRacingVecEnv, np.ndarray, ConstantPilot]:
    """One drone hovering at ``height``, its observation and a pilot that holds it there."""
    quad = QuadParams()
    env, obs = airborne(height)
    env.state.thrust[:] = quad.mass * GRAVITY
    return env, obs, ConstantPilot([hover_thrust(quad), 0, 0, 0])


def fly(env, filt, obs, steps: int) -> np.ndarray:
    for _ in range(steps):
        obs, *_ = env.step(filt.act(env.core, env.state, obs))
    return obs


def test_a_clear_prediction_is_kept_while_the_flight_keeps_to_it():
    """Hovering high, one prediction covers keep_s (10 steps); a push or a moved gate makes the
    filter predict again at once."""
    env, obs, pilot = hovering(3.0)
    filt = Lookahead(pilot, env.config)
    assert filt.keep_steps == 10
    obs = fly(env, filt, obs, 30)
    assert filt.predictions == 3
    env.state.vel[0, 0] += 1.0  # pushed: off its prediction
    obs = fly(env, filt, obs, 1)
    assert filt.predictions == 4
    env.core.g_pos[0, 3, 1] += 0.2  # a gate seen elsewhere
    obs = fly(env, filt, obs, 1)
    assert filt.predictions == 5
    every = Lookahead(pilot, env.config, LookaheadConfig(keep_s=0))
    fly(env, every, obs, 12)
    assert every.predictions == 12 and every.keep_steps == 0


def test_a_flight_with_little_room_is_predicted_every_step():
    """Hovering 3 cm over the ground is clear, but closer than keep_margin_m (5 cm): nothing is
    kept; 30 cm over it, predictions are kept."""
    quad = QuadParams()
    for height, expected in ((0.03, 12), (0.3, 2)):
        env, obs, pilot = hovering(quad.radius + height)
        filt = Lookahead(pilot, env.config)
        fly(env, filt, obs, 12)
        assert filt.interventions == 0
        assert filt.predictions == expected, height


def test_a_predicted_crash_is_averted():
    """Falling from 1.2 m with the motors idle hits the ground within the horizon; the filter
    flies the candidate that crashes latest: a large thrust offset."""
    env, obs = airborne(1.2)
    filt = Lookahead(ConstantPilot([-1, 0, 0, 0]), env.config)
    action = filt.act(env.core, env.state, obs)
    assert action[0, 0] >= 0.0  # -1 plus an offset of 1 or more
    np.testing.assert_array_equal(action[0, 1:], 0.0)
    assert filt.interventions == 1
    # a drone not racing any more is left alone
    action = filt.act(env.core, env.state, obs, live=np.zeros(1, dtype=bool))
    assert action[0, 0] == -1.0


def test_the_margin_keeps_the_model_away_from_frames_and_ground():
    """Sinking slowly from 15 cm over the ground loses about 7 cm in the horizon: clear for the
    model, not with a margin of 10 cm, where the filter adds thrust."""
    quad = QuadParams()
    env, obs = airborne(quad.radius + 0.15)
    env.state.thrust[:] = quad.mass * GRAVITY  # motors already at hover
    sink = ConstantPilot([hover_thrust(quad) - 0.02, 0, 0, 0])
    plain = Lookahead(sink, env.config)
    plain.act(env.core, env.state, obs)
    assert plain.interventions == 0
    careful = Lookahead(sink, env.config, LookaheadConfig(margin_m=0.1))
    action = careful.act(env.core, env.state, obs)
    assert careful.interventions == 1 and action[0, 0] > sink.action[0]


def test_the_disturbance_the_model_misses_is_estimated():
    """Wind the model does not know pushes a level drone by drag · wind / mass."""
    quad = QuadParams()
    env, obs = airborne(3.0)
    wind = np.array([2.0, -1.0, 0.0])
    env.core.wind_const[0] = wind
    filt = Lookahead(ConstantPilot([hover_thrust(quad), 0, 0, 0]), env.config,
                     LookaheadConfig(horizon_s=0.04, offset_s=0.02, disturbance_gain=0.3))  # fmt: skip
    for _ in range(30):
        obs, *_ = env.step(filt.act(env.core, env.state, obs))
    expected = np.array(quad.drag) * wind / quad.mass
    np.testing.assert_allclose(filt._accel[0], expected, atol=0.05 * np.abs(expected).max())


def test_the_model_takes_an_extra_acceleration():
    params = dynamics.QuadBatchParams.from_quad(QuadParams(), 2)
    state = dynamics.QuadState.zeros(2)
    state.pos[:, 2] = 5.0
    accel = np.array([[0.0, 0.0, GRAVITY], [1.0, 0.0, 0.0]])
    dynamics.step_substeps(state, np.zeros(2), np.zeros((2, 3)), np.zeros((2, 3)), params,
                           0.01, 10, accel=accel)  # fmt: skip
    np.testing.assert_allclose(state.vel[0], 0.0, atol=1e-12)  # gravity cancelled
    assert state.vel[1, 0] == pytest.approx(0.1, rel=0.05)  # less the drag
    assert state.vel[1, 2] == pytest.approx(-GRAVITY * 0.1, rel=0.05)


def test_evaluate_policy_flies_through_the_filter():
    policy = resolve_policy("default")
    r = evaluate_policy(policy, episodes=3, num_gates=3, difficulty=0.5, randomize=True, seed=1,
                        lookahead=True)  # fmt: skip
    assert r["lookahead"] is True and r["episodes"] == 3
    plain = evaluate_policy(policy, episodes=3, num_gates=3, difficulty=0.5, randomize=True, seed=1)
    assert plain["lookahead"] is False
    with pytest.raises(ValueError, match="scripted"):
        evaluate_policy("scripted", episodes=1, num_gates=2, lookahead=True)


def test_racing_mode_flies_a_candidate_that_gets_further():
    """A drone hovering 3 m up on grand-prix, its pilot holding hover: the racing mode tips it
    toward the first gate with a pitch offset, and it gets nearer the gate than hovering does."""
    quad = QuadParams()
    hover = ConstantPilot([hover_thrust(quad), 0, 0, 0])
    dist = {}
    for name, config in (("plain", LookaheadConfig()), ("racing", racing())):
        env, obs = airborne(3.0)
        env.state.thrust[:] = quad.mass * GRAVITY
        filt = Lookahead(hover, env.config, config)
        for step in range(20):
            action = filt.act(env.core, env.state, obs)
            if step == 0 and name == "racing":
                assert action[0, 2] != hover.action[2] and filt.interventions == 1
                np.testing.assert_array_equal(action[0, [0, 1, 3]], hover.action[[0, 1, 3]])
            obs, *_ = env.step(action)
        dist[name] = float(np.linalg.norm(env.core.g_pos[0, 0] - env.state.pos[0]))
    assert dist["racing"] < dist["plain"] - 0.05


def test_racing_mode_keeps_its_margin():
    """1 m over the ground no tipped flight keeps 0.9 m more from it: the policy's own (clear)
    action is flown."""
    quad = QuadParams()
    env, obs = airborne(1.0)
    env.state.thrust[:] = quad.mass * GRAVITY
    hover = ConstantPilot([hover_thrust(quad), 0, 0, 0])
    filt = Lookahead(hover, env.config, LookaheadConfig(race_amplitudes=(0.5,), race_margin_m=0.9))
    action = filt.act(env.core, env.state, obs)
    np.testing.assert_array_equal(action[0], hover.action)
    assert filt.interventions == 0


def test_evaluate_policy_flies_the_racing_mode():
    policy = resolve_policy("default")
    r = evaluate_policy(policy, episodes=2, num_gates=3, difficulty=0.5, seed=1, lookahead=racing())
    assert r["lookahead"] is True and r["lookahead_race"] is True


def test_a_filter_flies_on_into_a_race_with_other_gates():
    """Kept plans of one race are dropped, not compared, when the next has another gate count."""
    env, obs, pilot = hovering(3.0)
    filt = Lookahead(pilot, env.config)
    fly(env, filt, obs, 2)
    other = BatchedRacingVecEnv(1, EnvConfig(track="three-gates"))
    other.seed(0)
    other.reset()
    other.state.pos[0, 2] = 3.0
    other.core.taken_off[:] = True
    assert other.core.g_pos.shape != env.core.g_pos.shape
    filt.act(other.core, other.state, other.core.observe(other.state))
    assert filt.predictions == 2

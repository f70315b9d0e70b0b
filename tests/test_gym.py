"""cdpr.gym: the Gymnasium environment, checked by Gymnasium's own env checker and against real sessions.

Local mode runs the sim's and trajectory's cores (real DART); session mode is the controller of a real
`cdpr up --without controller --episodes N` (separate processes, Zenoh on loopback). Both must give the
same observations for the same seed and actions, and a zero residual must be the session's own controller.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import cdpr.gym  # noqa: F401  (registers cdpr/Track-v0)
from cdpr.config.scenario import load_scenario
from cdpr.errors import InputError
from cdpr.gym.env import TrackEnv
from cdpr.gym.task import Task
from conftest import ROOT, cdpr_here, free_port, last_json_line

ACTIONS = ("residual", "wrench", "tensions")
UP_TIMEOUT = 120.0  # s: a bound for a short session's processes, never a measurement


def zeros(env: gym.Env) -> np.ndarray:
    return np.zeros(env.action_space.shape, dtype=np.float32)


def episode(env: gym.Env, actions: list[np.ndarray] | None = None, seed: int = 0) -> tuple[list, dict]:
    """Observations of one episode (of the given actions, else zeros) and its last info."""
    obs, info = env.reset(seed=seed)
    seen = [obs]
    k = 0
    while True:
        a = actions[k] if actions is not None else zeros(env)
        obs, reward, terminated, truncated, info = env.step(a)
        seen.append((obs, reward, terminated, truncated))
        k += 1
        if terminated or truncated or (actions is not None and k == len(actions)):
            return seen, info


# --------------------------------------------------------------------------------------------------
# The task (pure)


def test_actions_map_onto_the_limits_and_zero_means_the_plain_law_or_hover() -> None:
    sc = load_scenario("caroca_15kg")
    t = Task(sc, "tensions")
    np.testing.assert_allclose(t.tensions_of(np.full(8, -1.0)), sc.robot.tmin)
    np.testing.assert_allclose(t.tensions_of(np.full(8, 1.0)), sc.robot.tmax)
    np.testing.assert_allclose(t.tensions_of(np.full(8, 7.0)), sc.robot.tmax)  # clipped to the space
    w = Task(sc, "wrench")
    np.testing.assert_allclose(w.wrench_of(np.zeros(6)), [0, 0, 15.0 * 9.81, 0, 0, 0])
    r = Task(sc, "residual")
    assert not np.any(r.wrench_of(np.zeros(6)))
    np.testing.assert_allclose(r.wrench_of(np.ones(6))[:3], 0.2 * 15.0 * 9.81)
    assert (t.action_size, w.action_size, r.action_size) == (8, 6, 6)
    assert t.observation_size == len(t.names()) == 24 + 16
    assert Task(load_scenario("caroca_15kg_3dof"), "residual").action_size == 3


def test_reward_is_bounded_and_termination_names_its_cause() -> None:
    t = Task(load_scenario("caroca_15kg"), "residual")
    for cost in (0.0, 0.5, 1e9):
        assert -1.0 < t.reward(cost) <= 0.0
    assert t.reward(2.0) < t.reward(1.0)
    assert t.cost(np.zeros(3), np.zeros(3), np.full(8, 15 * 9.81 / 8), None) < \
        t.cost(np.array([0.01, 0, 0]), np.zeros(3), np.full(8, 15 * 9.81 / 8), None)


def test_bad_options_are_one_line_errors() -> None:
    with pytest.raises(ValueError, match="action: expected one of tensions, wrench, residual, got 'torque'"):
        TrackEnv(action="torque")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"reward_weights: unknown weight\(s\) speed"):
        TrackEnv(reward_weights={"speed": 1.0})
    with pytest.raises(ValueError, match=r"reward_weights\.rate: expected a finite number >= 0"):
        TrackEnv(reward_weights={"rate": -1.0})
    with pytest.raises(ValueError, match="control_every: expected an integer >= 1"):
        TrackEnv(control_every=0)
    with pytest.raises(ValueError, match="limits: "):
        TrackEnv(limits={"max_spin": 3.0})
    with pytest.raises(ValueError, match="domain randomisation needs local mode"):
        TrackEnv(connect="tcp/127.0.0.1:9", randomize=[{"path": "platform.mass", "op": "scale", "uniform": [0.9, 1.1]}])
    with pytest.raises(InputError, match=r"controller\.law ibvs"):
        TrackEnv(scenario="caroca_15kg_ibvs")
    env = TrackEnv(duration=0.1)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action: expected 6 finite numbers"):
        env.step(np.array([np.nan] * 6))
    env.close()


# --------------------------------------------------------------------------------------------------
# Local mode


@pytest.mark.parametrize("action", ACTIONS)
def test_gymnasiums_env_checker_passes_without_a_warning(action: str) -> None:
    env = gym.make("cdpr/Track-v0", scenario="caroca_15kg", action=action, duration=0.2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    assert [str(w.message) for w in caught] == []
    obs, _ = env.reset(seed=5)
    assert env.observation_space.contains(obs)
    env.close()


def test_the_same_seed_gives_the_same_episode_and_randomisation_draws_from_it() -> None:
    laws = [{"path": "platform.mass", "op": "scale", "uniform": [0.7, 1.3]},
            {"path": "robot.cables.*.frame", "op": "add", "normal": [0.0, 0.002], "plant_only": True}]
    env = TrackEnv(duration=0.2, randomize=laws)
    rng = np.random.default_rng(1)
    actions = [rng.uniform(-1, 1, 6).astype(np.float32) for _ in range(20)]
    a, _ = episode(env, actions, seed=11)
    mass_a = env.plant.robot.mass
    b, _ = episode(env, actions, seed=11)
    c, _ = episode(env, actions, seed=12)
    for x, y in zip(a[1:], b[1:], strict=True):
        np.testing.assert_array_equal(x[0], y[0])
        assert x[1:] == y[1:]
    assert env.plant.robot.mass != mass_a  # seed 12 drew another platform
    assert 0.7 * 15.0 <= mass_a <= 1.3 * 15.0
    assert not np.array_equal(a[-1][0], c[-1][0])
    # the plant_only frame error is the plant's: the controller keeps the nominal anchors
    nominal = load_scenario("caroca_15kg").robot.frame_points
    assert not np.array_equal(env.plant.robot.frame_points, nominal)
    np.testing.assert_array_equal(env.controller.robot.frame_points, nominal)
    env.close()


def test_an_episode_of_zero_residual_is_the_feedback_linearisation_session(tmp_path: Path) -> None:
    """The env's base law is the controller's own, step for step: the same tracking error as `cdpr run` (its
    nodes in one process: the same nodes and messages as the separate processes, the same states)."""
    run = subprocess.run([sys.executable, "-m", "cdpr", "run", "caroca_15kg", "--duration", "1.5", "--quiet",
                          "--in-process"], capture_output=True, text=True, timeout=UP_TIMEOUT, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    session = last_json_line(run.stdout)
    env = TrackEnv(duration=1.5)
    seen, info = episode(env)
    stats = info["episode_stats"]
    assert seen[-1][3]  # truncated at the trajectory's end...
    assert not seen[-1][2]  # ...not terminated
    assert stats["steps"] == session["steps"] == 1500
    assert stats["rms_position_error"] == pytest.approx(session["rms_position_error"], rel=0.01)
    assert stats["infeasible_commands"] == session["infeasible_commands"]
    env.close()


def test_a_falling_platform_terminates_the_episode_with_its_cause_and_a_penalty() -> None:
    env = TrackEnv(action="tensions", duration=2.0)
    env.reset(seed=0)
    steps, terminated = 0, False
    while not terminated:
        _, reward, terminated, truncated, info = env.step(np.full(8, -1.0, dtype=np.float32))  # tmin: it falls
        steps += 1
        assert not truncated
    assert info["termination"] == "the platform left the frame's box"  # it fell through the floor, z < 0
    assert reward < -(200 - steps) + 1e-9  # every env step it will not live costs the most a step can
    env.close()


def test_vectorised_sync_and_async_give_the_same_observations() -> None:
    def make() -> gym.Env:
        return gym.make("cdpr/Track-v0", scenario="caroca_15kg", duration=0.1)

    rng = np.random.default_rng(3)
    actions = [rng.uniform(-1, 1, (2, 6)).astype(np.float32) for _ in range(10)]
    out = []
    for vector in (gym.vector.SyncVectorEnv, gym.vector.AsyncVectorEnv):
        envs = vector([make, make])
        obs, _ = envs.reset(seed=[1, 2])
        trace = [obs]
        for a in actions:
            obs, _, _, truncated, _ = envs.step(a)
            trace.append(obs)
        assert truncated.all()  # 0.1 s: 10 env steps
        envs.close()
        out.append(np.array(trace))
    np.testing.assert_array_equal(out[0], out[1])
    assert out[0].shape == (11, 2, 40)


# --------------------------------------------------------------------------------------------------
# Session mode


@pytest.mark.parametrize("scenario", ["caroca_15kg", "caroca_15kg_winch"])  # winch: sensors, elastic cables, lengths
def test_session_mode_joins_cdpr_up_and_gives_the_local_observations(tmp_path: Path, scenario: str) -> None:
    """Two episodes of `cdpr up --without controller --episodes 2`: the first to its end, the second ended by
    the environment after 10 env steps (session/end); the local env, same seed and actions, sees the same."""
    port = free_port()
    summary = tmp_path / "up.json"
    up = subprocess.Popen([sys.executable, "-m", "cdpr", "up", scenario, "--duration", "0.3", "--without",
                           "controller", "--listen", f"tcp/127.0.0.1:{port}", "--episodes", "2", "--quiet",
                           "--summary", str(summary)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        local = TrackEnv(scenario, duration=0.3)
        remote = TrackEnv(scenario, duration=0.3, connect=f"tcp/127.0.0.1:{port}", session_timeout=UP_TIMEOUT)
        rng = np.random.default_rng(7)
        actions = [rng.uniform(-1, 1, 6).astype(np.float32) for _ in range(30)]
        infos = []
        for count in (30, 10):
            here, _ = episode(local, actions[:count], seed=4)
            there, info_there = episode(remote, actions[:count], seed=4)
            infos.append(info_there)
            np.testing.assert_array_equal(here[0], there[0])
            for x, y in zip(here[1:], there[1:], strict=True):
                np.testing.assert_array_equal(x[0], y[0])
                assert x[1:] == y[1:]
        assert there[-1][3] is False  # the second episode was cut short by the environment, not the session
        remote.close()  # ends the second session (session/end)
        _, err = up.communicate(timeout=UP_TIMEOUT)
    finally:
        if up.poll() is None:
            up.kill()
            up.communicate()
    assert up.returncode == 0, err[-3000:]
    first = json.loads((tmp_path / "up_e0001.json").read_text())
    second = json.loads((tmp_path / "up_e0002.json").read_text())
    assert first["steps"] == first["total_steps"] == 300
    assert first["rms_position_error"] == pytest.approx(infos[0]["episode_stats"]["rms_position_error"], rel=1e-9)
    assert second["exit_ok"]
    assert second["steps"] < 300
    assert "[clock] finished: ended by the controller at step" in err
    assert "the environment was closed" in err
    local.close()


def test_session_mode_refuses_a_session_of_another_scenario() -> None:
    port = free_port()
    up = subprocess.Popen([sys.executable, "-m", "cdpr", "up", "caroca_15kg", "--duration", "0.3", "--without",
                           "controller", "--listen", f"tcp/127.0.0.1:{port}", "--quiet", "--join-timeout", "60"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        env = TrackEnv(duration=0.5, connect=f"tcp/127.0.0.1:{port}", session_timeout=UP_TIMEOUT)
        with pytest.raises(InputError, match=r"runs caroca_15kg \(dt 0.001 s, 300 steps, 8 cables\), this "
                                             r"environment caroca_15kg \(dt 0.001 s, 500 steps"):
            env.reset(seed=0)
        env.close()
    finally:
        up.kill()
        up.communicate()


# --------------------------------------------------------------------------------------------------
# A trained policy as a session's controller


def test_cdpr_run_with_the_zero_policy_is_the_plain_session_bit_for_bit(tmp_path: Path) -> None:
    """`cdpr run --policy` joins the session through the env's session mode; a zero residual is the law itself (the
    plain session's nodes in one process: the same states as separate processes)."""
    plain = subprocess.run([sys.executable, "-m", "cdpr", "run", "caroca_15kg", "--duration", "0.5", "--quiet",
                            "--in-process"], capture_output=True, text=True, timeout=UP_TIMEOUT, check=False)
    rrd = tmp_path / "policy.rrd"
    policy = subprocess.run([sys.executable, "-m", "cdpr", "run", "caroca_15kg", "--duration", "0.5", "--quiet",
                             "--policy", "cdpr.gym.policy:zero", "--rrd", str(rrd)],
                            capture_output=True, text=True, timeout=UP_TIMEOUT, check=False)
    assert plain.returncode == 0, plain.stderr[-3000:]
    assert policy.returncode == 0, policy.stderr[-3000:]
    a, b = last_json_line(plain.stdout), last_json_line(policy.stdout)
    assert b["steps"] == 500
    assert b["state_digest"] == a["state_digest"]  # every state of the session, bit for bit
    assert rrd.stat().st_size > 0


def test_a_bad_policy_is_one_line_and_exit_code_2(tmp_path: Path) -> None:
    for policy, message in (("nowhere:policy", "policy nowhere:policy: No module named 'nowhere'"),
                            ("cdpr.gym.policy:ALGORITHMS", "policy cdpr.gym.policy:ALGORITHMS: not a function"),
                            (str(tmp_path / "missing.zip"), "policy: no such file")):
        args = ("run", "caroca_15kg", "--duration", "0.1", "--policy", policy)
        if policy == "nowhere:policy":  # the real command's process once, the others in this process
            run = subprocess.run([sys.executable, "-m", "cdpr", *args], capture_output=True, text=True,
                                 timeout=UP_TIMEOUT, check=False)
        else:
            run = cdpr_here(*args)
        assert run.returncode == 2, run.stderr[-2000:]
        assert message in run.stderr


def test_the_policys_model_may_differ_from_the_plant(tmp_path: Path) -> None:
    """--policy-model: the env (its controller's model) takes another scenario than the plant's; a bad one is exit 2."""
    plant = str(ROOT / "examples" / "learning" / "caroca_17kg.yaml")  # caroca_15kg's motion, a 17.25 kg platform
    runs = {}
    for model in (None, "caroca_15kg"):
        run = subprocess.run([sys.executable, "-m", "cdpr", "run", plant, "--duration", "0.5", "--quiet", "--policy",
                              "cdpr.gym.policy:zero", *(["--policy-model", model] if model else [])],
                             capture_output=True, text=True, timeout=UP_TIMEOUT, check=False)
        assert run.returncode == 0, run.stderr[-3000:]
        runs[model] = last_json_line(run.stdout)
    # the law trusting a 15 kg model sags under 17.25 kg: a tracking error the matched model does not have
    assert runs["caroca_15kg"]["rms_position_error"] > 3 * runs[None]["rms_position_error"]
    bad = cdpr_here("run", plant, "--duration", "0.1", "--policy", "cdpr.gym.policy:zero", "--policy-model",
                    str(tmp_path / "none.yaml"))  # in this process: test_a_bad_policy_... runs one as a process
    assert bad.returncode == 2, bad.stderr[-2000:]
    assert "none.yaml" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1


def test_a_model_carries_its_environment_options_beside_it(tmp_path: Path) -> None:
    from cdpr.gym.policy import env_options

    model = tmp_path / "m.zip"
    assert env_options(str(model)) == {}
    (tmp_path / "m.env.json").write_text('{"action": "wrench", "normalize": true}')
    assert env_options(str(model)) == {"action": "wrench", "normalize": True}
    (tmp_path / "m.env.json").write_text('{"speed": 3}')
    with pytest.raises(InputError, match=r"m\.env\.json: a map of action, control_every, normalize, reward_weights, "
                                         r"limits \(unknown: speed\)"):
        env_options(str(model))


def test_normalised_observations_are_the_raw_ones_mapped_onto_the_unit_box() -> None:
    raw, unit = TrackEnv(duration=0.1), TrackEnv(duration=0.1, normalize=True)
    a, _ = raw.reset(seed=0)
    b, _ = unit.reset(seed=0)
    low, high = raw.observation_space.low, raw.observation_space.high
    np.testing.assert_allclose(b, (a - (high + low) / 2) / ((high - low) / 2), rtol=1e-6, atol=1e-7)
    assert unit.observation_space.contains(b)
    assert np.all(unit.observation_space.low == -1.0)


def test_the_session_waits_while_the_environment_does_not_step() -> None:
    """Lock-step: between two env steps nothing moves. A listener of sim/state hears no state beyond the one
    the env was given while the env sleeps (the clock may only repeat it), then the episode goes on."""
    import time

    import zenoh

    from cdpr.protocol import Keys, State
    from cdpr.runtime.transport import zenoh_config

    port = free_port()
    up = subprocess.Popen([sys.executable, "-m", "cdpr", "up", "caroca_15kg", "--duration", "0.2", "--without",
                           "controller", "--listen", f"tcp/127.0.0.1:{port}", "--quiet"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    heard: list[int] = []
    try:
        env = TrackEnv(duration=0.2, connect=f"tcp/127.0.0.1:{port}", session_timeout=UP_TIMEOUT)
        env.reset(seed=0)
        for _ in range(5):
            env.step(zeros(env))
        conf = zenoh_config("client", [f"tcp/127.0.0.1:{port}"])
        with zenoh.open(conf) as z:
            sub = z.declare_subscriber(Keys("default").state,
                                       lambda s: heard.append(State.decode(s.payload.to_bytes()).step))
            time.sleep(1.5)  # the environment is busy elsewhere (a training update)
            during = list(heard)
            _, _, _, truncated, info = env.step(zeros(env))  # the listener hears the loop go on
            assert info["step"] == 60
            deadline = time.monotonic() + 10.0
            while 60 not in heard and time.monotonic() < deadline:
                time.sleep(0.01)
            sub.undeclare()
        while not truncated:
            _, _, _, truncated, info = env.step(zeros(env))
        env.close()
        _, err = up.communicate(timeout=UP_TIMEOUT)
    finally:
        if up.poll() is None:
            up.kill()
            up.communicate()
    assert set(during) <= {50}, during  # nothing beyond the state the env holds (a resend of it at most)
    assert set(range(51, 61)) <= set(heard), heard
    assert up.returncode == 0, err[-3000:]

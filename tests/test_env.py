"""The reach env: Gymnasium's checker, vector envs, seeding, action mapping, faults, randomisation."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import twin.envs
from twin.envs import EndoscopeReachEnv, Randomization, TipLoads
from twin import load_params


@pytest.mark.parametrize("action_mode", ["tensions", "pairs"])
def test_registered_env_passes_the_checker(action_mode):
    env = gym.make("twin/EndoscopeReach-v0", action_mode=action_mode)
    try:
        check_env(env.unwrapped, skip_render_check=True)
        assert env.spec.max_episode_steps == 200
    finally:
        env.close()


def test_sync_vector_env_steps_randomised_envs_with_their_own_twins():
    vec = gym.vector.SyncVectorEnv([lambda: gym.make("twin/EndoscopeReachRandomized-v0") for _ in range(2)])
    try:
        obs, info = vec.reset(seed=5)
        assert obs.shape == (2, 22)
        hold = np.stack([vec.envs[i].unwrapped.action_for(np.full(4, 1.35)) for i in range(2)])
        for _ in range(4):
            obs, reward, terminated, truncated, info = vec.step(hold)
        assert not terminated.any() and np.all(reward < 0)
        # Different seeds draw different targets and twins.
        assert not np.allclose(obs[0, 15:18], obs[1, 15:18])
    finally:
        vec.close()


def test_a_step_is_one_telemetry_period_and_reset_is_reproducible():
    env = EndoscopeReachEnv(tip_loads=TipLoads(masses_kg=(0.005,), change_probability=0.0))
    try:
        first, info = env.reset(seed=11)
        t0 = info["time_s"]
        _, _, _, _, info = env.step(env.action_for(np.full(4, 1.35)))
        assert info["time_s"] - t0 == pytest.approx(0.025, abs=1e-9)
        again, _ = env.reset(seed=11)
        np.testing.assert_array_equal(first, again)
        assert info["tip_mass_kg"] == 0.005
    finally:
        env.close()


def test_tension_actions_bend_the_tip_towards_the_pulled_tendon():
    # Horizontal clamp: body x (tendon 1) points down world −z, so pulling tendon 1 lowers the tip.
    env = EndoscopeReachEnv(tip_loads=TipLoads.none())
    try:
        obs, _ = env.reset(seed=0)
        z0 = obs[10]
        action = env.action_for([2.5, 1.35, 1.35, 1.35])
        for _ in range(40):
            obs, *_ = env.step(action)
        assert obs[10] < z0 - 0.005
        assert 2.0 < obs[4] < 3.0
        np.testing.assert_allclose(obs[18:], action)
    finally:
        env.close()


def test_pulling_both_tendons_of_a_pair_in_length_mode_trips_the_limit_and_terminates():
    env = EndoscopeReachEnv(action_mode="lengths", tip_loads=TipLoads.none())
    try:
        env.reset(seed=0)
        terminated = False
        for _ in range(40):
            _, reward, terminated, _, info = env.step(np.array([-1.0, 0.0, -1.0, 0.0], np.float32))
            if terminated:
                break
        assert terminated and info["fault"] and reward < -env.fault_penalty + 1
    finally:
        env.close()


def test_randomization_is_seeded_and_within_its_ranges():
    params = load_params()
    spread = Randomization.typical()
    a, la = spread.sample(params, np.random.default_rng(3))
    b, lb = spread.sample(params, np.random.default_rng(3))
    assert a == b and la == lb
    ratio = a.backbone.youngs_modulus_pa / params.backbone.youngs_modulus_pa
    assert 0.8 <= ratio <= 1.2 and ratio != 1.0
    assert max(map(abs, a.effects.tension_gain_error)) <= 0.03
    assert not Randomization().changes_params and spread.changes_params
    with pytest.raises(ValueError, match="stiffness_scale"):
        Randomization(stiffness_scale=(1.2, 0.8))


def test_latency_delays_actions_by_whole_steps():
    env = EndoscopeReachEnv(randomization=Randomization(latency_steps=(2, 2)), tip_loads=TipLoads.none())
    try:
        env.reset(seed=0)
        pull = env.action_for([3.0, 1.35, 1.35, 1.35])
        targets = []
        for _ in range(3):
            env.step(pull)
            targets.append(env.device.latest().targets[0])
        assert targets[0] == pytest.approx(1.35, abs=1e-3) and targets[1] == pytest.approx(1.35, abs=1e-3)
        assert targets[2] == pytest.approx(3.0, abs=1e-3)
    finally:
        env.close()


def test_bad_arguments_name_the_value():
    with pytest.raises(ValueError, match="action_mode = 'torques'"):
        EndoscopeReachEnv(action_mode="torques")
    with pytest.raises(ValueError, match="leave the seed out"):
        EndoscopeReachEnv("sim://?seed=3")
    with pytest.raises(ValueError, match="tension_range_n"):
        EndoscopeReachEnv(tension_range_n=(0.3, 60.0))


def _rendering_env():
    env = EndoscopeReachEnv(render_mode="rgb_array", tip_loads=TipLoads.none())
    try:
        env.reset(seed=0)
        env.render()
    except Exception as exc:  # noqa: BLE001 - only a missing GL backend is a reason to skip
        env.close()
        from twin.sim.render import RenderError

        if isinstance(exc, RenderError):
            pytest.skip(f"no headless OpenGL here: {exc}")
        raise
    return env


def test_the_env_renders_the_twin_and_passes_gymnasiums_checker_with_rendering_on():
    env = _rendering_env()
    try:
        check_env(env)
        env.reset(seed=1, options={"target_m": env.target_m})
        first = env.render()
        assert first.shape == (480, 640, 3) and first.dtype == np.uint8
        for _ in range(20):
            env.step(np.array([1.0, -1.0, -1.0, -1.0], dtype=np.float32))
        bent = env.render()
        # Something is drawn, and pulling tendon 1 moves it in the picture.
        assert np.ptp(first) > 50 and np.mean(np.abs(bent.astype(int) - first.astype(int))) > 0.5
    finally:
        env.close()
    with pytest.raises(ValueError, match="render_mode = 'movie'"):
        EndoscopeReachEnv(render_mode="movie")


def test_a_frame_shows_the_target_a_floor_grid_and_its_scale_bars():
    env = _rendering_env()
    try:
        # A target 2 cm above the straight robot's middle: in view, clear of the robot.
        env.reset(seed=0, options={"target_m": np.array([0.03, 0.0, 0.02])})
        framed = env.render().astype(int)
        bare = env.unwrapped._view.render().astype(int)  # the same twin without the decorations
    finally:
        env.close()
    r, g, b = (framed[..., i] for i in range(3))
    added = np.abs(framed - bare).sum(axis=2) > 60
    # The target: green pixels that the bare frame lacks; the x bar: red ones; the grid: many grey lines.
    assert np.sum(added & (g > 60) & (g > 2 * r) & (g > 2 * b)) > 100
    assert np.sum(added & (r > 80) & (r > 2 * g) & (r > 2 * b)) > 10
    assert np.sum(added & (np.abs(r - g) < 20) & (np.abs(g - b) < 20) & (r > 60)) > 500
    rows, cols = np.nonzero(added & (np.abs(r - g) < 20) & (r > 60))
    assert np.ptp(rows) > 40 and np.ptp(cols) > 200  # a floor, not a dot


def test_an_episode_is_saved_as_a_video(tmp_path):
    pytest.importorskip("moviepy", reason="gymnasium's RecordVideo writes with moviepy")
    from gymnasium.wrappers import RecordVideo

    env = RecordVideo(_rendering_env(), str(tmp_path), episode_trigger=lambda episode: True, disable_logger=True)
    try:
        env.reset(seed=0)
        for _ in range(10):
            env.step(env.action_space.sample())
    finally:
        env.close()
    (video,) = tmp_path.glob("*.mp4")
    assert video.stat().st_size > 1000


def test_human_rendering_without_a_display_is_a_gymnasium_error_not_a_dead_process():
    # Before: GLFW's "could not initialize GLFW" ended the Python process, check_env with it.
    import os
    import subprocess
    import sys

    # Without a display the env does not offer "human" (so check_env, which renders every mode
    # offered, passes); asked for it directly it refuses; through gym.make, Gymnasium's own
    # HumanRendering wrapper takes over and raises its own error, the process lives on.
    script = ("import gymnasium as gym, twin.envs\n"
              "assert 'human' not in twin.envs.reach.EndoscopeReachEnv.metadata['render_modes']\n"
              "try:\n"
              "    twin.envs.reach.EndoscopeReachEnv(render_mode='human')\n"
              "except gym.error.DependencyNotInstalled as exc:\n"
              "    print('refused:', exc)\n"
              "env = gym.make('twin/EndoscopeReach-v0', render_mode='human')\n"
              "try:\n"
              "    env.reset(seed=0)\n"
              "    env.render()\n"
              "except gym.error.Error as exc:\n"
              "    print('gymnasium:', type(exc).__name__)\n"
              "env.close()\n")
    environment = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=environment,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith('refused: render_mode = "human": needs a display'), result.stdout

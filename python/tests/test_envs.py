"""Every env through Gymnasium: its own checker, the API's shapes and types, options, the vector
form against single envs, rendering, and bad input as a one-line ``selkd.SelkdError``."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import selkd

IDS = [selkd.gymnasium_id(n) for n in selkd.names()]
EXPECTED = {
    "selkd/Hopper-v0", "selkd/Walker2d-v0", "selkd/HalfCheetah-v0", "selkd/Ant-v0",
    "selkd/AntContacts-v0", "selkd/Humanoid-v0", "selkd/FpcAssembly-v0", "selkd/Pendulum-v0",
}


def test_every_registry_env_is_registered_under_its_gymnasium_id():
    assert set(IDS) == EXPECTED
    for env_id in IDS:
        assert env_id in gym.registry


@pytest.mark.parametrize("env_id", IDS)
def test_check_env_passes(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    assert env.spec.max_episode_steps == env.unwrapped.max_episode_steps


@pytest.mark.parametrize("env_id", IDS)
def test_the_api_is_gymnasiums(env_id):
    env = gym.make(env_id)
    obs, info = env.reset(seed=3)
    assert isinstance(env.observation_space, gym.spaces.Box)
    assert obs.dtype == np.float32 and obs.shape == env.observation_space.shape
    assert isinstance(info, dict)
    assert env.action_space.dtype == np.float32
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    out = env.step(env.action_space.sample())
    assert len(out) == 5
    obs, reward, terminated, truncated, info = out
    assert obs.shape == env.observation_space.shape and isinstance(reward, float)
    assert isinstance(terminated, bool) and isinstance(truncated, bool)
    # The same seed, the same start; an unseeded reset continues the generator.
    a, _ = env.reset(seed=11)
    b, _ = env.reset(seed=11)
    assert np.array_equal(a, b)
    c, _ = env.reset()
    assert not np.array_equal(a, c)


def test_an_episode_runs_to_the_time_limit_and_rendering_draws_the_robot():
    env = gym.make("selkd/Pendulum-v0", render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    first = env.render()
    assert first.shape == (48, 64, 3) and first.dtype == np.uint8
    steps, done = 0, False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.array([1.0], np.float32))
        steps += 1
        done = terminated or truncated
    assert steps == 200 and truncated and not terminated
    assert not np.array_equal(first, env.render()), "the pendulum moved"
    assert env.metadata["render_fps"] == 20


def test_options_are_make_keywords_and_are_applied():
    def pull(**opts):
        env = gym.make("selkd/Pendulum-v0", **opts)
        before = env.reset(seed=0)[0][2]
        return abs(env.step(np.zeros(1, np.float32))[0][2] - before)

    assert pull(g=20.0) > 1.5 * pull()
    assert pull(g=20) == pull(g=20.0), "an integer is taken for a float"


def test_the_assembly_task_reports_success_in_info():
    env = gym.make("selkd/FpcAssembly-v0", max_episode_steps=None)
    env.reset(seed=1)
    done, info = False, {}
    while not done:
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        done = terminated or truncated
    assert isinstance(info.get("success"), bool), info


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: gym.make("selkd/Pendulum-v0", gravity=3.0), "gravity"),
        (lambda: gym.make("selkd/Pendulum-v0", g="strong"), "g"),
        (lambda: gym.make("selkd/Pendulum-v0", g=-1.0), "g = -1 must be a positive number"),
        (lambda: gym.make("selkd/Hopper-v0", substeps=0), "`substeps` must be 1 to 640, got 0"),
        (lambda: gym.make("selkd/Pendulum-v0", render_mode="human"), "render_mode='human'"),
        (lambda: selkd.SelkdEnv("pendulm"), "unknown env `pendulm`"),
        (lambda: gym.make_vec("selkd/Hopper-v0", num_envs=0), "num_envs must be at least 1"),
    ],
)
def test_bad_options_are_one_line_errors(make, message):
    with pytest.raises(selkd.SelkdError) as e:
        make()
    assert message in str(e.value) and "\n" not in str(e.value), str(e.value)
    assert isinstance(e.value, ValueError)


def test_an_unknown_id_is_a_one_line_error():
    # Gymnasium's registry answers for a misspelt id, naming the near miss.
    with pytest.raises(gym.error.NameNotFound) as e:
        gym.make("selkd/Hoper-v0")
    assert "Hopper" in str(e.value) and "\n" not in str(e.value), str(e.value)
    with pytest.raises(selkd.SelkdError) as e:
        selkd.envs.registry_name("selkd/Hoper-v0")
    assert "selkd/Hopper-v0" in str(e.value) and "\n" not in str(e.value)


def test_bad_actions_are_one_line_errors():
    env = gym.make("selkd/Hopper-v0").unwrapped
    env.reset(seed=0)
    for action, message in [
        (np.zeros(4, np.float32), "the action has shape (4,), expected (3,)"),
        (np.zeros((2, 3), np.float32), "the action has shape (2, 3), expected (3,)"),
        (np.array([0.0, np.nan, 0.0], np.float32), "entry 1 is NaN"),
    ]:
        with pytest.raises(selkd.SelkdError) as e:
            env.step(action)
        assert message in str(e.value) and "\n" not in str(e.value), str(e.value)
    # Out of range is clipped by the env, as Gymnasium's MuJoCo envs' actuators do; float64 and
    # lists are accepted.
    env.step(np.full(3, 5.0))
    env.step([0.1, 0.2, 0.3])
    vec = gym.make_vec("selkd/Hopper-v0", num_envs=2)
    vec.reset(seed=0)
    with pytest.raises(selkd.SelkdError, match=r"expected \(2, 3\)"):
        vec.step(np.zeros((3, 3), np.float32))
    with pytest.raises(selkd.SelkdError, match="NaN"):
        vec.step(np.array([[0, 0, 0], [0, np.nan, 0]], np.float32))


def test_the_vector_env_steps_like_single_envs_with_next_step_autoreset():
    n = 3
    vec = gym.make_vec("selkd/Hopper-v0", num_envs=n)
    assert isinstance(vec, selkd.SelkdVectorEnv)
    assert vec.observation_space.shape == (n, 11) and vec.action_space.shape == (n, 3)
    singles = [gym.make("selkd/Hopper-v0").unwrapped for _ in range(n)]
    obs, _ = vec.reset(seed=5)
    for i, env in enumerate(singles):
        assert np.array_equal(obs[i], env.reset(seed=5 + i)[0])
    rng = np.random.default_rng(0)
    ended = np.zeros(n, bool)
    saw_reset = False
    for _ in range(400):
        actions = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
        obs, rewards, terminated, truncated, _ = vec.step(actions)
        for i, env in enumerate(singles):
            if ended[i]:
                # Next-step autoreset: the new episode's first observation, reward 0.
                want = env.reset()[0]
                assert rewards[i] == 0 and not terminated[i] and not truncated[i]
                saw_reset = True
            else:
                want, r, t, tr, _ = env.step(actions[i])
                assert rewards[i] == r and terminated[i] == t and truncated[i] == tr
            assert np.array_equal(obs[i], want)
        ended = terminated | truncated
    assert saw_reset, "no hopper fell in 400 random steps"
    assert rewards.dtype == np.float64 and terminated.dtype == bool


def test_the_vector_env_reports_success_with_a_mask():
    vec = gym.make_vec("selkd/FpcAssembly-v0", num_envs=2)
    vec.reset(seed=0)
    for _ in range(vec.unwrapped._env_spec.max_episode_steps + 1):
        _, _, terminated, truncated, info = vec.step(vec.action_space.sample())
        if (terminated | truncated).any():
            break
    ended = terminated | truncated
    assert np.array_equal(info["_success"], ended), info
    assert info["success"].dtype == bool

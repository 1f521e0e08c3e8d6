"""rba.gym: the envs pass Gymnasium's checker, and the skill policy in its env reproduces the rollout."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import rba.gym
from rba.data.export_zip import ExportError
from rba.domains import domain_names, get_domain
from rba.gym import ExportedReward, SkillEnv, env_id, has_simulator, run_episode, run_policy, skill_policy

rba.gym.register_envs()  # the tests' toy domain was registered after rba.gym may have been imported
ENV_DOMAINS = [name for name in domain_names() if has_simulator(name)]  # the toy among them


def test_every_domain_with_a_step_interface_has_an_env():
    assert env_id("walker") == "rba/Walker-v0" and env_id("lane_change") == "rba/LaneChange-v0"
    assert {"walker", "manipulator", "snake", "lane_change", "toy"} <= set(ENV_DOMAINS)
    for name in domain_names():  # the views whose states are not the policies' observations have none
        assert (env_id(name) in gym.registry) == has_simulator(name), name
    assert "rba/WalkerRaw-v0" not in gym.registry and "rba/LaneChangeImage-v0" not in gym.registry


@pytest.mark.parametrize("domain", ENV_DOMAINS)
def test_env_passes_the_checker(domain):
    check_env(SkillEnv(domain), skip_render_check=True)


@pytest.mark.parametrize("domain", ENV_DOMAINS)
def test_skill_policy_reproduces_the_rollout(domain):
    d, seed = get_domain(domain), 11
    params = d.sample_params(np.random.default_rng(seed))
    rollout = d.rollout(params, seed)
    policy = d.skill_policy(params, seed)
    states = run_policy(gym.make(env_id(domain)), policy, seed, params)
    assert states.shape == rollout.states.shape
    np.testing.assert_allclose(states.astype(np.float32), rollout.states, rtol=1e-6, atol=1e-6)
    measured = policy.measured()
    assert set(measured) == set(rollout.proxies)
    for name, value in rollout.proxies.items():
        assert measured[name] == pytest.approx(value, rel=1e-9, abs=1e-12), name


@pytest.mark.parametrize("domain", ["walker", "lane_change", "toy"])
def test_an_episode_measures_what_its_policy_did(domain):
    """The skill's episode measures as its rollout (the toy's through its sensor noise); a policy that holds still
    measures otherwise."""
    d, seed = get_domain(domain), 5
    params = d.sample_params(np.random.default_rng(seed))
    env = gym.make(env_id(domain))
    skill = run_episode(env, d.skill_policy(params, seed), seed, params)
    proxies, truth = skill.proxies(), d.rollout(params, seed).proxies
    tolerance = 0.05 if domain == "toy" else 1e-9
    assert proxies == {k: pytest.approx(v, abs=tolerance) for k, v in truth.items()}
    still = run_episode(env, lambda obs: np.zeros(env.action_space.shape), seed, params, max_steps=len(skill.rewards))
    assert len(still.observations) == len(skill.observations)
    assert any(abs(still.proxies()[k] - v) > 10 * tolerance for k, v in truth.items())


@pytest.mark.parametrize("domain", ["walker_raw", "lane_change_image", "manipulator"])
def test_domains_that_measure_only_their_skill_say_so(domain):
    with pytest.raises(NotImplementedError, match="measures its attributes only through its scripted skill"):
        get_domain(domain).observed_proxies(np.zeros((200, get_domain(domain).state_dim)))


def test_params_that_are_not_the_domains_are_refused():
    env = SkillEnv("toy")
    with pytest.raises(ValueError, match=r"options\['params'\] must name exactly 'toy''s param_names"):
        env.reset(seed=0, options={"params": {"amplitude": 1.0}})


def test_exported_reward_pays_the_return_of_the_recorded_states(exported_toy):
    export = rba.gym.read_export(exported_toy)
    p = export.profile
    env = ExportedReward(exported_toy)
    policy = skill_policy(exported_toy)
    obs, _ = env.reset(seed=p.seed, options={"params": p.params})
    total, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, _ = env.step(policy(obs))
        total += reward
        done = terminated or truncated
    rollout = get_domain("toy").rollout(p.params, p.seed)
    assert total == pytest.approx(export.reward.total(rollout.states), rel=1e-5)


@pytest.fixture
def exported_toy(toy_roots, tmp_path):
    """An export of a toy serve rollout chosen after one "less pace" round (written without the app)."""
    from rba.core.fileio import load_json
    from rba.data.export_zip import ExportSource, write_export
    from rba.data.library import SkillLibrary

    data, models, _ = toy_roots
    serve = SkillLibrary.load("toy", "serve", data)
    version = "-".join(load_json(models / "toy" / f"{kind}-onehot.json")["weights_sha"]
                       for kind in ("ranker", "global_reward"))
    rounds = [{"step": 0, "feedback": [{"attribute": "pace", "direction": "less"}], "rollout_before": serve.ids[0],
               "rollout_after": serve.ids[5]},
              {"step": 1, "feedback": "satisfied", "rollout_before": serve.ids[5], "rollout_after": serve.ids[5]}]
    src = ExportSource("toy", "global", "onehot", version, "builtin", models, serve, serve.ids[5], rounds,
                       clip=b"\0\0\0\x20ftypisom")
    out = tmp_path / "toy.zip"
    write_export(out, src)
    return out


def test_an_exported_reward_refuses_another_domains_env(exported_toy):
    refused = r"this export's reward is for 'toy' \(rba/Toy-v0\); the env given is rba/Walker-v0"
    with pytest.raises(ExportError, match=refused):
        ExportedReward(exported_toy, gym.make("rba/Walker-v0"))
    assert ExportedReward(exported_toy, gym.make("rba/Toy-v0")).export.profile.domain == "toy"

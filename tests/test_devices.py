"""The compiled PPO and the distillation split their environments over local devices.

Each check runs in a process of its own whose XLA host platform is split into two CPU
devices (``--xla_force_host_platform_device_count=2``, read when JAX starts): both
devices hold environments, and a run on two devices ends with the same networks as a run
on one with the same total batch, to float32 round-off (the devices sum their shares of
each reduction in another order).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("jax")
pytest.importorskip("optax")
pytest.importorskip("mujoco.mjx")

#: Networks after the same iterations on one and on two devices agree to this (float32
#: round-off: the order of the summed shares differs).
TOLERANCE = 1e-5

SCRIPT = r"""
import json, sys
import jax, numpy as np
from baselines.rl import compiled
from baselines.rl.config import ConfigError

settings = compiled.Settings(**json.loads(sys.argv[1]))
env = compiled.make_env("auv_envs/DockingStation-v2", "state",
                        {"difficulty": "paper", "time_limit": 0.6},
                        privileged=bool(settings.teacher))
out = {"devices": len(jax.local_devices()),
       "default": len(compiled.batch_devices(settings))}
for bad in (3, 0):
    try:
        compiled.batch_devices(settings, bad)
    except ConfigError as error:
        out[f"refused {bad}"] = str(error)
try:
    compiled.batch_devices(settings._replace(num_envs=5), 2)
except ConfigError as error:
    out["refused uneven"] = str(error)
for n in (1, 2):
    trainer = compiled.Trainer(env, settings, 2, compiled.local_devices(n))
    params, opt_state, normalizer, rollout, key = trainer.init(jax.random.PRNGKey(0))
    for _ in range(2):
        params, opt_state, normalizer, rollout, key, stats = trainer.iteration(
            params, opt_state, normalizer, rollout, key)
    leaf = jax.tree_util.tree_leaves(rollout.env)[0]
    out[n] = {
        "shards": sorted([str(s.device), list(s.data.shape)] for s in leaf.addressable_shards),
        "params": jax.tree_util.tree_map(lambda a: np.asarray(a).tolist(), params),
        "evaluation": [float(v) for v in trainer.evaluate(params, normalizer, 8, 6)],
    }
print(json.dumps(out))
"""


def two_devices(settings: dict) -> dict:
    """The script's findings, run where the host platform has two devices."""
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2",
           "JAX_PLATFORMS": "cpu"}
    run = subprocess.run([sys.executable, "-c", SCRIPT, json.dumps(settings)],
                         capture_output=True, text=True, timeout=900, env=env)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def flat(tree) -> list[float]:
    if isinstance(tree, dict):
        return [x for key in sorted(tree) for x in flat(tree[key])]
    if isinstance(tree, list):
        return [x for item in tree for x in flat(item)]
    return [float(tree)]


@pytest.mark.parametrize("settings", [
    {"num_envs": 8, "n_steps": 4, "n_minibatches": 2, "n_epochs": 1},
    {"num_envs": 8, "n_steps": 6, "n_minibatches": 2, "n_epochs": 1, "lstm_hidden_size": 8,
     "teacher": "pd", "teacher_fraction": 0.5},
], ids=["ppo", "recurrent-distillation"])
def test_two_devices_split_the_environments_and_match_one(settings):
    out = two_devices(settings)
    assert out["devices"] == 2 and out["default"] == 2  # all devices, by default
    assert "has 2 local cpu device(s)" in out["refused 3"]
    assert "has 2 local cpu device(s)" in out["refused 0"]
    assert "must split evenly" in out["refused uneven"]
    one, two = out["1"], out["2"]
    assert [device for device, _ in one["shards"]] == ["TFRT_CPU_0"]
    assert one["shards"][0][1][0] == 8
    # Two devices, each holding half of the environments.
    assert [device for device, _ in two["shards"]] == ["TFRT_CPU_0", "TFRT_CPU_1"]
    assert [shape[0] for _, shape in two["shards"]] == [4, 4]
    a, b = flat(one["params"]), flat(two["params"])
    assert len(a) == len(b) > 100
    assert max(abs(x - y) for x, y in zip(a, b, strict=True)) < TOLERANCE
    assert one["evaluation"] == pytest.approx(two["evaluation"], abs=1e-4)


def test_devices_is_for_cppo_runs(capsys):
    from baselines.commands.train import main

    code = main(["--algo", "ppo", "--env", "DockingStation-v2", "--devices", "2"])
    assert code == 2
    assert "--devices splits a new --algo cppo run" in capsys.readouterr().err

#!/usr/bin/env bash
# The installed package works without the repository: build the sdist and the wheel from it,
# install the wheel with the train extra into a clean venv and, from a directory outside the
# checkout, make and step every env id, load the shipped materials, find the shipped configs, act
# with a published policy, run Gymnasium's and SB3's env checkers on the current ids and train 300
# steps through rl_zoo3 with one of the configs.
#
#   bash scripts/check_wheel.sh [PYTHON]     (make test runs it after the test suite)
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PYTHON="${1:-python3}"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT
PIP=(--disable-pip-version-check -q)

"$PYTHON" -m venv "$WORK/venv"
PY="$WORK/venv/bin/python"
"$PY" -c "import torch" 2>/dev/null || "$PY" -m pip "${PIP[@]}" install "torch==2.13.0"
"$PY" -m pip "${PIP[@]}" install build
"$PY" -m build -o "$WORK/dist" "$ROOT" > "$WORK/build.log" 2>&1 || { tail -40 "$WORK/build.log"; exit 1; }  # the sdist, then the wheel from it
ls "$WORK"/dist/cloth_gym-*.tar.gz > /dev/null
WHEEL="$(ls "$WORK"/dist/cloth_gym-*.whl)"
"$PY" -m pip "${PIP[@]}" install "$WHEEL[train]"

cd "$WORK"  # outside the checkout: nothing of the repository is importable from here
"$PY" - <<'EOF'
import gymnasium as gym
import numpy as np

import cloth_gym
from cloth_gym.envs import ENV_SPECS
from cloth_gym.materials import available_materials, configs_dir, load_material

assert "site-packages" in cloth_gym.__file__, cloth_gym.__file__
names = available_materials()
assert {"thick_cotton", "thin_wool"} <= set(names), names
for name in names:
    load_material(name)
assert (configs_dir() / "train" / "sac.yaml").is_file()
import cloth_gym.agents.callbacks  # noqa: F401  (what the shipped configs name)
for env_id in ENV_SPECS:
    env = gym.make(env_id)
    obs, _ = env.reset(seed=0)
    obs, reward, *_ = env.step(env.action_space.sample())
    parts = list(obs.values()) if isinstance(obs, dict) else [obs]  # a goal env's Dict observation
    assert all(np.all(np.isfinite(a)) for a in parts) and np.isfinite(reward)
    print(f"{env_id}: {sum(a.size for a in parts)} observations, reward {reward:.3f}")
print("materials:", names)
from cloth_gym.agents.published import load_published, models_dir  # shipped as package data
assert "site-packages" in str(models_dir()), models_dir()
model, env_kwargs = load_published("cloth_gym/CornerLift-v2")
env = gym.make("cloth_gym/CornerLift-v2", **env_kwargs)
obs, _ = env.reset(seed=1)
action, _ = model.predict(obs, deterministic=True)
assert env.action_space.contains(action.astype(env.action_space.dtype)), action
print("published CornerLift-v2 policy acts:", action)
from gymnasium.utils.env_checker import check_env  # both env checkers, in this [train]-only install
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from cloth_gym.envs import CURRENT_IDS
for env_id in CURRENT_IDS:
    check_env(gym.make(env_id).unwrapped)  # makes the env again in every advertised render mode
    sb3_check_env(gym.make(env_id, render_mode="rgb_array").unwrapped, warn=True)
print("Gymnasium's and SB3's check_env pass:", CURRENT_IDS)
EOF
"$WORK/venv/bin/cloth-gym" configs --list
"$WORK/venv/bin/cloth-gym" --help > /dev/null
"$WORK/venv/bin/cloth-gym" drape --material thin_wool --sigma 2.5 --max-time 0.3 --quiet --out "$WORK/drape"
test -s "$WORK/drape/thin_wool_kes/drape.png"
CONF="$("$WORK/venv/bin/cloth-gym" configs)/train/sac_curriculum.yaml"
"$PY" -m rl_zoo3.train --algo sac --env cloth_gym/CornerLift-v0 --gym-packages cloth_gym -conf "$CONF" \
    -n 300 --eval-freq -1 -f "$WORK/logs" --seed 0 --hyperparams learning_starts:64 > "$WORK/zoo.log" 2>&1 \
    || { tail -40 "$WORK/zoo.log"; exit 1; }
find "$WORK/logs" -name "cloth_gym-CornerLift-v0.zip" | grep -q . || { tail -40 "$WORK/zoo.log"; echo "no model"; exit 1; }
echo "wheel check passed: $(basename "$WHEEL")"

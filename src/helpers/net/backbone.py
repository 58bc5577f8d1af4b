"""The convolutional backbone of the retrieval network: a residual encoder and a small decoder.

:class:`Encoder` maps a grey (B, 1, S, S) image to three pre-activation maps
(S/4, S/8 and S/8 - 3 on a side, 128 channels each); :class:`Decoder` builds the
per-level feature heads of the levels a model selects (named 32, 16 and 13
after their side at a 128 px input). :class:`helpers.net.model.OrientationNet`
assembles them with the fusion head.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class ResBlock(nn.Module):
    """Bias-free residual block: relu(conv3x3(relu(conv3x3(x))) + shortcut(x)).

    The shortcut is a 1x1 projection when stride or width changes, else identity.
    """

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.shortcut = (nn.Conv2d(cin, cout, 1, stride, bias=False)
                         if stride != 1 or cin != cout else nn.Identity())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.conv2(F.relu(self.conv1(x))) + self.shortcut(x))


class Encoder(nn.Module):
    """Grey (B,1,S,S) -> maps at S/4 (128 ch), S/8 (128 ch), S/8-3 (128 ch, pre-activation)."""

    def __init__(self) -> None:
        super().__init__()
        self.stem = nn.Conv2d(1, 32, 3, 1, 1)
        self.stage1 = nn.Sequential(ResBlock(32, 32), ResBlock(32, 64, 2), ResBlock(64, 64))
        self.stage2 = nn.Sequential(ResBlock(64, 128, 2), ResBlock(128, 128))
        self.stage3 = nn.Sequential(ResBlock(128, 128, 2), ResBlock(128, 128))
        self.valid = nn.Conv2d(128, 128, 4)  # no padding: 16 -> 13

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.stage1(F.relu(self.stem(x)))
        f32 = self.stage2(x)
        f16 = self.stage3(f32)
        return f32, f16, self.valid(f16)


class Head(nn.Module):
    """ReLU -> Dropout -> 1x1 conv (no bias): per-level feature head."""

    def __init__(self, cin: int, cout: int, dropout: float) -> None:
        super().__init__()
        self.drop = nn.Dropout(dropout)
        self.conv = nn.Conv2d(cin, cout, 1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(self.drop(F.relu(x)))


class Decoder(nn.Module):
    """Builds only the parts the selected levels need.

    Level 13 is the encoder's 13x13 map. Level 16: ConvTranspose k=4 (13->16),
    concat the 16x16 encoder map, 1x1 conv to 128. Level 32: bilinear x2 of
    the level-16 map, concat the 32x32 encoder map, 1x1 conv to 128. The maps
    entering the transposed conv and the upsampling are ReLU'd first, like
    every head input (they are pre-activations).
    """

    def __init__(self, levels: tuple[int, ...], channels: int, dropout: float) -> None:
        super().__init__()
        self.levels = levels
        self.need16 = 16 in levels or 32 in levels
        self.need32 = 32 in levels
        if self.need16:
            self.up13 = nn.ConvTranspose2d(128, 128, 4)
            self.merge16 = nn.Conv2d(256, 128, 1)
        if self.need32:
            self.merge32 = nn.Conv2d(256, 128, 1)
        self.heads = nn.ModuleDict({str(lv): Head(128, channels, dropout) for lv in levels})

    def forward(self, f32: torch.Tensor, f16: torch.Tensor, f13: torch.Tensor) -> dict[int, torch.Tensor]:
        pre = {13: f13}
        if self.need16:
            pre[16] = self.merge16(torch.cat([self.up13(F.relu(f13)), f16], dim=1))
        if self.need32:
            up = F.interpolate(F.relu(pre[16]), size=f32.shape[-2:], mode="bilinear", align_corners=False)
            pre[32] = self.merge32(torch.cat([up, f32], dim=1))
        return {lv: self.heads[str(lv)](pre[lv]) for lv in self.levels}

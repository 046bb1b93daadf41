"""Decoupled appearance modelling (VastGaussian; GOF's ``--use_decoupled_appearance``).

Per-image exposure/white-balance changes are absorbed by a small CNN that predicts a per-pixel gain
map from a downsampled render and a learned per-image embedding. The gain is applied to the render
*only inside the L1 term of the loss*; test renders and meshes never see it, so the Gaussians stay
view-consistent.

Architecture (GOF ``scene/appearance_network.py``): crop the render to ``(H//32·32, W//32·32)`` at the
centre, bilinearly downsample (align_corners) by 32, concatenate the image's 64-d embedding
(initialised N(0, 1e-4)) → conv3×3 67→256, ReLU → 4 × [PixelShuffle(2), conv3×3 C/4→C/2, ReLU]
(256→128→64→32→16) → bilinear ×2 → conv3×3 16→16, ReLU → conv3×3 16→3 → sigmoid.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

DOWNSAMPLE = 32


class AppearanceModel(nn.Module):
    """Per-image embeddings + the gain CNN.

    Args:
        num_images: how many images get an embedding (index = the image's position in the scene).
        embedding_dim: length of each embedding (GOF: 64).
    """

    def __init__(self, num_images: int, embedding_dim: int = 64):
        super().__init__()
        self.embedding = nn.Embedding(num_images, embedding_dim)
        nn.init.normal_(self.embedding.weight, 0.0, 1e-4)
        self.head = nn.Conv2d(3 + embedding_dim, 256, 3, padding=1)
        chans = [256, 128, 64, 32, 16]
        self.ups = nn.ModuleList(nn.Conv2d(c // 4, c // 2, 3, padding=1) for c in chans[:-1])
        self.conv = nn.Conv2d(16, 16, 3, padding=1)
        self.out = nn.Conv2d(16, 3, 3, padding=1)

    @staticmethod
    def crop(image: torch.Tensor) -> torch.Tensor:
        """Centre crop of ``[3, H, W]`` to multiples of 32 (the region the gain map covers)."""
        _, h, w = image.shape
        ch, cw = (h // DOWNSAMPLE) * DOWNSAMPLE, (w // DOWNSAMPLE) * DOWNSAMPLE
        top, left = (h - ch) // 2, (w - cw) // 2
        return image[:, top : top + ch, left : left + cw]

    def gain(self, render: torch.Tensor, image_index: int) -> torch.Tensor:
        """Gain map ``[3, H', W']`` in (0, 1) for the centre crop of ``render`` ``[3, H, W]``.

        Images smaller than 32 pixels on a side have no crop; a gain of ones is returned.
        """
        return self.gain_for(render, self.embedding.weight[image_index])

    def gain_for(self, render: torch.Tensor, embedding: torch.Tensor) -> torch.Tensor:
        """:meth:`gain` for an image's embedding ``[D]`` given as a tensor (a row of ``embedding.weight``), so that a
        compiled caller can pick the row on the device instead of specialising on the image's index."""
        crop = self.crop(render)
        _, h, w = crop.shape
        if h == 0 or w == 0:
            return torch.ones_like(render[:, :0, :0])
        small = F.interpolate(crop[None], size=(h // DOWNSAMPLE, w // DOWNSAMPLE), mode="bilinear", align_corners=True)
        emb = embedding[None, :, None, None].expand(1, -1, small.shape[2], small.shape[3])
        x = F.relu(self.head(torch.cat([small, emb], dim=1)))
        for conv in self.ups:
            x = F.relu(conv(F.pixel_shuffle(x, 2)))
        x = F.interpolate(x, size=(h, w), mode="bilinear", align_corners=True)
        x = F.relu(self.conv(x))
        return torch.sigmoid(self.out(x))[0]

    def apply(self, render: torch.Tensor, image_index: int) -> torch.Tensor:
        """The appearance-corrected centre crop ``gain ⊙ crop(render)`` (compare with ``crop(gt)``)."""
        return self.apply_for(render, self.embedding.weight[image_index])

    def apply_for(self, render: torch.Tensor, embedding: torch.Tensor) -> torch.Tensor:
        """:meth:`apply` for an image's embedding ``[D]`` given as a tensor (see :meth:`gain_for`)."""
        return self.gain_for(render, embedding) * self.crop(render)

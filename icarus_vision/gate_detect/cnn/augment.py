"""Training augmentation (albumentations), with the gate keypoints transformed alongside.

Photometric: blur, motion blur, Gaussian noise, colour/brightness/contrast/hue jitter, channel
shuffle (gate colours never rendered), grey, JPEG artefacts. Geometric: a small affine (scale,
rotation, shift, shear) with constant (black) borders, since reflected borders would duplicate
gates and their corners. The horizontal mirror, which must also swap TL <-> TR and BR <-> BL, is
applied by :class:`~icarus_vision.gate_detect.cnn.data.GateDataset` itself
(``base.FLIP_ORDER``).

Keypoints are in continuous pixel coordinates (the image's left edge at x = 0), the convention
albumentations uses.
"""

from __future__ import annotations

import albumentations as A  # noqa: N812
import cv2


def make_augment(seed: int | None = 0) -> A.Compose:
    """The training augmentation pipeline; ``keypoints`` are (N, 2) x, y, kept even outside."""
    return A.Compose(
        [
            A.Affine(
                scale=(0.85, 1.2),
                translate_percent=(-0.06, 0.06),
                rotate=(-12, 12),
                shear=(-4, 4),
                interpolation=cv2.INTER_LINEAR,
                border_mode=cv2.BORDER_CONSTANT,
                fill=0,
                p=0.6,
            ),
            A.OneOf(
                [
                    A.MotionBlur(blur_limit=(3, 5)),
                    A.GaussianBlur(blur_limit=(3, 3), sigma_limit=(0.2, 0.8)),
                ],
                p=0.25,
            ),
            A.ColorJitter(brightness=0.35, contrast=0.35, saturation=0.4, hue=0.08, p=0.7),
            A.ChannelShuffle(p=0.15),
            A.ToGray(p=0.05),
            A.GaussNoise(std_range=(0.01, 0.06), p=0.3),
            A.ImageCompression(quality_range=(40, 95), p=0.3),
        ],
        keypoint_params=A.KeypointParams(format="xy", remove_invisible=False),
        seed=seed,
    )

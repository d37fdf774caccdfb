"""Synthetic gate-keypoint datasets: racing-like frames rendered in parallel, labelled in COCO.

Public API: :func:`generate_dataset` (the ``icarus-vision gen-dataset`` command) and its
:class:`GenerationResult`; the folder layout is described in :mod:`icarus_vision.dataset.layout`.
"""

from icarus_vision.dataset.generate import GenerationResult, generate_dataset

__all__ = ["GenerationResult", "generate_dataset"]

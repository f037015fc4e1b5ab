"""Content digests of episodes: what a model was trained on, by value, for the names of its checkpoints.

    digest = sha1 over episodes (in the order given) of, per array: name, dtype, shape, bytes     -> 16 hex digits

A checkpoint is reused when its name matches, so the name must change whenever the training data do. Task names,
seeds and lengths are not enough: two stores, or a dataset imported again, with the same names and lengths but other
frames would share a model trained on the other data (a red and a faint one-disk control at the same settings did,
README "Why the model did not learn one disk"). Hashing the arrays costs one more read of the training episodes,
small beside training on them.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Mapping

import numpy as np


def _update(h, name: str, array: np.ndarray) -> None:
    a = np.ascontiguousarray(array)
    h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
    h.update(a.data)


def arrays_digest(episodes: Iterable[Mapping[str, np.ndarray]]) -> str:
    """Digest of episodes given as {name: array} (each episode's names in sorted order; None values skipped)."""
    h = hashlib.sha1()
    for i, arrays in enumerate(episodes):
        h.update(f"episode {i}|".encode())
        for name in sorted(arrays):
            if arrays[name] is not None:
                _update(h, name, arrays[name])
    return h.hexdigest()[:16]


def source_digest(source, episodes: np.ndarray, robot_masks: bool = False) -> str:
    """Digest of what a model trains on from `source` (simeval.episodes.dataset's ArraySource or StoreSource):
    the frames of its camera, states and actions (and robot masks when the loss reads them) of the episodes where
    `episodes` is True."""
    chosen = [e for e, keep in enumerate(np.asarray(episodes, bool)) if keep]
    return arrays_digest(source.read(e, 0, source.infos[e].n_rows, robot_mask=robot_masks) for e in chosen)

"""Every seed valid, seeds independent across tasks, and success as strict as the task text: each case builds
the situation in the simulator by pose (no oracle) and checks the verdict."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from simeval.sim.spec import SUITES_DIR, SpecError, load_suite, sample_instance, task_seed

SUITE = {s.name: s for s in load_suite(SUITES_DIR / "gensim")}


# --- section 4: sampling ------------------------------------------------------------------------------------
def test_every_seed_of_every_task_samples():
    for spec in SUITE.values():
        for seed in range(200):
            inst = sample_instance(spec, seed)  # raised SpecError for build-bridge 24/31, sweep-pile... 42
            xy = [inst.poses[o.id][0] for o in inst.objects]
            r = [o.footprint for o in inst.objects]
            assert all(np.linalg.norm(xy[i] - xy[j]) > r[i] + r[j] for i in range(len(xy)) for j in range(i))


def _largest_xy(seeds):
    out = {}
    for spec in SUITE.values():
        for seed in seeds:
            inst = sample_instance(spec, seed)
            big = max(inst.objects, key=lambda o: o.footprint)
            out[spec.name, seed] = inst.poses[big.id][0]
    return out


def test_tasks_draw_independent_layouts_for_the_same_seed():
    seeds = range(60)
    xy = _largest_xy(range(61))
    pairs = list(itertools.combinations(SUITE, 2))
    same = np.mean([np.linalg.norm(xy[a, s] - xy[b, s]) < 0.03 for a, b in pairs for s in seeds])
    shifted = np.mean([np.linalg.norm(xy[a, s] - xy[b, s + 1]) < 0.03 for a, b in pairs for s in seeds])
    # with one shared stream the same seed put the largest objects within 3 cm in 34% of task pairs
    assert same < 2 * shifted + 0.01, (same, shifted)


def test_task_seed_is_stable_and_name_dependent():
    a = np.random.default_rng(task_seed("stack-two-blocks", 3)).integers(1 << 30)
    b = np.random.default_rng(task_seed("stack-two-blocks", 3)).integers(1 << 30)
    c = np.random.default_rng(task_seed("build-wall", 3)).integers(1 << 30)
    assert a == b != c
    # a fixed value: the stream must not depend on the interpreter's hash salt
    assert task_seed("x", 0).entropy == [0, int.from_bytes(__import__("hashlib").sha256(b"x").digest()[:8], "little")]


def test_variation_counts_must_match_the_text():
    pyramid = SUITE["stack-block-pyramid"]
    with pytest.raises(SpecError, match=r"stack-block-pyramid.*'base'.*valid counts for 'base': 2"):
        sample_instance(pyramid, 0, {"base": {"count": 3}})
    with pytest.raises(SpecError, match="sweep-two-piles.*valid counts for 'pile': 2"):
        sample_instance(SUITE["sweep-two-piles"], 0, {"pile": {"count": 1}})
    with pytest.raises(SpecError, match="align-balls-in-zones.*valid counts for 'ball': 2"):
        sample_instance(SUITE["align-balls-in-zones"], 0, {"ball": {"count": 3}})
    # free counts stay free: more red blocks, more distractors
    inst = sample_instance(SUITE["place-red-in-green"], 0, {"block": {"count": 4}, "distractor": {"count": 0}})
    assert len(inst.by_name("block")) == 4 and not inst.by_name("distractor")

"""`src/controls.py gensim_own`'s verdict (simeval.measures.dynamics_diversity.controls.gensim_own): the generalist's
and the specialists' errors are ratios of the runs' per-episode sums over the same held-out episodes, computed here by
hand, and the criterion follows them."""

from __future__ import annotations

import numpy as np

from simeval.measures.dynamics_diversity.controls import gensim_own as control


def _record(condition: str, seed: int, moving: dict[tuple[str, int], tuple[float, float]]) -> dict:
    """A run record whose per-episode sums matter only for the one-step moving pixels: (model se, pixels)."""
    from simeval.measures.dynamics_diversity.prediction import SUM_KEYS

    episodes = []
    for (task, ep), (se, pixels) in moving.items():
        sums = dict.fromkeys(SUM_KEYS, 1.0)
        sums.update({"one_step/model/moving": se, "one_step/moving_pixels": pixels,
                     "one_step/last/moving": 2 * pixels})
        episodes.append({"task": task, "seed": ep, "sums": sums})
    return {"path": f"{condition}_s{seed}.json", "identity": {"task_group": condition, "seed": seed},
            "values": {"prediction": {"per_episode": episodes}}}


def test_the_verdict_pairs_the_specialists_with_the_generalist_episode_for_episode_by_hand():
    pixels = {("a", 16): 100.0, ("a", 17): 300.0, ("b", 16): 200.0, ("b", 17): 50.0}
    # the generalist errs 6 per moving pixel and channel on task a, 9 on b; each specialist 3 on its own task
    general = [_record("generalist", s, {k: ((6.0 if k[0] == "a" else 9.0) * 3 * px, px) for k, px in pixels.items()})
               for s in (0, 1)]
    special = [_record("specialists", s, {k: (3.0 * 3 * px, px) for k, px in pixels.items() if k[0] == task})
               for s in (0, 1) for task in ("a", "b")]
    v = control.verdict(general, special, n_boot=200)
    moving = v["pooled"]["one_step_moving"]
    total = sum(pixels.values())  # sum se / (3 sum pixels) over the four episodes
    by_hand = (6.0 * (100 + 300) + 9.0 * (200 + 50)) / total
    np.testing.assert_allclose(moving["generalist"], by_hand, rtol=1e-12)
    np.testing.assert_allclose(moving["specialists"], 3.0, rtol=1e-12)
    np.testing.assert_allclose(moving["difference"], by_hand - 3.0, rtol=1e-12)
    np.testing.assert_allclose(v["per_task"]["b"]["one_step_moving"]["difference"], 6.0, rtol=1e-12)
    # paired: every resample scores both on the same episodes, so the difference never falls below the smallest
    # per-task gap (3 on task a) although the generalist's own interval is wide
    assert moving["difference_interval"][0] >= 3.0 - 1e-9
    assert v["passes"] == {"moving_pixel_error_higher_for_generalist": True}
    assert v["held_out_episodes"] == 4

    swapped = control.verdict([dict(r, identity={**r["identity"], "task_group": "generalist"}) for r in
                               [_record("x", s, {k: (3.0 * 3 * px, px) for k, px in pixels.items()}) for s in (0, 1)]],
                              [_record("specialists", s, {k: ((6.0 if k[0] == "a" else 9.0) * 3 * px, px)
                                                          for k, px in pixels.items() if k[0] == t})
                               for s in (0, 1) for t in ("a", "b")], n_boot=200)
    assert swapped["passes"] == {"moving_pixel_error_higher_for_generalist": False}


def test_too_few_moving_pixels_is_no_reading_not_a_fail():
    pixels = {("a", 16): 3.0, ("b", 16): 2.0}  # 5 moving pixels in all: below the count a reading needs
    general = [_record("generalist", 0, {k: (9.0 * px, px) for k, px in pixels.items()})]
    special = [_record("specialists", 0, {k: (3.0 * px, px) for k, px in pixels.items() if k[0] == t}) for t in "ab"]
    v = control.verdict(general, special, n_boot=50)
    assert v["passes"] == {"moving_pixel_error_higher_for_generalist": None}
    assert control.outcome(v) == "no reading (too few pixels moved)"

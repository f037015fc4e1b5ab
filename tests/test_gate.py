"""The validity gate of dynamics-diversity readings (simeval.measures.dynamics_diversity.gate): skills and verdicts
computed by hand, and a stand-in world model that draws the task's mean image gets "no reading" through the whole
evaluation path."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from helpers import ConstantImageModel

from simeval.errors import UserError
from simeval.measures.dynamics_diversity.gate import GateConfig, fall_verdict, gate, pixel_gate


def test_skill_and_verdict_by_hand():
    tasks = np.array(["a", "a", "b", "b"])
    model = np.array([[1.0, 1.0, 1.0, 1.0]])
    last = np.array([[2.0, 2.0, 2.0, 2.0]])  # skill 1 - 4/8 = 0.5, the same in every resample
    mean = np.array([[4.0, 4.0, 4.0, 4.0]])  # skill 0.75
    g = gate(model, {"last": last, "mean": mean}, tasks)
    assert g["passes"] and g["verdict"] == "reads" and g["tasks_passing"] == 2
    assert g["baselines"]["last"]["skill"] == pytest.approx(0.5)
    assert g["baselines"]["last"]["interval"] == pytest.approx([0.5, 0.5])
    assert g["baselines"]["mean"]["skill"] == pytest.approx(0.75)


def test_a_model_as_good_as_a_baseline_gets_no_reading():
    tasks = np.array(["a"] * 4)
    model = np.array([[1.0, 2.0, 3.0, 4.0]])
    g = gate(model, {"last": model * 2, "mean": model.copy()}, tasks)
    assert not g["passes"]
    assert g["verdict"].startswith("no reading: the model does not beat the mean image (skill 0.000")


def test_below_the_margin_or_an_interval_reaching_zero_fails():
    tasks = np.array(["a"] * 4)
    model = np.array([[0.97, 0.97, 0.97, 0.97]])
    assert not gate(model, {"last": np.ones((1, 4))}, tasks)["passes"]  # skill 0.03 < margin 0.05
    assert gate(model, {"last": np.ones((1, 4))}, tasks, GateConfig(margin=0.02))["passes"]
    # skill 0.2 overall but worse than the baseline on half the episodes: the interval reaches below zero
    noisy = np.array([[0.1, 0.1, 1.5, 1.5]])
    g = gate(noisy, {"last": np.array([[0.1, 4.0, 1.0, 0.0]])}, tasks)
    lo = g["baselines"]["last"]["interval"][0]
    assert g["baselines"]["last"]["skill"] == pytest.approx(1 - 3.2 / 5.1) and lo < 0 and not g["passes"]


def test_a_group_with_a_task_that_does_not_read_gets_no_reading_unless_fewer_tasks_are_required():
    tasks = np.array(["a", "a", "b", "b"])
    model = np.array([[1.0, 1.0, 3.0, 3.0]])
    last = np.array([[4.0, 4.0, 3.0, 3.1]])  # the group's skill 1 - 8/14.1 > 0.05; task b's 1 - 6/6.1 < 0.05
    g = gate(model, {"last": last}, tasks)
    assert g["baselines"]["last"]["passes"] and not g["passes"]
    assert g["verdict"] == "no reading: the model does not beat the last frame on 1 of 2 tasks (b)"
    assert gate(model, {"last": last}, tasks, GateConfig(min_task_share=0.5))["passes"]


def test_config_mistakes_are_user_errors():
    with pytest.raises(UserError, match="gate.margin=1.5"):
        GateConfig(margin=1.5)
    with pytest.raises(UserError, match="unknown key"):
        GateConfig.from_dict({"margn": 0.1})


def test_fall_verdicts():
    reads = {10: {"passes": True}, 40: {"passes": True}}
    # errors of 10 at 10 episodes: "no fall" needs the fall within +-0.5 (5% of 10) or the fall of the error relative
    # to a baseline within +-0.05 of it (gate.relative_fall_interval)
    assert fall_verdict((1.0, 0.5, 1.5), {"last": (0.05, 0.15), "mean": (0.02, 0.1)}, reads, 10.0) == "falls"
    for bad in ({}, {10: {"passes": True}}, {10: {"passes": True}, 40: {"verdict": "x"}}):  # internal: said plainly
        with pytest.raises(ValueError, match="a fall needs the gate"):
            fall_verdict((1.0, 0.5, 1.5), {"last": (0.05, 0.15)}, bad, 10.0)
    # the error relative to the mean image did not fall, to within 0.05: the fall is the mean image's own change
    assert fall_verdict((1.0, 0.5, 1.5), {"last": (0.05, 0.15), "mean": (-0.02, 0.04)}, reads, 10.0) == "no fall"
    assert fall_verdict((-1.0, -1.5, -0.5), {"last": (-0.15, -0.05)}, reads, 10.0) == "rises"
    assert fall_verdict((0.1, -0.3, 0.4), {"last": (-0.03, 0.04)}, reads, 10.0) == "no fall"
    # a change that excludes 0 but lies within the margin is no change to read, either sign (before: "falls"/"rises")
    assert fall_verdict((-0.24, -0.42, -0.07), {"last": (-0.1, -0.06)}, reads, 10.0) == "no fall"
    assert fall_verdict((0.24, 0.07, 0.42), {"last": (0.06, 0.1)}, reads, 10.0) == "no fall"
    # a fall of 1-15% of the error, against a mean state 1,000x the model's: relative to it the error falls by 1-15%
    # too, so no "no fall" (the skill's rise the rule read before, 0.00001-0.00015, was always within 0.05)
    # the verdict names which interval is too wide, and that the fall's own excludes 0
    assert fall_verdict((0.8, 0.1, 1.5), {"last": (-0.02, 0.15), "mean": (0.01, 0.15)}, reads, 10.0) == (
        "no reading: too wide (its relative fall against the last [-0.02, +0.15] contains 0 and reaches past +-0.05; "
        "the fall's interval [+0.1, +1.5] excludes 0)")
    assert fall_verdict((0.8, 0.1, 1.5), {"mean_state": (-0.02, 0.15)}, reads, 10.0).startswith(
        "no reading: too wide (its relative fall against the mean state [-0.02, +0.15]")
    # the error falls, and falls less than the mean state's own error does (a newcomer's case): no reading, named
    opposite = fall_verdict((1.0, 0.6, 1.5), {"last": (0.05, 0.15), "mean": (-0.3, -0.1)}, reads, 10.0)
    assert opposite.startswith("no reading: the fall and its excess over a baseline's own change point opposite ways")
    assert "[-0.3, -0.1]" in opposite
    # intervals that contain 0 and reach past both bounds cannot tell a fall from none
    wide = fall_verdict((0.1, -0.3, 2.0), {"last": (-0.03, 0.2), "mean": (-0.1, 0.2)}, reads, 10.0)
    assert wide == ("no reading: too wide (the fall's interval [-0.3, +2] contains 0 and reaches past +-0.05 of the "
                    "error at 10 episodes, 0.5; its relative fall against the last [-0.03, +0.2] contains 0 and "
                    "reaches past +-0.05; its relative fall against the mean [-0.1, +0.2] contains 0 and reaches past "
                    "+-0.05)")
    assert fall_verdict((0.1, -0.3, 0.4), {"last": (-0.03, 0.4)}, reads, 1.0).startswith("no reading: too wide")
    gated = {10: {"passes": False, "verdict": "no reading: the model does not beat the last frame"}, 40: reads[40]}
    assert fall_verdict((1.0, 0.5, 1.5), {"last": (0.05, 0.15)}, gated, 10.0) == \
        "no reading: the model does not beat the last frame at 10 episodes"


def test_the_relative_fall_is_a_share_of_the_relative_error_at_the_fewest_episodes_by_hand():
    from simeval.measures.dynamics_diversity.gate import relative_fall_interval

    # relative errors 0.001 and 0.002 at the fewest, 0.0009 and 0.001 at the most: shares 0.1 and 0.5 of them
    lo, hi = relative_fall_interval(np.array([1.0, 2.0]), np.array([1000.0, 1000.0]), np.array([0.9, 1.0]),
                                    np.array([1000.0, 1000.0]))
    assert (lo, hi) == pytest.approx((0.1 + 0.025 * 0.4, 0.1 + 0.975 * 0.4))
    # a baseline that halves its own error between the counts: a model error that halves too falls by nothing
    assert relative_fall_interval(np.full(3, 2.0), np.full(3, 4.0), np.full(3, 1.0), np.full(3, 2.0)) == \
        pytest.approx((0.0, 0.0))


def test_a_model_that_outputs_the_mean_image_gets_no_reading():
    from simeval.measures.dynamics_diversity.prediction import step_sums, summarise

    from simeval.measures.dynamics_diversity.controls.random_draws import make_control_group, one_disk_control

    src = make_control_group(one_disk_control(), "varied", n_tasks=1, episodes=6, n_actions=8, size=16)
    frames = np.concatenate([a["image"] for a in src.arrays[:3]]).astype(np.float64) / 255
    mean = torch.as_tensor(frames.mean(0), dtype=torch.float32)
    model = ConstantImageModel(mean)  # the task's mean image: it has learned nothing of the dynamics
    per_episode = []
    for e in range(3, 6):
        a = src.arrays[e]
        L = len(a["image"])
        batch = {"image": torch.as_tensor(a["image"])[None], "state": torch.zeros(1, L, 0),
                 "prev_action": torch.zeros(1, L, 2), "is_first": torch.zeros(1, L, dtype=torch.bool),
                 "mask": torch.ones(1, L, dtype=torch.bool), "task": torch.zeros(1, dtype=torch.long)}
        sums = {k: float(v[0]) for k, v in step_sums(model, batch, mean[None]).items()}
        per_episode.append({"task": src.infos[e].task, "seed": src.infos[e].seed, "sums": sums})
    total = {k: sum(p["sums"][k] for p in per_episode) for k in per_episode[0]["sums"] if "open_loop" not in k}
    total.update({k: 0.0 for k in ("open_loop/frames", "open_loop/kept_pixels", "open_loop/moving_pixels")})
    total.update({f"open_loop/{p}/{part}": 0.0 for p in ("model", "last", "mean")
                  for part in ("full", "object", "moving")})
    assert summarise(total, 16)["one_step"]["skill_vs_mean"] == pytest.approx(0.0, abs=1e-6)
    g = pixel_gate([per_episode])
    assert not g["passes"] and g["verdict"].startswith("no reading: the model does not beat the last frame")
    assert " nor the mean image (skill 0.000 " in g["verdict"]


def test_order_between_groups_by_hand():
    from simeval.measures.dynamics_diversity.gate import order_between_groups

    tasks = np.array(["t"] * 4)
    base = np.ones((1, 4))
    a = (np.full((1, 4), 0.8), base, tasks)  # relative error 0.8 in every resample
    b = (np.full((1, 4), 0.5), base, tasks)  # 0.5
    out = order_between_groups(a, b)
    assert out["difference"] == pytest.approx(0.3) and out["interval"] == pytest.approx([0.3, 0.3])
    assert out["order"] == "a > b" and order_between_groups(b, a)["order"] == "a < b"
    noisy = (np.array([[0.1, 1.0, 0.2, 0.9]]), base, tasks)  # 0.55 with a wide interval around b's 0.5
    assert order_between_groups(noisy, b)["order"] == "none"


def test_paired_episodes_cancel_their_own_spread_and_each_resample_holds_the_same_episodes_in_both_groups():
    """Episodes whose errors spread widely (an episode's motion sets its size) but where group a leaves 10% more of
    the baseline's error than b on every episode: drawn independently the spread hides the order, drawn in pairs
    every resample's difference is exactly 0.1 (relative errors 1.1 x and x of the same episodes' sums)."""
    from simeval.measures.dynamics_diversity.gate import order_between_groups
    from simeval.stats.resample import paired_draws

    rng = np.random.default_rng(0)
    size = rng.uniform(0.1, 10.0, 12)  # the baseline's error per episode: how far the objects moved
    spread = rng.uniform(0.2, 0.9, 12)  # the share of it the model leaves, per episode
    tasks_a = np.repeat(["varied-0", "varied-1"], 6)
    tasks_b = np.repeat(["shared-0", "shared-1"], 6)
    a = ((spread + 0.1) * size)[None], size[None], tasks_a
    b = (spread * size)[None], size[None], tasks_b
    independent, paired = order_between_groups(a, b), order_between_groups(a, b, paired=True)
    assert independent["difference"] == pytest.approx(0.1) == paired["difference"]
    assert independent["order"] == "none"
    assert paired["interval"] == pytest.approx([0.1, 0.1]) and paired["order"] == "a > b"
    same = order_between_groups(b, b, paired=True)  # identical data (the looks' states): exactly no difference
    assert same["interval"] == [0.0, 0.0] and order_between_groups(b, b)["interval"][1] > 0.01
    first, second = paired_draws(3, 2, np.repeat([0, 1], 6), n_boot=5, seed=4)
    for (sa, ea), (sb, eb) in zip(first, second):
        assert np.array_equal(ea, eb) and set(ea[:6]) <= set(range(6)) and set(ea[6:]) <= set(range(6, 12))
        assert len(sa) == 3 and len(sb) == 2 and sb.max() < 2
    with pytest.raises(ValueError, match="same number of episodes per task"):
        order_between_groups(a, ((spread * size)[None, :10], size[None, :10], tasks_b[:10]), paired=True)


def test_the_html_report_shows_the_verdict_in_place_of_a_gated_runs_numbers():
    from simeval.report.html import headline_values

    one = {"model": {"object_error_per_pixel": 0.002}, "object_skill_vs_last": -3.0, "object_skill_vs_mean": 0.01}
    values = {"prediction": {"summary": {"one_step": one}},
              "gate": {"passes": False, "verdict": "no reading: the model does not beat the last frame"},
              "state": {"line": "one-step state error 0.001 (...)"}}
    shown = headline_values({"metric": "dynamics_diversity", "values": values})
    assert shown == [("pixel reading", "no reading: the model does not beat the last frame"),
                     ("state reading", "one-step state error 0.001 (...)")]
    values["gate"] = {"passes": True, "verdict": "reads"}
    shown = dict(headline_values({"metric": "dynamics_diversity", "values": values}))
    assert shown["object-focused one-step error (x1e-3/pixel)"] == pytest.approx(2.0)

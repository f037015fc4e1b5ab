"""The random dynamics-diversity controls (simeval.measures.dynamics_diversity.controls.random_draws): draws are fixed
by their seed and cover the ranges they state, objects stay in the arena, the varied group differs from the shared one
in its dynamics alone (same looks, same actions), the looks family in its frames alone (same states), and the dynamics
are the module docstring's, stepped by hand."""

from __future__ import annotations

import numpy as np
import pytest

from simeval.measures.dynamics_diversity.controls.random_draws import (ACTION_KINDS, KNOB_RANGES, KNOBS_USED, draw_control,
                                            make_control_group, one_disk_control, radius_of, render, step_object,
                                            write_control_group)


def test_draws_are_fixed_by_their_seed_and_cover_their_ranges():
    draws = [draw_control(s) for s in range(40)]
    assert draw_control(3) == draws[3]
    assert {d.n_objects for d in draws} == {1, 2, 3, 4}
    assert {d.action_kind for d in draws} == set(ACTION_KINDS)
    for d in draws:
        assert 0.02 <= d.area <= 0.12 and 0.6 <= d.camera_scale <= 1.0
        assert d.varied_knobs[0] in ("rotation", "gain")
        assert set(d.varied_knobs) <= set(KNOBS_USED[d.action_kind])
        for knobs in d.base:
            assert all(KNOB_RANGES[k][0] <= v <= KNOB_RANGES[k][1] for k, v in knobs.items())


def test_force_step_by_hand():
    knobs = {"rotation": 90.0, "gain": 1.0, "damping": 0.5, "restitution": 0.5, "mass": 2.0, "friction": 0.0}
    p, v = step_object("force", knobs, np.array([0.5, 0.5]), np.array([0.02, 0.0]), np.array([1.0, 0.0]), 0.1)
    # v <- 0.5 * (0.02, 0) + 0.03 * 1 / 2 * R(90)(1, 0) = (0.01, 0.015)
    np.testing.assert_allclose(v, [0.01, 0.015], atol=1e-12)
    np.testing.assert_allclose(p, [0.51, 0.515], atol=1e-12)
    # a wall at 1 - r: reflected, that velocity component reversed and scaled by the restitution
    p, v = step_object("velocity", {**knobs, "rotation": 0.0, "mass": 1.0}, np.array([0.88, 0.5]), np.zeros(2),
                       np.array([1.0, 0.0]), 0.1)
    np.testing.assert_allclose(p, [0.9 - (0.93 - 0.9), 0.5])
    np.testing.assert_allclose(v, [-0.025, 0.0])


@pytest.mark.parametrize("seed", [0, 5, 11])
def test_groups_differ_in_what_their_family_varies_alone(seed):
    d = draw_control(seed)
    kw = dict(n_tasks=2, episodes=3, n_actions=12, size=32)
    shared, varied = make_control_group(d, "shared", **kw), make_control_group(d, "varied", **kw)
    looks = make_control_group(d, "varied", kind="visual", **kw)
    for a, b, c in zip(shared.arrays, varied.arrays, looks.arrays):
        np.testing.assert_array_equal(a["action"], b["action"])  # the same pushes
        np.testing.assert_array_equal(a["object_poses"], c["object_poses"])  # the same motion, other looks
        assert not np.array_equal(a["image"], c["image"])
        np.testing.assert_array_equal(a["object_poses"][0], b["object_poses"][0])  # the same start
        r = radius_of(d)
        assert (b["object_poses"][..., :2] >= r - 1e-6).all() and (b["object_poses"][..., :2] <= 1 - r + 1e-6).all()
    assert any(not np.array_equal(a["object_poses"], b["object_poses"]) for a, b in zip(shared.arrays, varied.arrays))


def test_an_object_covers_its_share_of_the_frame():
    d = one_disk_control()
    frame = render(d, d.look, np.array([[[0.5, 0.5]]]), 64)[0].astype(float)
    covered = np.abs(frame - np.array(d.look.background)).sum(-1) / np.abs(
        np.subtract(d.look.colors[0], d.look.background)).sum()
    assert covered.sum() / 64**2 == pytest.approx(d.area, rel=0.03)


def test_written_groups_read_back_through_the_store(tmp_path):
    from simeval.episodes.dataset import StoreSource

    d = one_disk_control()
    paths = write_control_group(tmp_path, d, "varied", state_xy=True, n_tasks=1, episodes=2, n_actions=6, size=16)
    src = StoreSource(paths, "front")
    mem = make_control_group(d, "varied", n_tasks=1, episodes=2, n_actions=6, size=16)
    np.testing.assert_array_equal(src.read_full(0, "image"), mem.arrays[0]["image"])
    np.testing.assert_allclose(src.read_full(0, "state"), mem.arrays[0]["object_poses"][:, 0, :2])
    np.testing.assert_allclose(src.read_full(0, "object_poses"), mem.arrays[0]["object_poses"])


def _record(draw, group, reading, ratio, passes=True):
    base = [1.0, 2.0, 1.5, 1.0]
    return {"draw": draw, "group": group, "reading": reading, "seed": 0, "model": [[ratio * b for b in base]],
            "baseline": base, "tasks": ["a", "a", "b", "b"],
            "gate": {"passes": passes, "verdict": "reads" if passes else "no reading: the model does not beat x"}}


def test_the_controls_table_applies_its_written_criterion(tmp_path):
    import json

    from simeval.measures.dynamics_diversity.controls import random_sweep as rc

    runs = tmp_path / "controls" / "random" / "runs"
    runs.mkdir(parents=True)
    recs = [_record(0, "shared", "state", 0.5), _record(0, "varied", "state", 0.8), _record(0, "looks", "state", 0.9),
            _record(0, "shared", "pixel", 0.5), _record(0, "varied", "pixel", 0.3),
            _record(0, "looks", "pixel", 3.0, passes=False)]
    for i, r in enumerate(recs):
        (runs / f"r{i}.json").write_text(json.dumps(r))
    table = rc.build(type("Args", (), {"out": tmp_path})())
    verdict = {(r["family"], r["reading"]): r["verdict"] for r in table["rows"]}
    # varied above shared: right; looks above shared: wrong; varied below shared: wrong; a gated group: gated
    assert verdict == {("dynamics", "state"): "right", ("visual", "state"): "wrong",
                       ("dynamics", "pixel"): "wrong", ("visual", "pixel"): "gated"}
    assert table["counts"]["dynamics/pixel"]["wrong"] == 1
    # a change of the pixel model's settings leaves the saved state runs valid, and the other way round
    s = {"preset": "cpu", "protocol": {"steps": 1000, "model": {"pixel_norm": "standardise"}, "gate": {},
                                       "state_model": {"history": 4}}}
    t = {**s, "protocol": {**s["protocol"], "model": {"pixel_norm": "none"}}}
    assert rc.relevant(s, "state") == rc.relevant(t, "state") and rc.relevant(s, "pixel") != rc.relevant(t, "pixel")
    u = {**s, "protocol": {**s["protocol"], "state_model": {"history": 2}}}
    assert rc.relevant(s, "pixel") == rc.relevant(u, "pixel") and rc.relevant(s, "state") != rc.relevant(u, "state")


def test_the_pile_controls_table_applies_the_dynamics_criterion_by_hand(tmp_path, capsys):
    """Hand-built level records: by position the relative error rises 0.2 -> 0.5 with the friction spread (right),
    with the quaternions the top level is gated (gated); each relative error is sum(model) / sum(last state)."""
    import json
    from pathlib import Path

    from simeval.errors import UserError
    from simeval.measures.dynamics_diversity.controls import pile_state as pc

    args = type("Args", (), {"out": tmp_path, "episodes": 10, "heldout": [11, 30],
                             "conf_dir": Path(__file__).resolve().parent.parent / "conf"})()
    runs = tmp_path / "controls" / "pile" / "runs"
    runs.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i, name in enumerate(pc.LEVELS):
        for reads, share in (("position", 0.2 + 0.1 * i), ("pose", 1.0)):
            base = rng.uniform(1, 2, 20)
            model = [list(base * share * rng.uniform(0.97, 1.03, 20)) for _ in range(3)]
            gated = reads == "pose" and name == "friction100"
            (runs / f"{name}_{reads}.json").write_text(json.dumps({
                "level": name, "reads": reads, "settings": pc.settings(args), "model": model,
                "baseline": list(base), "tasks": ["t"] * 20, "read_dims": 150,
                "gate": {"passes": not gated, "verdict": "no reading: ..." if gated else "reads"},
                "summary": {"skill_vs_last_state": 1 - share, "model": share, "last_state": 1.0,
                            "constant_velocity": 0.5, "skill_vs_constant_velocity": 1 - 2 * share}}))
    table = pc.build(args)
    pos = table["readings"]["position"]
    assert pos["verdict"] == "right" and pos["top_minus_bottom"]["interval"][0] > 0
    rec = json.loads((runs / "friction000_position.json").read_text())
    assert pos["by_level"]["friction000"]["relative_error"] == pytest.approx(
        np.sum(rec["model"]) / (3 * np.sum(rec["baseline"])))
    assert table["readings"]["pose"]["verdict"] == "gated"
    assert "| particles by position (not the protocol's) |" in pc.markdown(table)
    (runs / "friction000_position.json").write_text(json.dumps({**rec, "settings": {"other": 1}}))
    with pytest.raises(UserError, match=r"^no run friction000_position under .+ with these settings \(--episodes 10 "
                                        r"--heldout 11 30\): run python src/controls.py pile with them$"):
        pc.build(args)  # a run of other settings is not read, and a table without it is not made
    with pytest.raises(UserError, match=r"^--episodes 10 --heldout 5 30: expected 2 <= episodes < first <= last"):
        pc.main(["--episodes", "10", "--heldout", "5", "30", "--replot"], conf_dir=args.conf_dir)


def test_the_pile_control_refuses_a_file_for_a_folder_and_committed_runs_of_other_settings(tmp_path):
    """--out/--tables naming a file (or a folder inside one) is one line before any work; a run that would replace
    a committed run record of other settings is refused before the collection (without --overwrite)."""
    import json
    import subprocess
    from pathlib import Path

    from simeval.errors import UserError
    from simeval.measures.dynamics_diversity.controls import pile_state as pc

    conf = Path(__file__).resolve().parent.parent / "conf"
    afile = tmp_path / "afile"
    afile.write_text("x")
    for option in ("--out", "--tables"):
        with pytest.raises(UserError, match=rf"^{option} {afile}/sub: {afile} is a file, not a folder; give a folder$"):
            pc.main([option, str(afile / "sub")], conf_dir=conf)
    runs = tmp_path / "controls" / "pile" / "runs"
    runs.mkdir(parents=True)
    (runs / "friction000_pose.json").write_text(json.dumps({"settings": {"episodes": 10}}))
    git = ["git", "-C", str(tmp_path), "-c", "user.email=t@t", "-c", "user.name=t"]
    subprocess.run(git[:3] + ["init", "-q"], check=True)
    subprocess.run(git + ["add", "controls"], check=True)
    subprocess.run(git + ["commit", "-qm", "runs"], check=True)
    with pytest.raises(UserError, match=r"friction000_pose.json is a committed run of other settings .+ write "
                                        r"elsewhere with --out DIR, or replace the committed runs with --overwrite$"):
        pc.main(["--episodes", "3", "--heldout", "4", "6", "--out", str(tmp_path), "--tables", str(tmp_path)],
                conf_dir=conf)
    assert not (tmp_path / "control_episodes").exists()  # refused before collecting

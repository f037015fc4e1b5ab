"""Table 5 rebuilt from result.json files: seeds of one cell pool, paper values sit beside ours, a settings clash
is refused."""

import pytest

from simeval.errors import UserError
from simeval.measures.generalization.table5 import build, write


def rec(path, k, n, seed=0, policy="cpu"):
    return {"path": path, "identity": {"pipeline": "gensim", "task_group": "piles", "policy": policy, "seed": seed},
            "values": {"splits": {"eval": {"success": {"k": k, "n": n}}}}}


def test_seeds_pool_and_the_table_shows_paper_and_interval(tmp_path):
    rows = build([rec("a", 2, 10), rec("b", 4, 10, seed=1)])
    piles = next(r for r in rows if r["group"] == "piles")
    assert piles["paper"] == 0.2 and piles["eval"]["k"] == 6 and piles["eval"]["n"] == 20
    assert piles["eval"]["ci"][0] == pytest.approx(0.1455, abs=1e-3)  # Wilson 6/20
    md = write(rows, tmp_path / "table5")["md"]
    line = next(x for x in md.read_text().splitlines() if "| piles |" in x)
    assert "0.20 |" in line and "0.30 [0.15, 0.52] (6/20)" in line


def test_runs_with_other_settings_are_refused():
    other_sampler = rec("b", 1, 10)
    other_sampler["identity"]["sampler"] = "ddpm"
    with pytest.raises(UserError, match="differ in sampler.*move the other runs out"):
        build([rec("a", 1, 10), other_sampler])


def test_runs_trained_on_successful_demonstrations_pool_only_with_each_other():
    successful = rec("b", 1, 10, seed=1)
    successful["identity"]["demonstrations"] = "successful"
    with pytest.raises(UserError, match="differ in demonstrations \\('all' vs 'successful'\\)"):
        build([rec("a", 1, 10), successful])  # a run from before the key: it trained on every episode
    # a run made before the identity recorded it says so in values.training
    earlier = rec("a", 2, 10)
    earlier["values"]["training"] = {"demonstrations": {"kept": "successful", "episodes": 30, "failed": 0}}
    (piles,) = [r for r in build([earlier, successful]) if r["group"] == "piles"]
    assert piles["eval"]["k"] == 3 and piles["eval"]["n"] == 20


def test_each_policy_preset_is_its_own_row_and_can_be_chosen():
    # the quick profile's tiny runs beside the cpu preset's: two rows, never pooled
    runs = [rec("a", 1, 10), rec("b", 5, 10, policy="tiny")]
    piles = [r for r in build(runs) if r["group"] == "piles"]
    assert [(r["policy"], r["eval"]["k"]) for r in piles] == [("cpu", 1), ("tiny", 5)]
    only = [r for r in build(runs, policy="tiny") if r["group"] == "piles"]
    assert [(r["policy"], r["eval"]["k"]) for r in only] == [("tiny", 5)]
    with pytest.raises(UserError, match="report.policy=paper: no generalization run of that preset.*cpu, tiny"):
        build(runs, policy="paper")


def test_a_group_named_as_in_the_paper_lands_in_the_suite_row():
    # imported BBSEA episodes carry the paper's "table-top"; the suite's group is `table`: one row, the paper's 0.0
    r = rec("a", 3, 10)
    r["identity"].update(pipeline="bbsea", task_group="table-top")
    bbsea = [x for x in build([r]) if x["pipeline"] == "bbsea"]
    assert [x["group"] for x in bbsea] == ["table", "drawer"]
    assert bbsea[0]["paper"] == 0.0 and (bbsea[0]["eval"]["k"], bbsea[0]["eval"]["n"]) == (3, 10)
    # a suite run and an imported run are different data: one cell refuses to pool them
    s = rec("b", 1, 10)
    s["identity"].update(pipeline="bbsea", task_group="table")
    with pytest.raises(UserError, match="task_group"):
        build([r, s])


def test_gensims_own_tasks_sit_beside_the_papers_gensim_value_as_a_row_of_their_own():
    """pipeline=gensim_own runs GenSim's own tasks, the ones the paper's authors measured: its row carries the paper's
    GenSim value (0.32 for placement), apart from the row of simeval's GenSim-style suite."""
    own, suite = rec("a", 3, 10), rec("b", 1, 10)
    own["identity"].update(pipeline="gensim_own", task_group="placement")
    suite["identity"].update(task_group="placement")
    rows = {(r["pipeline"], r["group"]): r for r in build([own, suite])}
    assert rows[("gensim_own", "placement")]["paper"] == 0.32 == rows[("gensim", "placement")]["paper"]
    assert rows[("gensim_own", "placement")]["eval"]["k"] == 3 and rows[("gensim", "placement")]["eval"]["k"] == 1
    assert ("metaworld", "ml10") not in rows and rows[("gensim", "piles")]["paper"] == 0.2  # not run: paper only


def test_a_table_extended_with_keep_holds_the_earlier_rows_and_the_new_runs(tmp_path):
    """--keep: the committed table gathers groups run on different machines; a row comes from exactly one side."""
    from simeval.measures.generalization.table5 import merge, read_rows

    placement = rec("p", 0, 50)
    placement["identity"]["task_group"] = "placement"
    earlier = build([placement, rec("a", 2, 10)])
    write(earlier, tmp_path / "earlier")
    kept = read_rows(tmp_path / "earlier.csv")
    assert kept == earlier  # counts, rates and Wilson intervals come back exactly

    drawer = rec("d", 5, 30)
    drawer["identity"].update(pipeline="bbsea", task_group="drawer")
    newer_piles = rec("n", 7, 20)
    rows = merge(kept, build([drawer, newer_piles]))
    cells = {(r["pipeline"], r["group"]): r for r in rows}
    assert (cells[("gensim", "placement")]["eval"]["k"], cells[("gensim", "placement")]["eval"]["n"]) == (0, 50)
    assert cells[("gensim", "piles")]["eval"]["k"] == 7  # the new run wins over the kept 2/10
    assert cells[("bbsea", "drawer")]["eval"]["k"] == 5 and cells[("gensim", "stacking")]["runs"] == 0
    assert len(rows) == len(cells) == 8  # one row per paper group, in the paper's order
    assert [r["group"] for r in rows][:4] == ["stacking", "placement", "piles", "assembling"]

    (tmp_path / "bad.csv").write_text((tmp_path / "earlier.csv").read_text().replace("(0/50)", "(none)"))
    with pytest.raises(UserError, match="bad.csv, line 3: eval cell .* has no \\(successes/rollouts\\)"):
        read_rows(tmp_path / "bad.csv")
    (tmp_path / "more.csv").write_text((tmp_path / "earlier.csv").read_text().replace("(0/50)", "(60/50)"))
    with pytest.raises(UserError, match="more.csv, line 3: eval cell .* successes <= rollouts"):
        read_rows(tmp_path / "more.csv")
    (tmp_path / "t4.csv").write_text("pipeline,group,preset\n")
    with pytest.raises(UserError, match="t4.csv: not a Table 5 CSV"):
        read_rows(tmp_path / "t4.csv")
    with pytest.raises(UserError, match="nope.csv: cannot read it"):
        read_rows(tmp_path / "nope.csv")


def test_a_kept_table_cut_short_or_not_a_csv_is_a_user_error(tmp_path):
    from simeval.measures.generalization.table5 import read_rows
    from simeval.measures.dynamics_diversity import table4

    write(build([rec("a", 2, 10)]), tmp_path / "t5")
    text = (tmp_path / "t5.csv").read_text().splitlines()
    (tmp_path / "cut.csv").write_text("\n".join(text[:3] + [text[3][:20]]) + "\n")
    with pytest.raises(UserError, match="cut.csv, line 4: .* cells, expected 10"):
        read_rows(tmp_path / "cut.csv")
    (tmp_path / "binary.csv").write_bytes(b"\xff\xfe\x00garbage")
    for reader in (read_rows, table4.read_rows):
        with pytest.raises(UserError, match="binary.csv: "):
            reader(tmp_path / "binary.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(UserError, match="empty.csv: not a Table 4 CSV"):
        table4.read_rows(tmp_path / "empty.csv")
    table4.write(table4.build([]), tmp_path / "t4")
    lines = (tmp_path / "t4.csv").read_text().splitlines()
    (tmp_path / "t4cut.csv").write_text("\n".join(lines[:2] + [lines[2][:15]]) + "\n")
    with pytest.raises(UserError, match="t4cut.csv, line 3: .* cells, expected 18"):
        table4.read_rows(tmp_path / "t4cut.csv")
    (tmp_path / "header_only.csv").write_text(text[0] + "\n")  # the report always writes the paper's rows
    with pytest.raises(UserError, match="header_only.csv: not a Table 5 CSV .*: no rows"):
        read_rows(tmp_path / "header_only.csv")


def test_runs_of_one_cell_at_other_training_seeds_pool_but_other_settings_do_not():
    """A generalization run records its training seed twice (identity.seed and identity.settings.train.seed):
    runs that differ only there, or in how often they log and checkpoint, are one cell's seeds; any other
    difference is another experiment."""
    from simeval.errors import UserError

    def rec(seed, lr=3e-4, k=1, every=500):
        ident = {"metric": "generalization", "pipeline": "bbsea", "task_group": "drawer", "policy": "cpu",
                 "seed": seed, "settings": {"train": {"lr": lr, "seed": seed, "log_every": every,
                                                      "checkpoint_every": every}}}
        return {"identity": ident, "path": f"r{seed}/{lr}/result.json",
                "values": {"splits": {"eval": {"success": {"k": k, "n": 5}}}}}

    row = next(r for r in build([rec(0), rec(1, k=2), rec(2, k=0, every=20)]) if r["group"] == "drawer")
    assert row["runs"] == 3 and (row["eval"]["k"], row["eval"]["n"]) == (3, 15)
    with pytest.raises(UserError, match="settings.train.lr") as refused:
        build([rec(0), rec(1, lr=1e-3, every=20)])
    assert "every" not in str(refused.value)


def test_the_figure_draws_a_cell_with_no_success_in_100_rollouts(tmp_path):
    """Wilson's lower bound of 0/100 computed in floats was 3.5e-18, a hair above the rate 0, and matplotlib refused
    the negative error bar (it once stopped the whole rebuild): the bounds at k = 0 and k = n are exact now."""
    from simeval.stats.intervals import wilson_interval
    from simeval.measures.generalization.table5 import plot

    assert wilson_interval(0, 100)[0] == 0.0 and wilson_interval(100, 100)[1] == 1.0

    rows = build([rec("a", 0, 100)])
    paths = plot(rows, tmp_path / "t5.png")
    assert (tmp_path / "t5.png").stat().st_size > 10_000 and len(paths) == 2


def test_the_figure_wraps_pipelines_into_rows_of_at_most_ten_groups(tmp_path):
    """Five pipelines of 9, 4, 4, 8 and 2 groups in one row were 5300 px wide: in order, a panel goes on the open row
    while that row stays within 10 groups, and a panel wider than a row gets one of its own."""
    from simeval.measures.generalization.table5 import pack_panels, plot

    assert pack_panels([9, 4, 4, 8, 2], 10) == [[0], [1, 2], [3, 4]]
    assert pack_panels([3, 3, 3, 1], 10) == [[0, 1, 2, 3]]
    assert pack_panels([12, 1], 10) == [[0], [1]]
    assert pack_panels([], 10) == []

    import matplotlib.image

    rows = build([rec("a", 0, 10), {**rec("b", 1, 10), "identity": {**rec("b", 1, 10)["identity"],
                                                                       "pipeline": "bbsea", "task_group": "drawer"}}])
    plot(rows, tmp_path / "t5.png", formats=("png",))
    height, width = matplotlib.image.imread(tmp_path / "t5.png").shape[:2]
    assert width < 2000 and height < width / 2  # the paper's 8 groups of 3 pipelines: one row, 150 dpi


def test_eval_progress_pools_by_rollouts_and_kept_rows_take_it_from_their_detail(tmp_path):
    """The paper's GenSim column is a step-wise reward: the eval progress beside our success. Runs of one cell weigh
    by their rollouts (0.5 over 10 and 0.2 over 30: (5 + 6) / 40 = 0.275); a row kept from a table written before
    the column existed takes it from its group's eval line in the per-task table."""
    from simeval.measures.generalization.table5 import HEAD_WITHOUT_PROGRESS, eval_progress_from_detail, read_rows

    a, b = rec("a", 2, 10), rec("b", 3, 30, seed=1)
    a["values"]["splits"]["eval"]["mean_progress"] = 0.5
    b["values"]["splits"]["eval"]["mean_progress"] = 0.2
    piles = next(r for r in build([a, b]) if r["group"] == "piles")
    assert piles["eval_progress"] == pytest.approx(0.275)
    line = next(x for x in write([piles], tmp_path / "t5")["md"].read_text().splitlines() if "| piles |" in x)
    assert "| 0.12 [0.05, 0.26] (5/40) | 0.28 |" in line  # success, then progress, in the eval columns
    assert read_rows(tmp_path / "t5.csv")[0]["eval_progress"] == pytest.approx(0.28)

    old = tmp_path / "old.csv"  # a table as written before the column: read as having no progress
    old.write_text("\n".join([",".join(HEAD_WITHOUT_PROGRESS),
                              ('bbsea,drawer,0.00,"0.17 [0.10, 0.26] (15/90)","0.18 [0.11, 0.27] (16/90)",'
                               '"0.00 [0.00, 0.20] (0/15)",cpu,3')]) + "\n")
    kept = read_rows(old)
    assert kept[0]["eval_progress"] is None and kept[0]["eval"]["k"] == 15 and kept[0]["heldout"]["n"] == 15
    detail = [["bbsea", "drawer", "cpu", "eval", "all tasks", "0.17 (15/90)", "-", "-", "-", "0.31", "3"],
              ["bbsea", "drawer", "cpu", "eval", "close-drawer", "0.50 (15/30)", "-", "-", "-", "0.70", "3"],
              ["bbsea", "drawer", "cpu", "train", "all tasks", "0.18 (16/90)", "-", "-", "-", "0.40", "3"]]
    assert eval_progress_from_detail(kept, detail)[0]["eval_progress"] == 0.31
    assert eval_progress_from_detail(kept, detail[1:])[0]["eval_progress"] is None  # no eval group line: none


def test_the_table_says_which_demonstrations_each_row_trained_on_and_reads_older_tables_as_all(tmp_path):
    """GenSim's demos.py keeps only completed demonstrations (demonstrations=successful); a row says which it
    trained on, random (nothing trained) says '-', and a table written before the column read all its trained rows
    as 'all' (the only choice then)."""
    from simeval.measures.generalization.table5 import HEAD_WITHOUT_DEMONSTRATIONS, read_rows

    successful = rec("s", 1, 10)
    successful["identity"].update(task_group="assembling", demonstrations="successful")
    chance = rec("r", 0, 10, policy="random")
    chance["identity"]["demonstrations"] = "successful"  # the pipeline's default rides along; nothing trained
    rows = build([rec("a", 2, 10), successful, chance])
    write(rows, tmp_path / "t5")
    lines = (tmp_path / "t5.csv").read_text().splitlines()
    assert lines[0].endswith(",Policy,Demonstrations,Runs")
    by_group = {(r["group"], r["policy"]): r["demonstrations"] for r in read_rows(tmp_path / "t5.csv") if r["runs"]}
    assert by_group == {("piles", "cpu"): "all", ("piles", "random"): None, ("assembling", "cpu"): "successful"}

    old = tmp_path / "old.csv"
    old.write_text("\n".join([",".join(HEAD_WITHOUT_DEMONSTRATIONS),
                              'gensim,piles,0.20,"0.20 [0.06, 0.51] (2/10)",0.30,-,-,cpu,1',
                              'gensim,piles,0.20,"0.00 [0.00, 0.28] (0/10)",0.00,-,-,random (chance: nothing trained),1'
                              ]) + "\n")
    assert [(r["policy"], r["demonstrations"]) for r in read_rows(old)] == [("cpu", "all"), ("random", None)]

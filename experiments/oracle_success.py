"""Oracle success per task of a suite over N seeds (the bar: >= 90% over 100 seeds for every task).
Writes outputs/tables/oracle_success_<suite>.{csv,md,tex}. Rendering is off: only physics and the oracle run.

Every finished episode is appended to outputs/tables/oracle_success_<suite>_episodes.csv (task, seed, success,
...), so a killed or time-limited run resumes where it stopped and the table is rebuilt from that file; runs for
different --tasks add up. Delete the file (or pass --fresh) after changing the suite, goals or oracle.

    python experiments/oracle_success.py [--suite gensim] [--seeds 100] [--workers 2] [--tasks a,b]
                                         [--budget-s SECONDS] [--fresh] [--table-only] [--split train|eval]

--split eval runs each task under its own `variations.eval` on the evaluation seeds (100000 + i), writing
oracle_success_<suite>_eval.*: the varied distribution must stay solvable, or a policy's failures there say
nothing about generalization.
"""

from __future__ import annotations

import csv
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from simeval.cli import OneLineParser

ROOT = Path(__file__).resolve().parents[1]

FIELDS = ["task", "group", "seed", "success", "progress", "steps", "seconds", "error"]


EVAL_SEED_OFFSET = 100000  # conf/variation/eval.yaml


def one(args):
    from simeval.sim.rollout import RecordSettings, run_episode
    from simeval.sim.tasks.spec import load_spec

    path, seed, split = args
    spec = load_spec(path)
    t0 = time.perf_counter()
    try:
        if split == "eval":
            ep = run_episode(spec, EVAL_SEED_OFFSET + seed, RecordSettings(cameras=()),
                             variation=spec.variations.get("eval") or {})
        else:
            ep = run_episode(spec, seed, RecordSettings(cameras=()))
        return [spec.name, spec.group, seed, int(ep.success), round(float(ep.progress[-1]), 4), ep.n_steps,
                round(time.perf_counter() - t0, 2), ""]
    except Exception as e:  # a crash is a failure of that seed, reported with its message
        return [spec.name, spec.group, seed, 0, 0.0, 0, round(time.perf_counter() - t0, 2), f"{type(e).__name__}: {e}"]


def read_episodes(path: Path) -> dict[tuple[str, int], dict]:
    if not path.exists():
        return {}
    with path.open(newline="", encoding="utf-8") as f:
        return {(r["task"], int(r["seed"])): r for r in csv.DictReader(f)}


def table_rows(episodes: dict[tuple[str, int], dict], tasks: list[str], seeds: int) -> list[list[str]]:
    rows = []
    for task in tasks:
        r = sorted((x for (t, s), x in episodes.items() if t == task and s < seeds), key=lambda x: int(x["seed"]))
        if not r:
            continue
        n, ok = len(r), sum(int(x["success"]) for x in r)
        fails = [x["seed"] + (f" ({x['error'][:60]})" if x["error"] else "") for x in r if not int(x["success"])]
        rows.append([r[0]["group"], task, f"{ok}/{n}", f"{100 * ok / n:.0f}%",
                     f"{sum(float(x['progress']) for x in r) / n:.2f}", f"{sum(int(x['steps']) for x in r) / n:.0f}",
                     f"{sum(float(x['seconds']) for x in r) / n:.2f}", " ".join(fails) or "-"])
    return sorted(rows)


def main() -> None:
    from simeval.writing.tables import write_table
    from simeval.sim.tasks.spec import suite_dir

    ap = OneLineParser()
    ap.add_argument("--suite", default="gensim")
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--tasks", default="")
    ap.add_argument("--budget-s", type=float, default=0.0, help="stop starting episodes after this many seconds")
    ap.add_argument("--fresh", action="store_true", help="forget the episodes of earlier runs")
    ap.add_argument("--table-only", action="store_true", help="rebuild the table from the episodes file, run nothing")
    ap.add_argument("--split", choices=["train", "eval"], default="train",
                    help="eval: each task under its own variations.eval, seeds 100000+")
    args = ap.parse_args()
    paths = sorted(p for p in (suite_dir(args.suite)).glob("*.yaml") if p.name != "splits.yaml")
    if args.tasks:
        paths = [p for p in paths if p.stem in args.tasks.split(",")]
    out = ROOT / "outputs" / "tables"
    out.mkdir(parents=True, exist_ok=True)
    name = f"oracle_success_{args.suite}" + ("_eval" if args.split == "eval" else "")
    ep_path = out / f"{name}_episodes.csv"
    if args.fresh and ep_path.exists():
        ep_path.unlink()
    done = read_episodes(ep_path)
    # seed-major order: a run cut short by --budget-s covers every task about equally
    jobs = [] if args.table_only else [(str(p), s, args.split) for s in range(args.seeds) for p in paths if (p.stem, s) not in done]
    t0 = time.monotonic()
    new = ep_path.exists()
    with ep_path.open("a", newline="", encoding="utf-8") as f, ProcessPoolExecutor(args.workers) as pool:
        writer = csv.writer(f)
        if not new:
            writer.writerow(FIELDS)
        pending, queue = set(), list(reversed(jobs))
        while queue or pending:
            while queue and len(pending) < 2 * args.workers and not (args.budget_s and time.monotonic() - t0 > args.budget_s):
                pending.add(pool.submit(one, queue.pop()))
            if not pending:
                break
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                writer.writerow(fut.result())
            f.flush()
    if queue:
        print(f"budget reached: {len(queue)} episodes not run (rerun to resume)")
    episodes = read_episodes(ep_path)
    names = [p.stem for p in paths] if args.tasks else sorted({t for t, _ in episodes})
    rows = table_rows(episodes, names, args.seeds)
    counts = sorted({int(r[2].split("/")[1]) for r in rows})
    over = f"{counts[0]} seeds" if len(counts) == 1 else "seeds 0..n-1 (n per task in the Success column)"
    header = ["Group", "Task", "Success", "Rate", "Mean progress", "Mean steps", "s/episode", "Failed seeds"]
    split = " under each task's eval variation (seeds 100000 + i)" if args.split == "eval" else ""
    notes = [f"Oracle success over {over} per task ({args.suite} suite){split}; per-episode results in "
             f"{ep_path.name}."]
    if len(counts) > 1 or (counts and counts[0] < args.seeds):
        notes.append(f"Fewer than {args.seeds} seeds for some tasks: the run was cut by its time budget; run the "
                     "same command again to resume.")
    write_table(out / name, header, rows, caption=notes[0], notes=notes)
    print(f"| {' | '.join(header)} |")
    for r in rows:
        print(f"| {' | '.join(r)} |")
    print("all tasks >= 90%:", all(int(r[2].split("/")[0]) >= 0.9 * int(r[2].split("/")[1]) for r in rows))


if __name__ == "__main__":
    main()

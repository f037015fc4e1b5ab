"""Tools around Table 5's generalization runs (simeval.measures.generalization), from one command:

    python src/generalization_tools.py offline pack|train|score|export|import ...
        # train a Diffusion Policy where the simulator is not (a GPU machine), score it on held-out demonstrations
    python src/generalization_tools.py vs-random --policy RUN [RUN ...] --random RUN [RUN ...]
        # a trained policy's rollout progress against the chance baseline's, per split
    python src/generalization_tools.py eval-vs-train RUN [RUN ...]
        # the generalization gap scene by scene: each eval rollout against its train twin
    python src/generalization_tools.py variation-probe [--out-dir DIR] <generalization overrides>
        # which eval scenes a variation changes, before any training (nothing trained or rolled out)
    python src/generalization_tools.py <tool> --help    # that tool's options

RUN is a src/generalization.py run folder (its result.json). A wrong option is one line on stderr, exit status 2.
"""

from pathlib import Path

CONF = Path(__file__).resolve().parent.parent / "conf"
TOOLS = {"offline": "offline", "vs-random": "vs_random", "eval-vs-train": "eval_vs_train",
         "variation-probe": "variation_probe"}


def main(argv: list[str] | None = None) -> None:
    from simeval.cli import run_subcommand

    run_subcommand(argv, __doc__, tuple(TOOLS), "tool", "python src/generalization_tools.py", run)


def run(tool: str, argv: list[str]) -> None:
    import importlib

    importlib.import_module(f"simeval.measures.generalization.{TOOLS[tool]}").main(argv, conf_dir=CONF)


if __name__ == "__main__":
    main()

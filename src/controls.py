"""Controls of dynamics diversity, groups whose answer is known (simeval.measures.dynamics_diversity.controls), from
one command:

    python src/controls.py dynamics [--episodes 10 40]     # physics shared vs varied, identical visuals
    python src/controls.py visual --episodes 10            # identical physics, the robot's look varied
    python src/controls.py dose|dose_drawer|dose_push      # a real task at four levels of one variation knob
    python src/controls.py random [--draws 0 1 --jobs 2]   # 12 configurations drawn at random, both readings
    python src/controls.py plateau [--rows 0 1]            # the one-disk diagnosis: when the model leaves the
                                                           # mean-image plateau
    python src/controls.py <control> --help                # that control's options

Each saves its runs as they end (a killed control resumes), writes its table and figure under outputs/, and never
replaces a committed one unless given --overwrite. A wrong option is one line on stderr, exit status 2.
"""

import sys
from pathlib import Path

CONF = Path(__file__).resolve().parent.parent / "conf"
FIXED = ("dynamics", "visual", "dose", "dose_drawer", "dose_push")
CONTROLS = (*FIXED, "random", "plateau")


def main(argv: list[str] | None = None) -> None:
    from simeval.errors import UserError

    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in ("-h", "--help"):
        print(__doc__)
        return
    if not argv:
        print(f"error: name a control: {', '.join(CONTROLS)} (python src/controls.py --help)", file=sys.stderr)
        sys.exit(2)
    if argv[0] not in CONTROLS:
        print(f"error: control {argv[0]!r}: expected one of {', '.join(CONTROLS)}", file=sys.stderr)
        sys.exit(2)
    from simeval.measures.dynamics_diversity.controls import fixed, plateau, random_sweep

    try:
        if argv[0] in FIXED:
            fixed.main(argv, conf_dir=CONF)
        else:
            {"random": random_sweep, "plateau": plateau}[argv[0]].main(argv[1:], conf_dir=CONF)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()

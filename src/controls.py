"""Controls of dynamics diversity, groups whose answer is known (simeval.measures.dynamics_diversity.controls), from
one command:

    python src/controls.py dynamics [--episodes 10 40]     # physics shared vs varied, identical visuals
    python src/controls.py visual --episodes 10            # identical physics, the robot's look varied
    python src/controls.py dose|dose_drawer|dose_push      # a real task at four levels of one variation knob
    python src/controls.py random [--draws 0 1 --jobs 2]   # 12 configurations drawn at random, both readings
    python src/controls.py pile                            # a pile's particles' friction at four levels: the
                                                           # state reading of a pile
    python src/controls.py plateau [--rows 0 1]            # the one-disk diagnosis: when the model leaves the
                                                           # mean-image plateau
    python src/controls.py gensim_own [--seeds 0 1 2]      # GenSim's own episodes: a four-task generalist against
                                                           # one-task specialists at equal data
    python src/controls.py <control> --help                # that control's options

Each saves its runs as they end (a killed control resumes), writes its table and figure under outputs/, and never
replaces a committed one unless given --overwrite. A wrong option is one line on stderr, exit status 2.
"""

from pathlib import Path

CONF = Path(__file__).resolve().parent.parent / "conf"
FIXED = ("dynamics", "visual", "dose", "dose_drawer", "dose_push")
CONTROLS = (*FIXED, "random", "pile", "plateau", "gensim_own")


def main(argv: list[str] | None = None) -> None:
    from simeval.cli import run_subcommand

    run_subcommand(argv, __doc__, CONTROLS, "control", "python src/controls.py", run)


def run(control: str, argv: list[str]) -> None:
    from simeval.measures.dynamics_diversity.controls import fixed, gensim_own, pile_state, plateau, random_sweep

    if control in FIXED:
        fixed.main([control, *argv], conf_dir=CONF)
    else:
        {"random": random_sweep, "pile": pile_state, "plateau": plateau,
         "gensim_own": gensim_own}[control].main(argv, conf_dir=CONF)


if __name__ == "__main__":
    main()

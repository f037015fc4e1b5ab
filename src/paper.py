"""Every measurement of the paper for some pipelines, at the cost a profile sets (simeval.orchestrate says what
each stage runs; conf/paper.yaml and conf/profile/ configure it).

    python src/paper.py profile=quick                          # minutes: every stage, tiny models
    python src/paper.py profile=cpu "pipelines=[gensim]"       # one pipeline, all aspects, cpu presets
    python src/paper.py profile=quick profile.episodes=6       # a profile's value changed for this run
    make paper PROFILE=quick        make evaluate PIPELINE=bbsea PROFILE=quick
"""

import shlex
from pathlib import Path

import hydra
import yaml
from omegaconf import DictConfig, OmegaConf

from simeval.cli import exit_cleanly_on_user_error, launch
from simeval.errors import UserError

HERE = Path(__file__).resolve().parent
CONF = HERE.parent / "conf"


def pipeline_suites() -> dict[str, str | None]:
    """{pipeline: its simeval suite or None}, from conf/pipeline/*.yaml."""
    return {p.stem: (yaml.safe_load(p.read_text()) or {}).get("suite")
            for p in sorted((CONF / "pipeline").glob("*.yaml"))}


def names(value, key: str) -> list[str]:
    """A list of names from the config: `[a,b]`, or one name (`pipelines=gensim`), or a comma list as a string."""
    out = value.split(",") if isinstance(value, str) else list(value or [])
    if not out or not all(isinstance(n, str) and n for n in out):
        raise UserError(f"{key}={value!r}: give a list of names, e.g. {key}=[a,b]")
    return out


@hydra.main(version_base="1.3", config_path="../conf", config_name="paper")
@exit_cleanly_on_user_error
def main(cfg: DictConfig) -> None:
    from simeval.orchestrate import run_profile

    profile = OmegaConf.to_container(cfg.profile, resolve=True)
    # absolute: the stages run from the project root, the user may not (out=mine is the user's ./mine)
    out = Path(cfg.out).resolve()
    run_profile(profile, names(cfg.pipelines, "pipelines"), set(names(cfg.stages, "stages")), out,
                suites=pipeline_suites(), entries=HERE, cwd=HERE.parent, launcher_name=cfg.launcher,
                sbatch_args=shlex.split(cfg.sbatch_args or ""))


if __name__ == "__main__":
    launch(main)

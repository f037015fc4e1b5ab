"""Which Pipeline (simeval.pipelines.base) a `conf/pipeline/<name>.yaml` describes: its `_target_` (a Pipeline class
on the user's PYTHONPATH: a plugin, no edit to simeval), else its `kind` (KINDS: simeval's own kinds), or, where it
names neither, its own code when it has `native:` settings (GenSim's checkout) else its simeval suite."""

from __future__ import annotations

from collections.abc import Mapping

from simeval.errors import UserError
from simeval.pipelines.base import Pipeline, SuitePipeline
from simeval.pipelines.gensim_own.pipeline import GensimOwnPipeline
from simeval.pipelines.gymnasium.pipeline import GymnasiumPipeline
from simeval.pipelines.metaworld.pipeline import MetaworldPipeline

KINDS: dict[str, type[Pipeline]] = {"suite": SuitePipeline, "gensim_checkout": GensimOwnPipeline,
                                    "metaworld": MetaworldPipeline, "gymnasium": GymnasiumPipeline}


def plugin_class(target: str) -> type[Pipeline]:
    """The Pipeline class a config's `_target_` names (module.Class, importable from the user's PYTHONPATH)."""
    from simeval.pipelines.base import load_target

    cls = load_target(target, "pipeline._target_")
    if not (isinstance(cls, type) and issubclass(cls, Pipeline)):
        raise UserError(f"pipeline._target_={target}: is not a simeval.pipelines.base.Pipeline class")
    return cls


def pipeline_class(pipeline: Mapping, needs: str = "closed-loop evaluation") -> type[Pipeline]:
    """The Pipeline class of a pipeline config; a UserError naming the key when it has none (`needs`: what for)."""
    if pipeline.get("_target_"):
        return plugin_class(str(pipeline["_target_"]))
    kind = pipeline.get("kind") or ("gensim_checkout" if pipeline.get("native") else
                                    "suite" if pipeline.get("suite") else None)
    if kind is None:
        raise UserError(f"pipeline={pipeline['name']} has no simeval suite (pipeline.suite is null) and no code of "
                        f"its own to run (pipeline.native): {needs} needs one")
    if kind not in KINDS:
        raise UserError(f"pipeline.kind={kind!r}: expected one of {', '.join(sorted(KINDS))}")
    missing = [f"pipeline.{key}" for key in KINDS[kind].requires if not pipeline.get(key)]
    if missing:
        raise UserError(f"pipeline.kind={kind} needs {' and '.join(missing)} (pipeline={pipeline['name']} sets "
                        "none)")
    return KINDS[kind]


def pipeline_from_config(pipeline: Mapping) -> Pipeline:
    """The Pipeline a `conf/pipeline/<name>.yaml` describes (pipeline_class), built from it."""
    return pipeline_class(pipeline).from_config(pipeline)


def own_code_args(pipeline: Mapping) -> str | None:
    """For a pipeline whose own code records its episodes: what its collect command needs beyond pipeline= (its
    class's `collect_args`, e.g. GenSim's checkout); None for a simeval suite or a pipeline with nothing to run."""
    try:
        cls = pipeline_class(pipeline)
    except UserError:
        return None
    return None if cls is SuitePipeline else cls.collect_args

"""Which Pipeline (simeval.pipelines.base) a `conf/pipeline/<name>.yaml` describes: its `kind`, or, where it names
none, its own code when it has `native:` settings (GenSim's checkout, the one such kind so far) else its simeval
suite. A new kind of pipeline is one entry in KINDS."""

from __future__ import annotations

from collections.abc import Mapping

from simeval.errors import UserError
from simeval.pipelines.base import Pipeline, SuitePipeline
from simeval.pipelines.gensim.pipeline import GensimOwnPipeline
from simeval.pipelines.metaworld.pipeline import MetaworldPipeline

KINDS: dict[str, type[Pipeline]] = {"suite": SuitePipeline, "gensim_checkout": GensimOwnPipeline,
                                    "metaworld": MetaworldPipeline}


def pipeline_class(pipeline: Mapping, needs: str = "closed-loop evaluation") -> type[Pipeline]:
    """The Pipeline class of a pipeline config; a UserError naming the key when it has none (`needs`: what for)."""
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

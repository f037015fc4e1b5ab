"""Which Pipeline (simeval.pipelines.base) a `conf/pipeline/<name>.yaml` describes."""

from __future__ import annotations

from collections.abc import Mapping

from simeval.errors import UserError
from simeval.pipelines.base import Pipeline, SuitePipeline
from simeval.pipelines.gensim.pipeline import GensimOwnPipeline
from simeval.sim.spec import SUITES_DIR


def pipeline_from_config(pipeline: Mapping) -> Pipeline:
    """The Pipeline a `conf/pipeline/<name>.yaml` describes: its own code where it has `native:` settings, else its
    simeval suite; a UserError when it has neither."""
    if pipeline.get("native"):
        return GensimOwnPipeline.from_config(pipeline)
    if pipeline.get("suite"):
        return SuitePipeline(pipeline["name"], SUITES_DIR / pipeline["suite"])
    raise UserError(f"pipeline={pipeline['name']} has no simeval suite (pipeline.suite is null) and no code of its "
                    "own to run (pipeline.native): closed-loop evaluation needs one")

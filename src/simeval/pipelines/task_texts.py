"""Task sets of each pipeline, loaded from the user's own sources.

`load_tasks(pipeline, source, ...)` is the one entry: `source="auto"` takes the first configured source in the
pipeline's order below; naming a source that is not configured, or having none, raises `SourceNotConfigured`
whose `hint` names the config keys (and environment variables) that would provide one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from simeval.pipelines.bbsea import tasks as bbsea
from simeval.pipelines.custom import tasks as custom
from simeval.pipelines.gensim import tasks as gensim
from simeval.pipelines.robogen import tasks as robogen
from simeval.pipelines.task_records import (
    ALL_GROUPS,
    SourceNotConfigured,
    TaskText,
    TaskSourceError,
    groups_of,
    select_group,
)

__all__ = ["ALL_GROUPS", "SOURCES", "SourceNotConfigured", "TaskText", "TaskSourceError", "groups_of", "load_tasks",
           "select_group"]


@dataclass(frozen=True)
class Source:
    name: str
    needs: str  # the option (config key under `pipeline`) that must be set for this source
    env: str | None  # the environment variable the shipped config reads that key from
    load: Callable[[dict], list[TaskText]]
    auto: bool = True  # tried by source=auto; False: only when named


def load_suite_tasks(pipeline: str, suite: str, text_template: str = "{description}") -> list[TaskText]:
    """simeval's own PyBullet suite: one task per spec, its description rendered for seed 0."""
    from simeval.sim.tasks.spec import suite_dir, load_suite, sample_instance

    out = []
    for spec in load_suite(suite_dir(suite)):
        desc = sample_instance(spec, 0).description
        out.append(TaskText(pipeline, spec.group, spec.name, desc, text_template.format(name=spec.name, description=desc),
                        {"spec": spec.source}))
    return out


def _template(o: dict, default: str) -> str:
    return o.get("text_template") or default


SOURCES: dict[str, list[Source]] = {
    "gensim": [
        Source("grouped_file", "grouped_file", "GENSIM_DESCS",
               lambda o: gensim.load_grouped_texts(o["grouped_file"], "gensim", o.get("group_aliases"))),
        Source("checkout", "root", "GENSIM_ROOT",
               lambda o: gensim.load_gensim_checkout(o["root"], _template(o, gensim.DEFAULT_TEMPLATE))),
        # Not tried by auto: a Table 3 "GenSim" row must never silently become simeval's own suite.
        Source("suite", "suite", None, lambda o: load_suite_tasks("gensim", o["suite"], _template(
            o, gensim.DEFAULT_TEMPLATE)), auto=False),
    ],
    "robogen": [
        Source("checkout", "root", "ROBOGEN_ROOT",
               lambda o: robogen.load_robogen_checkout(o["root"], _template(o, robogen.DEFAULT_TEMPLATE))),
        Source("file", "tasks_path", "ROBOGEN_TASKS",
               lambda o: robogen.load_robogen_records(o["tasks_path"], _template(o, robogen.DEFAULT_TEMPLATE))),
        # Not tried by auto, as for GenSim: a RoboGen row must never silently become simeval's own suite.
        Source("suite", "suite", None, lambda o: load_suite_tasks("robogen", o["suite"], _template(
            o, robogen.DEFAULT_TEMPLATE)), auto=False),
    ],
    "bbsea": [
        Source("output", "root", "BBSEA_ROOT", lambda o: bbsea.load_bbsea_output(o["root"])),
        Source("file", "tasks_path", "BBSEA_TASKS", lambda o: bbsea.load_bbsea_list(o["tasks_path"])),
        # simeval's own BBSEA-style suite; not tried by auto, as for GenSim
        Source("suite", "suite", None, lambda o: load_suite_tasks("bbsea", o["suite"], _template(o, "{description}")),
               auto=False),
    ],
    "custom": [
        Source("file", "tasks_path", None,
               lambda o: custom.load_custom(o["tasks_path"], o.get("name") or "custom", _template(o, "{description}"))),
    ],
}


# pipelines with episodes but no task texts of their own: why, and what to do instead
NO_TASK_TEXTS = {
    "metaworld": "Meta-World's package ships no task descriptions (its tasks are named, not described): text "
                 "diversity does not apply to it",
    "gensim_own": "its task texts are GenSim's own: run pipeline=gensim with pipeline.root= the same checkout",
}


def source_hint(pipeline: str) -> str:
    parts = []
    for s in (x for x in SOURCES[pipeline] if x.auto):
        env = f" (or env {s.env})" if s.env else ""
        parts.append(f"pipeline.{s.needs}=...{env} for source '{s.name}'")
    return "set " + ", or ".join(parts)


SOURCE_OPTIONS = ("root", "grouped_file", "tasks_path", "suite", "text_template", "group_aliases", "tasks")


def config_tasks(pipeline: str, tasks, text_template: str | None = None) -> list[TaskText]:
    """The tasks a pipeline config lists itself (`tasks: {name: {group, description, ...}}`, a Gymnasium pipeline's
    or a plugin's): `pipeline.source: config`, or any pipeline simeval has no loader of that lists them."""
    out = []
    for name, t in dict(tasks or {}).items():
        t = dict(t or {})
        if not t.get("group"):
            raise TaskSourceError(f"pipeline.tasks.{name}: no group")
        desc = str(t.get("description") or str(name).replace("-", " "))
        out.append(TaskText(pipeline, str(t["group"]), str(name), desc,
                        (text_template or "{description}").format(name=name, description=desc)))
    if not out:
        raise TaskSourceError(f"pipeline={pipeline}: pipeline.tasks lists no task")
    return out


def source_options(pipeline_config) -> dict:
    """The keys of a pipeline config (conf/pipeline/*.yaml) that load_tasks reads; the others are its episodes'."""
    return {k: pipeline_config.get(k) for k in SOURCE_OPTIONS}


def load_tasks(pipeline: str, source: str = "auto", **options) -> list[TaskText]:
    """Load every task of `pipeline` from the chosen source. Options: root, grouped_file, tasks_path, suite,
    text_template, group_aliases (the keys of the pipeline config)."""
    if source == "config" or (pipeline not in SOURCES and pipeline not in NO_TASK_TEXTS and options.get("tasks")):
        return config_tasks(pipeline, options.get("tasks"), options.get("text_template"))
    if pipeline in NO_TASK_TEXTS:
        raise TaskSourceError(f"pipeline={pipeline} has no task texts to load: {NO_TASK_TEXTS[pipeline]}")
    if pipeline not in SOURCES:
        raise TaskSourceError(f"unknown pipeline '{pipeline}'; known: {', '.join(SOURCES)}")
    candidates = SOURCES[pipeline]
    if source != "auto":
        by_name = {s.name: s for s in candidates}
        if source not in by_name:
            raise TaskSourceError(
                f"pipeline.source={source!r} is not a source of '{pipeline}'; choose auto or one of {', '.join(by_name)}"
            )
        candidates = [by_name[source]]
    for s in candidates:
        if options.get(s.needs) and (s.auto or source != "auto"):
            return s.load(options)
    raise SourceNotConfigured(pipeline, source_hint(pipeline))

"""The settings of each report kind (conf/report/<kind>.yaml), checked before a report is built.

The `report` config group's keys differ by kind, so the entrypoint's schema types the group as a whole
(simeval.config_schemas.ReportConfig); here each kind names its keys and their types, and `check_report` refuses,
in one line naming `report.<key>`, a key the kind does not have, a value of the wrong type, or one outside its
range (a Table 3 statistic that no run records would otherwise give a table of dashes).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Optional

from simeval.errors import UserError, check_field_types, require_whole, settings_from_dict
from simeval.measures.text_diversity.metric import STATISTICS


@dataclass
class Table3Report:
    kind: str
    id: str
    metric: str
    runs_dir: Optional[str]
    out_dir: str
    caption: str
    statistic: str
    digits: int
    rows: Any  # [{pipeline, display, groups: {group: label}}]: read by the table's builder
    columns: Any


@dataclass
class Figure4Report:
    kind: str
    id: str
    metric: str
    runs_dir: Optional[str]
    out_dir: str


@dataclass
class Table4Report:
    kind: str
    runs_dir: Optional[str]
    out: str
    figure: str
    episodes: Any  # three whole numbers, one per paper column
    preset: Optional[str]
    keep: Any  # one CSV path or a list of them


@dataclass
class Table4HeldoutReport:
    kind: str
    runs_dir: Optional[str]
    out: str
    figure: str
    keep: Any


@dataclass
class Table5Report:
    kind: str
    runs_dir: Optional[str]
    out: str
    figure: str
    policy: Optional[str]
    keep: Any


@dataclass
class HtmlReport:
    kind: str
    id: str
    runs_dir: Optional[str]
    tables_dir: Optional[str]
    figures_dir: Optional[str]
    out_dir: Optional[str]
    title: str


KIND_SETTINGS = {"table3": Table3Report, "figure4": Figure4Report, "table4": Table4Report,
                 "table4_heldout": Table4HeldoutReport, "table5": Table5Report, "html": HtmlReport}


def check_report(spec: dict, key: str = "report") -> None:
    """`spec` (one kind's resolved settings; `key`: where the user's config holds it) as its kind allows, else a
    UserError naming `<key>.<field>`. A kind this module does not know is left to the caller's own message."""
    cls = KIND_SETTINGS.get(spec.get("kind"))
    if cls is None:
        return
    missing = [f.name for f in fields(cls) if f.name not in spec]
    if missing:
        raise UserError(f"{key}: {spec['kind']} needs {', '.join(missing)} (see conf/report/{spec['kind']}.yaml)")
    settings = settings_from_dict(cls, spec, key)
    check_field_types(settings, key)
    if isinstance(settings, Table3Report):
        require_whole(f"{key}.digits", settings.digits, 0)
        if settings.statistic not in STATISTICS:
            raise UserError(f"{key}.statistic={settings.statistic!r}: expected one of {', '.join(STATISTICS)}")
        _check_entries(f"{key}.rows", settings.rows, ("pipeline", "display", "groups"),
                       "[{pipeline: gensim, display: GenSim, groups: {stacking: Stacking}}]")
        _check_entries(f"{key}.columns", settings.columns, ("embedding", "display"),
                       "[{embedding: minilm, display: MiniLM-L6-v2}]")
    if isinstance(settings, Table4Report):
        episodes = settings.episodes
        if not isinstance(episodes, list | tuple):
            raise UserError(f"{key}.episodes={episodes!r}: expected a list of episode counts, e.g. [10,20,40]")
        for count in episodes:
            require_whole(f"{key}.episodes[]", count, 1)
    figure = getattr(settings, "figure", None)
    if figure is not None:
        from simeval.writing.figures import check_figure_formats

        check_figure_formats(f"{key}.figure={figure}", [Path(figure).suffix.lstrip(".")])
    keep = getattr(settings, "keep", None)
    if keep is not None and not isinstance(keep, str) and not (
            isinstance(keep, list | tuple) and all(isinstance(path, str) for path in keep)):
        raise UserError(f"{key}.keep={keep!r}: expected a CSV path or a list of them, e.g. "
                        f"{key}.keep=[outputs/tables/{spec['kind']}.csv]")


def _check_entries(key: str, value: Any, needs: tuple[str, ...], example: str) -> None:
    """A list of mappings, each with the keys `needs`."""
    if not isinstance(value, list) or not all(isinstance(e, dict) and set(needs) <= set(e) for e in value):
        raise UserError(f"{key}={value!r}: expected a list of mappings with {', '.join(needs)}, e.g. {key}={example}")

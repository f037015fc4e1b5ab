"""Typed schemas of the entrypoints' configs (Hydra structured configs, registered in Hydra's ConfigStore).

Each `conf/<entrypoint>.yaml` names its schema first in its defaults list (`- <entrypoint>_schema`); the YAML keeps
the values and their comments, the schema gives each top-level key its type. OmegaConf then checks a value while
Hydra composes the config, before any simeval code runs: `episodes=abc`, `episodes=1.5` or `compile=fast` stop with
one line naming the key (simeval.cli's composition-error line), and a mistyped key is refused with the valid
ones. What a type cannot say, a lower bound, is declared beside the type (`whole(low)`) and checked by
`check_values`, one call per entrypoint, so each number's rule lives in one place.

A config group (pipeline, world_model, protocol, policy, judge, ...) is typed `Any` here: its keys differ by
option (a plugin pipeline brings its own) and each is read into its own settings dataclass, which names its keys
(simeval.errors.settings_from_dict).

Fields are MISSING (no default): the YAML is the one place a default is written. `test_config_schemas.py` composes
each entrypoint and checks that nothing is left missing.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, Optional, get_args, get_type_hints

from omegaconf import MISSING, OmegaConf

from simeval.errors import UserError, require_whole


def whole(low: int) -> Any:
    """A whole-number field whose value must be >= low (checked by check_values; the type by OmegaConf)."""
    return field(default=MISSING, metadata={"at_least": low})


def task_names() -> Any:
    """A field of task names: null, one name, or a list of names (checked by check_values). Why not a type:
    OmegaConf has no union of a string and a list."""
    return field(default=MISSING, metadata={"names": True})


def mapping(example: str) -> Any:
    """A field holding a mapping of names to text, e.g. `{task: group}`, or null (checked by check_values). Its YAML
    default is null rather than {}: Hydra refuses a new key in an empty mapping (`groups={a: b}` would need a `+`),
    not a value that replaces null."""
    return field(default=MISSING, metadata={"mapping": example})


@dataclass
class WindowEval:
    seed: int = whole(0)
    context: int = whole(1)
    batch_size: int = whole(1)


@dataclass
class DiversityConfig:
    task_group: str = MISSING
    episodes: int = whole(1)
    eval_episodes: Any = MISSING
    heldout_episodes: Optional[list[int]] = MISSING
    store: str = MISSING
    camera: str = MISSING
    seed: int = whole(0)
    eval: WindowEval = field(default_factory=WindowEval)
    videos: int = whole(0)
    threads: int = whole(1)
    device: str = MISSING
    compile: bool = MISSING
    capture: bool = MISSING
    checkpoint_dir: Optional[str] = MISSING
    progress: bool = MISSING
    paths: Any = MISSING
    pipeline: Any = MISSING
    world_model: Any = MISSING
    protocol: Any = MISSING
    logger: Any = MISSING


@dataclass
class CollectConfig:
    task_group: str = MISSING
    tasks: Any = task_names()
    episodes: int = whole(1)
    seed_offset: int = whole(0)
    workers: int = MISSING  # its bound (0: one per core) is worded by the collector
    store: str = MISSING
    record: Any = MISSING
    paths: Any = MISSING
    pipeline: Any = MISSING
    variation: Any = MISSING
    logger: Any = MISSING


@dataclass
class PolicyEval:
    splits: Any = MISSING  # one name or a list: read by the generalization run
    seeds: int = whole(1)
    seed_offset: int = whole(0)
    max_steps: Optional[int] = whole(1)
    variation: Any = MISSING
    videos: bool = MISSING
    video_camera: str = MISSING
    sampler_check: bool = MISSING


@dataclass
class GeneralizationConfig:
    task_group: str = MISSING
    tasks: Any = task_names()
    heldout_tasks: Any = task_names()
    episodes_per_task: int = whole(1)
    val_episodes_per_task: int = whole(0)
    demonstrations: str = MISSING
    store: str = MISSING
    checkpoint_dir: str = MISSING
    seed: int = whole(0)
    progress: bool = MISSING
    torch_threads: Optional[int] = whole(1)
    device: str = MISSING
    eval: PolicyEval = field(default_factory=PolicyEval)
    paths: Any = MISSING
    pipeline: Any = MISSING
    policy: Any = MISSING
    logger: Any = MISSING


@dataclass
class QualityEpisodes:
    store: Optional[str] = MISSING
    pipeline: Optional[str] = MISSING
    group: Optional[str] = MISSING
    per_task: int = whole(1)
    camera: Optional[str] = MISSING
    max_frames: int = whole(2)  # the first and the last frame at least


@dataclass
class QualityConfig:
    bundles_dir: Optional[str] = MISSING
    episodes: QualityEpisodes = field(default_factory=QualityEpisodes)
    metric: str = MISSING
    scene_alignment_mode: str = MISSING
    repeats: int = whole(1)
    max_reasks: int = whole(0)
    n_frames: int = MISSING  # its bound (>= 2) is the judge's, checked with the frames it samples
    budget_usd: Optional[float] = MISSING
    dry_run: bool = MISSING
    seed: int = whole(0)
    label: Optional[str] = MISSING
    cache_dir: str = MISSING
    prompts: Any = MISSING
    paths: Any = MISSING
    judge: Any = MISSING
    captioner: Any = MISSING
    logger: Any = MISSING


@dataclass
class ReportConfig:
    overwrite: bool = MISSING
    paths: Any = MISSING
    report: Any = MISSING


@dataclass
class TextMetrics:
    n_boot: int = MISSING  # its bound (>= 10) is the metric's, worded with why
    subsample_n: Any = MISSING  # auto, a whole number or null: read by the metric
    subsample_repeats: int = MISSING  # its bound is the metric's


@dataclass
class TextDiversityConfig:
    task_group: str = MISSING
    on_missing_source: str = MISSING
    seed: int = whole(0)
    cache_dir: str = MISSING
    metrics: TextMetrics = field(default_factory=TextMetrics)
    paths: Any = MISSING
    pipeline: Any = MISSING
    embedding: Any = MISSING
    logger: Any = MISSING


@dataclass
class AgreementConfig:
    scores_path: Optional[str] = MISSING
    human_column: str = MISSING
    n_boot: int = whole(1)
    seed: int = whole(0)
    figure_formats: list[str] = MISSING
    paths: Any = MISSING
    logger: Any = MISSING


@dataclass
class EpisodeSelection:
    store: str = MISSING
    pipeline: Optional[str] = MISSING
    group: str = MISSING


@dataclass
class DynamicsStage:
    counts: Any = MISSING  # lists of whole numbers, checked with an example (src/evaluate.py dynamics_settings)
    heldout: int = whole(1)
    seeds: Any = MISSING
    debug: str = MISSING
    overrides: Any = MISSING


@dataclass
class GeneralizationStage:
    debug: str = MISSING
    random_baseline: bool = MISSING
    overrides: Any = MISSING


@dataclass
class QualityStage:
    overrides: Any = MISSING


@dataclass
class EvaluateConfig:
    environment: Optional[str] = MISSING
    episodes: EpisodeSelection = field(default_factory=EpisodeSelection)
    camera: Optional[str] = MISSING
    out: str = MISSING
    tables: str = MISSING
    cache_dir: str = MISSING
    dynamics: DynamicsStage = field(default_factory=DynamicsStage)
    generalization: GeneralizationStage = field(default_factory=GeneralizationStage)
    quality: QualityStage = field(default_factory=QualityStage)
    paths: Any = MISSING
    embedding: Any = MISSING


@dataclass
class ExportDataConfig:
    format: str = MISSING
    episodes: EpisodeSelection = field(default_factory=EpisodeSelection)
    out: Optional[str] = MISSING
    fps: Any = MISSING  # a number > 0 or null, kept as written (info.json records it): checked by the exporter
    robot_type: str = MISSING
    overwrite: bool = MISSING
    paths: Any = MISSING


@dataclass
class ImportDataConfig:
    format: str = MISSING
    src: Optional[str] = MISSING
    store: str = MISSING
    image_size: Any = MISSING  # [H, W] or null: checked by the importers' image_size_option
    overwrite: bool = MISSING
    groups: Any = mapping("{task: group}")
    descriptions: Any = mapping("{task: 'the task text'}")
    name: Optional[str] = MISSING
    filter_key: Optional[str] = MISSING
    paths: Any = MISSING


@dataclass
class PaperConfig:
    pipelines: Any = MISSING  # one name or a list (src/paper.py names())
    stages: Any = MISSING
    out: str = MISSING
    launcher: str = MISSING
    sbatch_args: Optional[str] = MISSING
    paths: Any = MISSING
    profile: Any = MISSING


SCHEMAS = {"diversity": DiversityConfig, "collect": CollectConfig, "generalization": GeneralizationConfig,
           "quality": QualityConfig, "report": ReportConfig, "text_diversity": TextDiversityConfig,
           "agreement": AgreementConfig, "evaluate": EvaluateConfig, "export_data": ExportDataConfig,
           "import_data": ImportDataConfig, "paper": PaperConfig}


def register() -> None:
    """Store each schema as `<entrypoint>_schema` in Hydra's ConfigStore (idempotent)."""
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    for name, schema in SCHEMAS.items():
        store.store(name=f"{name}_schema", node=schema)


def check_values(cfg: Any, schema: type, prefix: str = "") -> None:
    """Each `whole(low)` field of `schema` (nested schemas included) >= its low, each `task_names()` field null, a
    name or a list of names, each `mapping()` field a mapping of names to text; else a UserError naming the dotted
    key. An Optional field may be null. The type was checked by OmegaConf when the config was composed."""
    hints = get_type_hints(schema)
    for f in fields(schema):
        key, value, kind = f"{prefix}{f.name}", cfg[f.name], hints[f.name]
        if is_dataclass(kind):
            check_values(value, kind, f"{key}.")
        elif "at_least" in f.metadata and not (value is None and type(None) in get_args(kind)):
            require_whole(key, value, low=f.metadata["at_least"])
        elif "names" in f.metadata:
            _check_names(key, value)
        elif "mapping" in f.metadata:
            _check_mapping(key, value, f.metadata["mapping"])


def _check_names(key: str, value: Any) -> None:
    items = [value] if value is None or isinstance(value, str) else value if OmegaConf.is_list(value) else None
    if items is None or not all(v is None and value is None or isinstance(v, str) for v in items):
        raise UserError(f"{key}={_shown(value)}: expected a task name, a list of names (e.g. {key}=[a,b]) or null")


def _check_mapping(key: str, value: Any, example: str) -> None:
    if value is None:
        return
    if not OmegaConf.is_dict(value) or not all(isinstance(k, str) and isinstance(v, str) for k, v in value.items()):
        raise UserError(f"{key}={_shown(value)}: expected a mapping, e.g. {key}={example}")


def _shown(value: Any) -> str:
    return repr(OmegaConf.to_container(value) if OmegaConf.is_config(value) else value)


register()

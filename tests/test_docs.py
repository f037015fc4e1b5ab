"""The manual a newcomer reads: the README stays short and its links and results-at-a-glance numbers point at real
files, the MkDocs site under docs/ builds with --strict (no broken link or anchor, every page in the nav), every
`python src/<entrypoint>.py key=value ...` line in a code block of the README or docs/ composes with the real
configs, and the glance figure is what docs/glance.py draws from the committed tables."""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
MAX_README_LINES = 220
# The docs' plugin example lives in `$HOME/my_sim` (my_sim.py and conf/pipeline/reach.yaml); the tests ship that
# very folder as tests/plugin_example, so its commands compose with Hydra's search path pointing there.
PLUGIN_FOLDER = ("$HOME/my_sim", str(ROOT / "tests" / "plugin_example"))
ERROR_MARK = "error example"  # a comment line right above a command that is meant to fail (it must fail to compose)

needs_mkdocs = pytest.mark.skipif(os.environ.get("CI") != "true" and importlib.util.find_spec("mkdocs") is None,
                                  reason="mkdocs is not installed (make docs-env)")


def _pages() -> list[Path]:
    return sorted([README, *DOCS.rglob("*.md")])


def _code_blocks(text: str) -> list[list[str]]:
    """The lines of each fenced code block (``` or ~~~), the fences left out."""
    blocks, current, fence = [], None, None
    for line in text.splitlines():
        stripped = line.strip()
        if current is None and stripped.startswith(("```", "~~~")):
            current, fence = [], stripped[:3]
        elif current is not None and stripped.startswith(fence):
            blocks.append(current)
            current = None
        elif current is not None:
            current.append(line)
    assert current is None, "a code block is not closed"
    return blocks


def _logical_lines(block: list[str]) -> list[tuple[str, str]]:
    """(line, the comment line right above it) with backslash continuations joined."""
    out, previous, pending = [], "", ""
    for line in block:
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        out.append((pending + line, previous))
        pending = ""
        if line.strip():
            previous = line.strip() if line.strip().startswith("#") else ""
    return out


def _entrypoints() -> dict[str, str]:
    """src/<entry>.py -> the config_name its @hydra.main composes."""
    names = {}
    for path in (ROOT / "src").glob("*.py"):
        m = re.search(r'config_name="(\w+)"', path.read_text())
        if m:
            names[path.stem] = m.group(1)
    return names


def _commands() -> list[tuple[str, str, list[str], bool]]:
    """(where, entrypoint, overrides, is an error example) for every `python src/<entry>.py ...` line of a code
    block, shell variables set earlier in the same block substituted and `-m` dropped."""
    found = []
    for page in _pages():
        where_page = page.relative_to(ROOT)
        for block in _code_blocks(page.read_text()):
            shell_vars: dict[str, str] = {}
            for line, comment_above in _logical_lines(block):
                if not re.search(r"python3?\s+src/\w+\.py", line):
                    m = re.match(r"\s*(?:export\s+)?([A-Z_][A-Z0-9_]*)=(.*)$", line)
                    if m:  # NAME=value, as the shell would keep it (quotes removed, nothing expanded)
                        shell_vars[m.group(1)] = shlex.split(m.group(2), comments=True)[0]
                    continue
                tokens = shlex.split(line, comments=True)
                start = next(i for i, t in enumerate(tokens) if re.fullmatch(r"(\S*/)?python3?", t)
                             and i + 1 < len(tokens) and re.fullmatch(r"src/\w+\.py", tokens[i + 1]))
                entry = Path(tokens[start + 1]).stem
                args = []
                for token in tokens[start + 2:]:
                    if token in ("&&", "||", "|", ";"):
                        break
                    if token in ("-m", "--multirun"):  # a sweep: its values are composed one by one below
                        continue
                    assert not token.startswith("-"), f"{where_page}: {line.strip()}: flag {token} is not handled"
                    token = token.replace(*PLUGIN_FOLDER)
                    token = re.sub(r"\$\{?(\w+)\}?", lambda m: shell_vars.get(m.group(1), m.group(0)), token)
                    token = token.replace(*PLUGIN_FOLDER)
                    assert "$" not in token, f"{where_page}: {line.strip()}: {token} names a variable the block does not set"
                    args.append(token)
                found.append((f"{where_page}: {line.strip()}", entry, args, ERROR_MARK in comment_above.lower()))
    return found


def _compositions(args: list[str]) -> list[list[str]]:
    """The override lists a command stands for: one with the first value of every sweep, then one more per other
    value of each sweep (episodes=10,20,40 composes episodes=10, 20 and 40)."""
    parsed = OverridesParser.create().parse_overrides(args)
    first = [f"{o.get_key_element()}={next(o.sweep_string_iterator())}" if o.is_sweep_override() else o.input_line
             for o in parsed]
    out = [first]
    for k, o in enumerate(parsed):
        if o.is_sweep_override():
            for value in list(o.sweep_string_iterator())[1:]:
                out.append([*first[:k], f"{o.get_key_element()}={value}", *first[k + 1:]])
    return out


def _compose(config_name: str, overrides: list[str]):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name=config_name, overrides=overrides)


COMMANDS = _commands()


def test_the_docs_show_commands_of_every_measurement():
    entries = {entry for _, entry, _, _ in COMMANDS}
    assert {"text_diversity", "quality", "agreement", "diversity", "generalization", "collect", "import_data",
            "evaluate", "report"} <= entries, entries
    assert any(error for *_, error in COMMANDS), "the error example of docs/errors.md was not found"


@pytest.mark.parametrize("where,entry,args,error", COMMANDS, ids=[c[0][:120] for c in COMMANDS])
def test_every_documented_command_composes_with_the_real_configs(where, entry, args, error):
    entrypoints = _entrypoints()
    assert entry in entrypoints, f"{where}: src/{entry}.py is not a Hydra entrypoint ({sorted(entrypoints)})"
    if error:  # marked in the docs as a mistake a user might make: Hydra must refuse it
        with pytest.raises(Exception, match="Could not override"):
            _compose(entrypoints[entry], args)
        return
    for overrides in _compositions(args):
        cfg = _compose(entrypoints[entry], overrides)
        assert cfg, f"{where}: {overrides} composed an empty config"


def test_the_plugin_example_composes_its_own_pipeline():
    """The docs' plugin commands reach tests/plugin_example's pipeline through hydra.searchpath, not a built-in one."""
    plugin = [(where, args) for where, entry, args, _ in COMMANDS if entry == "collect" and "pipeline=reach" in args]
    assert plugin, "the docs lost the plugin example's collect command"
    for where, args in plugin:
        cfg = _compose("collect", args)
        assert cfg.pipeline.name == "reach" and cfg.pipeline["_target_"] == "my_sim.MyPipeline", where


def test_readme_is_short_and_its_relative_links_point_at_files():
    text = README.read_text()
    assert len(text.splitlines()) <= MAX_README_LINES
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    relative = [link for link in links if not re.match(r"[a-z]+:", link) and not link.startswith("#")]
    assert len(relative) >= 20, relative  # the docs' pages, the glance figure, the committed tables
    missing = [link for link in relative if not (ROOT / link.split("#")[0]).is_file()]
    assert not missing, f"README.md links to files that do not exist: {missing}"
    assert "docs/img/glance.png" in relative


def test_readme_verdicts_quote_numbers_of_the_committed_tables():
    """Every decimal and every count like 6/50 in the README's results-at-a-glance section is in a committed table
    (outputs/tables/*.md, Figure 3's agreement.md): a verdict follows from committed numbers."""
    section = README.read_text().split("## Results at a glance", 1)[1].split("\n## ", 1)[0]
    committed = "\n".join(p.read_text() for p in [*(ROOT / "outputs" / "tables").glob("*.md"),
                                                  ROOT / "outputs" / "figures" / "figure3" / "agreement.md"])
    numbers = re.findall(r"(?<![\w.])-?\d+\.\d+|\b\d+/\d+\b", section)
    assert len(numbers) >= 30, numbers
    assert not [n for n in numbers if n not in committed], "numbers of the README that no committed table holds"


def test_every_docs_page_is_in_the_nav():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())

    def pages(node):
        if isinstance(node, str):
            yield node
        elif isinstance(node, list):
            for item in node:
                yield from pages(item)
        elif isinstance(node, dict):
            for value in node.values():
                yield from pages(value)

    nav = list(pages(config["nav"]))
    on_disk = sorted(str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md"))
    assert sorted(nav) == on_disk
    assert len(nav) == len(set(nav))


@needs_mkdocs
def test_mkdocs_builds_the_manual_strictly(tmp_path):
    site = tmp_path / "site"
    res = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file",
                          str(ROOT / "mkdocs.yml"), "--site-dir", str(site)], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "WARNING" not in res.stderr, res.stderr[-3000:]
    for page in DOCS.rglob("*.md"):  # every page rendered (index.md -> index.html, x.md -> x/index.html)
        rel = page.relative_to(DOCS).with_suffix("")
        html = site / (rel.parent if rel.name == "index" else rel) / "index.html"
        assert html.is_file(), f"{page.relative_to(ROOT)} was not built"
    assert (site / "img" / "glance.png").read_bytes() == (DOCS / "img" / "glance.png").read_bytes()
    assert not (site / "glance.py").exists()  # the script is not published as a page asset


def test_the_glance_figure_is_what_its_script_draws_from_the_committed_tables(tmp_path):
    out = tmp_path / "glance.png"
    res = subprocess.run([sys.executable, str(DOCS / "glance.py"), "--out", str(out)], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert out.read_bytes() == (DOCS / "img" / "glance.png").read_bytes(), \
        "docs/img/glance.png is stale: run `.venv/bin/python docs/glance.py` (or make docs) and commit it"

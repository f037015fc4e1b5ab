"""Per-file seconds of a pytest run's JUnit XML (`pytest --junitxml=F`), written as tests/file_seconds.json, which
conftest.py reads to hand out the longest test files first. Run by `make test-order`."""

import json
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path


def file_seconds(junit_xml: Path) -> dict[str, float]:
    """{test file name: the sum of its test cases' times}, longest first."""
    totals: dict[str, float] = defaultdict(float)
    for case in ET.parse(junit_xml).getroot().iter("testcase"):
        module = case.get("classname", "").split(".")
        name = next((f"{part}.py" for part in module if part.startswith("test_")), None)
        if name is not None:
            totals[name] += float(case.get("time", 0.0))
    return dict(sorted(((k, round(v, 1)) for k, v in totals.items()), key=lambda kv: -kv[1]))


if __name__ == "__main__":
    out = Path(__file__).with_name("file_seconds.json")
    out.write_text(json.dumps(file_seconds(Path(sys.argv[1])), indent=1) + "\n")
    print(f"wrote {out}")
